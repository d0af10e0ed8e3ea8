//! EM for the training workload: 8 scalar features × N samples × 3 states, default restarts.
//! Target (issue 5): ≤ 5 ms median for N = 400.

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use evitrack::hmm::{GaussianHmm, HmmSettings};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use std::hint::black_box;

/// 8 smooth features along a serpentine sweep of a square mesh with `n` nodes, plus noise.
fn features(n: usize) -> Vec<Vec<f64>> {
    let side = (n as f64).sqrt().ceil() as usize;
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let noise = Normal::new(0.0, 0.02).unwrap();
    (0..8)
        .map(|f| {
            let a = 0.5 + f as f64 * 0.37;
            (0..n)
                .map(|i| {
                    let (r, c) = (i / side, i % side);
                    let c = if r % 2 == 0 { c } else { side - 1 - c };
                    let (x, y) = (c as f64 / side as f64, r as f64 / side as f64);
                    (a * x + (1.0 - a) * y * y).sin()
                        + (3.0 * a * x * y).cos()
                        + noise.sample(&mut rng)
                })
                .collect()
        })
        .collect()
}

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

criterion_group!(benches, em_eight_features);
criterion_main!(benches);
