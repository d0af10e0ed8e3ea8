//! Tracking one frame with the features given: 8 features, 400 sample poses (20 × 20 mesh),
//! both constructors (issue 6, item 10). Target: median ≤ 20 µs.
//!
//! `paper_like`: 8 linear features of the pose in different directions, 2–3 states each (the
//! paper's state counts). `fine`: x and y with 20 states, their coarse versions with 7, x ± y with
//! 10 and x + 2y, 2x − y with 8 (every sample pose is its own cell).
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use evitrack::evidence::{Constructor, Refining};
use evitrack::track::{TrackSettings, TrackedFeature, Tracker, TrackerModel};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::hint::black_box;

struct Feat {
    coef: [f64; 2],
    states: usize,
}

impl Feat {
    fn value(&self, p: [f64; 2]) -> f64 {
        self.coef[0] * p[0] + self.coef[1] * p[1]
    }
}

fn setup(feats: &[Feat], constructor: Constructor, seed: u64) -> (Tracker, Vec<Option<Vec<f64>>>) {
    let poses: Vec<[f64; 2]> = (0..20)
        .flat_map(|y| (0..20).map(move |x| [x as f64, y as f64]))
        .collect();
    let mut features = Vec::new();
    let mut ranges = Vec::new();
    for f in feats {
        let values: Vec<f64> = poses.iter().map(|&p| f.value(p)).collect();
        let lo = values.iter().copied().fold(f64::INFINITY, f64::min) - 0.5;
        let hi = values.iter().copied().fold(f64::NEG_INFINITY, f64::max) + 0.5;
        let w = (hi - lo) / f.states as f64;
        let assignment: Vec<usize> = values
            .iter()
            .map(|v| (((v - lo) / w).floor() as usize).min(f.states - 1))
            .collect();
        let refining =
            Refining::from_assignment(f.states, &assignment).expect("every bin holds a node");
        features.push(TrackedFeature {
            refining,
            validation_error: None,
        });
        ranges.push((lo, w));
    }
    let model = TrackerModel::new(poses, features).expect("model");
    let settings = TrackSettings {
        constructor,
        ..TrackSettings::default()
    }
    .check()
    .expect("settings");
    let tracker = Tracker::new(model, settings).expect("tracker");
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let p = [rng.random_range(0.0..19.0), rng.random_range(0.0..19.0)];
    let lik = feats
        .iter()
        .zip(&ranges)
        .map(|(f, &(lo, w))| {
            let v = f.value(p);
            Some(
                (0..f.states)
                    .map(|j| {
                        let c = lo + (j as f64 + 0.5) * w;
                        (-(v - c).powi(2) / (0.5 * w * w)).exp()
                    })
                    .collect(),
            )
        })
        .collect();
    (tracker, lik)
}

fn bench(c: &mut Criterion) {
    let dir = |deg: f64| [deg.to_radians().cos(), deg.to_radians().sin()];
    let paper_like: Vec<Feat> = [
        (0.0, 2),
        (22.5, 2),
        (45.0, 2),
        (67.5, 3),
        (90.0, 3),
        (112.5, 2),
        (135.0, 3),
        (157.5, 2),
    ]
    .into_iter()
    .map(|(a, states)| Feat {
        coef: dir(a),
        states,
    })
    .collect();
    let fine: Vec<Feat> = [
        ([1.0, 0.0], 20),
        ([0.0, 1.0], 20),
        ([1.0, 0.0], 7),
        ([0.0, 1.0], 7),
        ([1.0, 1.0], 10),
        ([1.0, -1.0], 10),
        ([1.0, 2.0], 8),
        ([2.0, -1.0], 8),
    ]
    .into_iter()
    .map(|(coef, states)| Feat { coef, states })
    .collect();
    let mut group = c.benchmark_group("track_frame_8_features_400_poses");
    for (name, feats) in [("paper_like", &paper_like), ("fine", &fine)] {
        for constructor in [Constructor::Bayesian, Constructor::Consonant] {
            let (tracker, lik) = setup(feats, constructor, 2026);
            let id = BenchmarkId::new(name, format!("{constructor:?}").to_lowercase());
            group.bench_with_input(id, &lik, |b, lik| {
                b.iter(|| {
                    black_box(
                        tracker
                            .track(black_box(lik))
                            .expect("one entry per feature"),
                    )
                })
            });
        }
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
