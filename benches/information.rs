//! The information limit of one frame (`information::NoiseModel::bound`): tr (Gᵀ Σ⁻¹ G)⁻¹ with
//! the slopes of the synthetic maps (`estimator::test_maps`) at a random pose and a full noise
//! covariance measured on 400 seeded residual rows, for 8 and 64 features. `all`: every feature
//! present (Σ⁻¹ cached); `one missing`: the block of the present features factored per frame.
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use evitrack::estimator::test_maps::{feature_gradient, workspace_points};
use evitrack::information::NoiseModel;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use std::hint::black_box;

/// A noise model of `n` features whose residuals share one common term (correlation ≈ 0.2).
fn noise(n: usize, rng: &mut ChaCha8Rng) -> NoiseModel {
    let normal = Normal::new(0.0, 1.0).expect("σ = 1");
    let rows: Vec<Vec<Option<f64>>> = (0..400)
        .map(|_| {
            let common = normal.sample(rng);
            (0..n)
                .map(|_| Some(0.01 * (0.5 * common + normal.sample(rng))))
                .collect()
        })
        .collect();
    NoiseModel::from_residuals(&vec![0.0112; n], &rows).expect("a noise model")
}

fn bench_bound(c: &mut Criterion) {
    let mut group = c.benchmark_group("information_bound");
    for n in [8usize, 64] {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let model = noise(n, &mut rng);
        let poses = workspace_points(64, &mut rng);
        let slopes: Vec<Vec<[f64; 2]>> = (poses.iter())
            .map(|&q| (0..n).map(|i| feature_gradient(i, q)).collect())
            .collect();
        let all = vec![true; n];
        let mut missing = all.clone();
        missing[n / 2] = false;
        for (name, present) in [("all", &all), ("one missing", &missing)] {
            let mut k = 0;
            group.bench_with_input(BenchmarkId::new(name, n), &n, |b, _| {
                b.iter(|| {
                    k = (k + 1) % slopes.len();
                    black_box(model.bound(black_box(&slopes[k]), present))
                })
            });
        }
    }
    group.finish();
}

criterion_group!(benches, bench_bound);
criterion_main!(benches);
