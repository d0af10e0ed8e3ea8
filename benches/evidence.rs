//! Dempster's rule on 8 mass functions × 3 focal sets of seeded random k-of-n subsets, plus all
//! singleton plausibilities (issue 2, item 5). Target for 200 of 400: median ≤ 100 µs.
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use evitrack::evidence::{dempster_all, MassFunction, Subset};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::hint::black_box;

fn inputs(k: usize, n: usize, seed: u64) -> Vec<MassFunction> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..8)
        .map(|_| {
            let raw: Vec<f64> = (0..3).map(|_| rng.random_range(0.1..1.0)).collect();
            let total: f64 = raw.iter().sum();
            let focal = raw
                .iter()
                .map(|m| {
                    let idx = rand::seq::index::sample(&mut rng, n, k);
                    let s = Subset::from_indices(n, idx.iter()).expect("indices below n");
                    (s, m / total)
                })
                .collect();
            MassFunction::new(n, focal).expect("valid mass function")
        })
        .collect()
}

fn bench(c: &mut Criterion) {
    let mut group = c.benchmark_group("dempster_8x3_plus_contour");
    for (k, n) in [(200, 400), (130, 400), (14, 20)] {
        let fs = inputs(k, n, 2026);
        group.bench_with_input(
            BenchmarkId::from_parameter(format!("{k}_of_{n}")),
            &fs,
            |b, fs| {
                b.iter(|| {
                    let c = dempster_all(black_box(fs)).expect("same frames");
                    let pl = c.mass.as_ref().map(MassFunction::contour);
                    black_box((c.conflict_level, pl))
                })
            },
        );
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
