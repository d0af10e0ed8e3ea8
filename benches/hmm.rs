//! EM for the training workload: 8 scalar features × N samples × 3 states, default restarts.
//! Target (issue 5): ≤ 5 ms median for N = 400. Also 400 samples with 12 and 24 states per
//! feature (the general recursions, beyond the specialised K ≤ 6: `best.toml`'s n24).

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use evitrack::hmm::{GaussianHmm, HmmSettings};
use std::hint::black_box;

#[path = "common/inputs.rs"]
mod inputs;
use inputs::em_features as features;

fn em_eight_features(c: &mut Criterion) {
    let settings = HmmSettings::default();
    let mut group = c.benchmark_group("hmm_em_8_features_3_states");
    for n in [100, 400, 1600] {
        let data = features(n);
        group.bench_with_input(BenchmarkId::from_parameter(n), &data, |b, data| {
            b.iter(|| {
                for (i, col) in data.iter().enumerate() {
                    let fit = GaussianHmm::fit(black_box(col), 3, &settings, i as u64);
                    black_box(fit.ok());
                }
            })
        });
    }
    group.finish();
}

fn em_many_states(c: &mut Criterion) {
    let settings = HmmSettings::default();
    let mut group = c.benchmark_group("hmm_em_8_features_400_samples");
    group.sample_size(10);
    let data = features(400);
    for states in [12, 24] {
        group.bench_with_input(BenchmarkId::new("states", states), &data, |b, data| {
            b.iter(|| {
                for (i, col) in data.iter().enumerate() {
                    let fit = GaussianHmm::fit(black_box(col), states, &settings, i as u64);
                    black_box(fit.ok());
                }
            })
        });
    }
    group.finish();
}

criterion_group!(benches, em_eight_features, em_many_states);
criterion_main!(benches);
