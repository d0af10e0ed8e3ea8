//! Dempster's rule on 8 mass functions × 3 focal sets of seeded random k-of-n subsets, plus all
//! singleton plausibilities (issue 2, item 5; issue 16, item 3). `fixed/…`: one draw per shape
//! (masses uniform in (0.1, 1)). `draws/…`: ten draws of the 200-of-400 shape with masses
//! uniform in (0, 1), then normalised (the C400 shape); the target is the slowest draw
//! ≤ 100 µs. `rules_c400/…` (issue 30, item 4): every rule of `evidence::Rule` through
//! `combine_all` on the fixed C400 draw and on draw 5, plus the contour; the cautious rule only
//! takes frames of at most 20 elements and non-dogmatic functions, so it is timed on the same
//! shape scaled to 20 elements (8 × 3 focal sets of 10 of 20, discounted by 0.9).
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use evitrack::evidence::{combine_all, dempster_all, discount_all, MassFunction, Rule};
use std::hint::black_box;

#[path = "common/inputs.rs"]
mod inputs;
use inputs::mass_functions as inputs;

fn combine_and_contour(fs: &[MassFunction]) -> (f64, Option<Vec<f64>>) {
    let c = dempster_all(black_box(fs)).expect("same frames");
    let pl = c.mass.as_ref().map(MassFunction::contour);
    (c.conflict_level, pl)
}

fn bench(c: &mut Criterion) {
    let mut group = c.benchmark_group("dempster_8x3_plus_contour");
    for (k, n) in [(200, 400), (130, 400), (14, 20)] {
        let fs = inputs(k, n, 2026, 0.1);
        group.bench_with_input(
            BenchmarkId::new("fixed", format!("{k}_of_{n}")),
            &fs,
            |b, fs| b.iter(|| black_box(combine_and_contour(fs))),
        );
    }
    for seed in 1..=10 {
        let fs = inputs(200, 400, seed, 0.0);
        group.bench_with_input(
            BenchmarkId::new("draws", format!("200_of_400_seed{seed}")),
            &fs,
            |b, fs| b.iter(|| black_box(combine_and_contour(fs))),
        );
    }
    group.finish();
}

fn rules(c: &mut Criterion) {
    let mut group = c.benchmark_group("rules_c400");
    group.sample_size(10);
    for (name, fs) in [
        ("fixed", inputs(200, 400, 2026, 0.1)),
        ("seed5", inputs(200, 400, 5, 0.0)),
    ] {
        for rule in Rule::ALL {
            let fs = if rule == Rule::Cautious {
                discount_all(&inputs(10, 20, 2026, 0.1), &[0.9]).expect("valid reliability")
            } else {
                fs.clone()
            };
            group.bench_with_input(BenchmarkId::new(rule.name(), name), &fs, |b, fs| {
                b.iter(|| {
                    let c = combine_all(rule, black_box(fs)).expect("within the limits");
                    black_box((c.conflict_level, c.mass.as_ref().map(MassFunction::contour)))
                })
            });
        }
    }
    group.finish();
}

criterion_group!(benches, bench, rules);
criterion_main!(benches);
