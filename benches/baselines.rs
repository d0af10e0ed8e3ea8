//! The baseline estimators on 8 smooth synthetic features of the pose (plus a little noise):
//! fitting on 400 (20 × 20 mesh) and 1,521 (39 × 39) samples over [−9.5, 9.5] × [38, 57] mm,
//! and one frame's estimate; k-NN also per frame on 10,000 samples (100 × 100), where its k-d
//! tree matters, with 8 features and with 2, 32 and 64. Also learning a calibration (regions
//! and abstention limit) from 400 validation estimates, with and without the stretched limit.

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use evitrack::estimator::{
    Calibration, Centre, CentreSettings, ConfidenceSettings, Gp, GpSettings, Knn, KnnSettings,
    PoseEstimate, PoseEstimator,
};
use evitrack::planar::Rect;
use std::hint::black_box;
use std::time::Duration;

#[path = "common/inputs.rs"]
mod inputs;

use inputs::Samples;

/// Feature rows (`dim` features) of random poses inside the mesh.
fn frames(n: usize, dim: usize) -> Vec<Vec<Option<f64>>> {
    inputs::frames(n, dim).1
}

/// Estimates frames in turn, one per iteration.
fn bench_frames(
    group: &mut criterion::BenchmarkGroup<'_, criterion::measurement::WallTime>,
    id: BenchmarkId,
    estimator: &dyn PoseEstimator,
) {
    let rows = frames(64, estimator.feature_names().len());
    let mut i = 0;
    group.bench_function(id, |b| {
        b.iter(|| {
            i = (i + 1) % rows.len();
            black_box(estimator.estimate(black_box(&rows[i])).ok())
        })
    });
}

fn fit(c: &mut Criterion) {
    let mut group = c.benchmark_group("baseline_fit");
    for side in [20, 39] {
        let samples = Samples::mesh(side);
        let n = side * side;
        let training = samples.training();
        group.sample_size(10);
        group.measurement_time(Duration::from_secs(5));
        group.bench_function(BenchmarkId::new("centre", n), |b| {
            b.iter(|| Centre::fit(&CentreSettings::default(), black_box(&training)).ok())
        });
        group.bench_function(BenchmarkId::new("knn", n), |b| {
            b.iter(|| Knn::fit(&KnnSettings::default(), black_box(&training)).ok())
        });
        group.measurement_time(Duration::from_secs(30));
        group.bench_function(BenchmarkId::new("gp", n), |b| {
            b.iter(|| Gp::fit(&GpSettings::default(), black_box(&training)).ok())
        });
    }
    group.finish();
}

fn estimate(c: &mut Criterion) {
    let mut group = c.benchmark_group("baseline_frame");
    for side in [20, 39, 100] {
        let samples = Samples::mesh(side);
        let n = side * side;
        let training = samples.training();
        let knn = Knn::fit(&KnnSettings::default(), &training).expect("k-NN fits");
        bench_frames(&mut group, BenchmarkId::new("knn", n), &knn);
        if n > 2000 {
            continue;
        }
        let centre = Centre::fit(&CentreSettings::default(), &training).expect("centre fits");
        bench_frames(&mut group, BenchmarkId::new("centre", n), &centre);
        let gp = Gp::fit(&GpSettings::default(), &training).expect("GP fits");
        bench_frames(&mut group, BenchmarkId::new("gp", n), &gp);
    }
    group.finish();
}

/// k-NN on 10,000 samples with 2, 32 and 64 features (8: `baseline_frame/knn/10000`).
fn knn_features(c: &mut Criterion) {
    let mut group = c.benchmark_group("knn_frame_10000");
    for dim in [2, 32, 64] {
        let samples = Samples::mesh_of(100, dim);
        let knn = Knn::fit(&KnnSettings::default(), &samples.training()).expect("k-NN fits");
        bench_frames(&mut group, BenchmarkId::new("features", dim), &knn);
    }
    group.finish();
}

/// 400 validation estimates about a fixed truth, each with its covariance and a detection score.
fn validation_estimates() -> (Vec<PoseEstimate>, Vec<[f64; 2]>) {
    (0..400)
        .map(|i| {
            let phase = f64::from(i) * 0.37;
            let sigma = 0.05 + 0.01 * f64::from(i % 7);
            let estimate = PoseEstimate {
                pose: Some([sigma * phase.sin(), 47.5 + sigma * phase.cos()]),
                detection_score: Some(6.0 + 3.0 * (phase * 1.7).sin().abs() + f64::from(i % 13)),
                covariance: Some([[sigma * sigma, 0.0], [0.0, sigma * sigma]]),
                ..PoseEstimate::default()
            };
            (estimate, [0.0, 47.5])
        })
        .unzip()
}

fn calibration(c: &mut Criterion) {
    let mut group = c.benchmark_group("calibration_learn_400");
    let (estimates, truth) = validation_estimates();
    let workspace = Rect {
        x_min: -9.5,
        x_max: 9.5,
        y_min: 38.0,
        y_max: 57.0,
    };
    for stretch in [0.0, 0.5] {
        let settings = ConfidenceSettings {
            detection_stretch: stretch,
            ..ConfidenceSettings::default()
        };
        group.bench_function(BenchmarkId::new("stretch", stretch), |b| {
            b.iter(|| {
                black_box(Calibration::from_validation(
                    black_box(&estimates),
                    &truth,
                    workspace,
                    &settings,
                ))
            })
        });
    }
    group.finish();
}

criterion_group!(benches, fit, estimate, knn_features, calibration);
criterion_main!(benches);
