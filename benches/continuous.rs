//! The continuous evidential tracker, one frame with the features given: 8 synthetic smooth
//! features of the pose (`estimator::test_maps`), 400 sample poses (the 1 mm mesh), a validation
//! path of 100 poses. `clean`: a frame at a random pose with the samples' noise, every feature
//! combined. `faulty`: two features stuck far from their value and a learned threshold, so the
//! groups below the full one are searched (largest subset). Target (clean): median ≤ 100 µs.
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use evitrack::estimator::test_maps::{feature_row, workspace_mesh, workspace_points};
use evitrack::estimator::{Continuous, ContinuousSettings, Labelled, PoseEstimator, TrainingSet};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use std::hint::black_box;

const FEATURES: usize = 8;
const NOISE: f64 = 0.002;

fn fitted(per_side: usize, learn: bool) -> Continuous {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let poses = workspace_mesh(per_side);
    let rows: Vec<_> = poses
        .iter()
        .map(|&q| feature_row(FEATURES, q, NOISE, &mut rng))
        .collect();
    let valid_poses = workspace_points(100, &mut rng);
    let valid_rows: Vec<_> = (valid_poses.iter())
        .map(|&q| feature_row(FEATURES, q, NOISE, &mut rng))
        .collect();
    let names: Vec<String> = (0..FEATURES).map(|i| format!("f{i}")).collect();
    let mut data = TrainingSet::new(
        &names,
        Labelled {
            poses: &poses,
            rows: &rows,
        },
    );
    data.validation = Some(Labelled {
        poses: &valid_poses,
        rows: &valid_rows,
    });
    let settings = ContinuousSettings {
        learn_threshold: learn,
        ..ContinuousSettings::default()
    };
    Continuous::fit(&settings, &data).expect("fits")
}

fn frames(faulty: bool) -> Vec<Vec<Option<f64>>> {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    (workspace_points(32, &mut rng).iter())
        .map(|&q| {
            let mut row = feature_row(FEATURES, q, NOISE, &mut rng);
            if faulty {
                row[1] = row[1].map(|v| v + 0.8);
                row[6] = row[6].map(|v| v - 0.8);
            }
            row
        })
        .collect()
}

fn bench(c: &mut Criterion) {
    let mut group = c.benchmark_group("continuous");
    for (name, faulty) in [("clean", false), ("faulty", true)] {
        let model = fitted(20, faulty);
        let rows = frames(faulty);
        let mut k = 0;
        group.bench_function(BenchmarkId::new(name, "400x8"), |b| {
            b.iter(|| {
                k = (k + 1) % rows.len();
                black_box(model.estimate(black_box(&rows[k])).expect("estimates"))
            })
        });
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
