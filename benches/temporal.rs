//! Tracking over time (issue 17): one frame of a motion through `MotionTracker::next`, for the
//! paper's tracker (per frame, for reference) and the three temporal methods, on 8 synthetic
//! features of a 20 × 20 mesh (1 mm) with 24 states each, along a 200-frame Lissajous path at
//! 20 frames per second; the particle filter also with 20,000 particles (what a fair filter
//! needs, issue 32); and loading the temporal evidential tracker's model file (which refines
//! the sample poses).

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use evitrack::estimator::test_maps::{feature_row, MeshSamples};
use evitrack::estimator::{EstimatorSettings, Method, TemporalEvidential};
use evitrack::model::{ModelSettings, StateCounts};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use std::hint::black_box;
use std::time::Duration;

const FEATURES: usize = 8;
const NOISE: f64 = 0.01;

/// The test path: (time, feature row) of a Lissajous figure over the workspace.
fn path() -> Vec<(f64, Vec<Option<f64>>)> {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    (0..200)
        .map(|k| {
            let t = k as f64 / 20.0;
            let q = [
                8.0 * (std::f64::consts::TAU * 0.3 * t).sin(),
                47.5 + 8.0 * (std::f64::consts::TAU * 0.2 * t).sin(),
            ];
            (t, feature_row(FEATURES, q, NOISE, &mut rng))
        })
        .collect()
}

fn temporal(c: &mut Criterion) {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let samples = MeshSamples::new(20, FEATURES, NOISE, &mut rng);
    let data = samples.training();
    let mut settings = EstimatorSettings::default();
    settings.evidential.model = ModelSettings {
        states: StateCounts::All(24),
        ..ModelSettings::default()
    };
    settings.temporal.reliability = Some(1.0);
    let frames = path();

    let mut group = c.benchmark_group("temporal");
    group.measurement_time(Duration::from_secs(4));
    for method in [
        Method::EVIDENTIAL,
        Method::EVIDENTIAL_TEMPORAL,
        Method::CONTINUOUS_TEMPORAL,
        Method::PARTICLE_FILTER,
    ] {
        let estimator = method.fit(&settings, &data).expect("fits");
        group.bench_function(BenchmarkId::new("frame", estimator.method()), |b| {
            let mut motion = estimator.start_motion();
            let mut k = 0;
            b.iter(|| {
                if k == frames.len() {
                    motion = estimator.start_motion();
                    k = 0;
                }
                let (t, row) = &frames[k];
                k += 1;
                black_box(motion.next(*t, row).expect("tracks"))
            });
        });
        if method == Method::EVIDENTIAL_TEMPORAL {
            let text = estimator.to_json().expect("writes");
            group.bench_function("load evidential_temporal (refines 400 poses)", |b| {
                b.iter(|| black_box(TemporalEvidential::from_json(&text).expect("loads")));
            });
        }
    }
    settings.particle_filter.particles = 20_000;
    // Without the recovery and with it (the default, as in `frame/particle_filter`; its cost:
    // the frame's own fit and the weights' correction).
    for (name, recovery_share) in [
        ("frame/particle_filter 20000", 0.0),
        ("frame/particle_filter 20000 with recovery 0.3", 0.3),
    ] {
        settings.particle_filter.recovery_share = recovery_share;
        let filter = Method::PARTICLE_FILTER.fit(&settings, &data).expect("fits");
        group.bench_function(name, |b| {
            let mut motion = filter.start_motion();
            let mut k = 0;
            b.iter(|| {
                if k == frames.len() {
                    motion = filter.start_motion();
                    k = 0;
                }
                let (t, row) = &frames[k];
                k += 1;
                black_box(motion.next(*t, row).expect("tracks"))
            });
        });
    }
    group.finish();
}

criterion_group!(benches, temporal);
criterion_main!(benches);
