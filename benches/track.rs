//! Tracking one frame with the features given: 8 features, 400 sample poses (20 × 20 mesh),
//! both constructors (issue 6, item 10). Target: median ≤ 20 µs (≤ 10 µs for `paper_like`,
//! issue 16).
//!
//! `scale`: 10,000 sample poses (100 × 100 mesh) × 32 linear features of 3 states, directions
//! spread over a half turn, Bayesian, each selection policy (issue 16): threshold ∞ on a clean
//! frame; a finite threshold (1.05 × the clean frame's level) on the clean frame; the same
//! threshold on a frame whose features 0 and 16 report a pose 8 mm away (the full group is
//! beyond it, so the groups below it are searched). Target: median ≤ 1 ms for the largest
//! subset.
//!
//! `paper_like`: 8 linear features of the pose in different directions, 2–3 states each (the
//! paper's state counts). `fine`: x and y with 20 states, their coarse versions with 7, x ± y with
//! 10 and x + 2y, 2x − y with 8 (every sample pose is its own cell). `faulty`: the fine model with
//! two features reporting a pose 8 mm away and a threshold just above the clean frame's level,
//! so the groups below the full one are searched; with the largest-subset policy and with
//! splitting into alternatives weighed by group reliabilities.
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use evitrack::evidence::ConflictLevel;
use evitrack::evidence::{Constructor, Refining};
use evitrack::track::{
    GroupError, SelectionPolicy, TrackSettings, TrackedFeature, Tracker, TrackerModel,
};
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

/// A tracker over the `side` × `side` mesh of the 19 mm square and one frame's likelihoods at a
/// random pose, the features in `corrupt` reporting a pose 8 mm away in x.
fn setup(
    feats: &[Feat],
    side: usize,
    settings: TrackSettings,
    corrupt: &[usize],
    seed: u64,
) -> (Tracker, Vec<Option<Vec<f64>>>) {
    let step = 19.0 / (side - 1) as f64;
    let poses: Vec<[f64; 2]> = (0..side)
        .flat_map(|y| (0..side).map(move |x| [x as f64 * step, y as f64 * step]))
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
    // Group reliabilities for the splitting policy: larger groups more reliable (only for
    // models small enough to list every group).
    let n = feats.len();
    let group_errors: Vec<GroupError> = (1u32..1 << n.min(10))
        .filter(|_| n <= 10)
        .map(|m| GroupError {
            features: (0..n).filter(|j| m >> j & 1 == 1).collect(),
            error: 1.0 / f64::from(m.count_ones()),
        })
        .collect();
    let model = TrackerModel::new(poses, features)
        .expect("model")
        .with_group_errors(&group_errors)
        .expect("group errors");
    let tracker = Tracker::new(model, settings.check().expect("settings")).expect("tracker");
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let p = [rng.random_range(0.0..19.0), rng.random_range(0.0..19.0)];
    let shifted = if p[0] < 11.0 { p[0] + 8.0 } else { p[0] - 8.0 };
    let lik = feats
        .iter()
        .zip(&ranges)
        .enumerate()
        .map(|(i, (f, &(lo, w)))| {
            let v = f.value(if corrupt.contains(&i) {
                [shifted, p[1]]
            } else {
                p
            });
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

/// Times tracking one frame.
fn bench_frame(
    group: &mut criterion::BenchmarkGroup<'_, criterion::measurement::WallTime>,
    id: BenchmarkId,
    tracker: &Tracker,
    lik: &[Option<Vec<f64>>],
) {
    group.bench_with_input(id, lik, |b, lik| {
        b.iter(|| {
            black_box(
                tracker
                    .track(black_box(lik))
                    .expect("one entry per feature"),
            )
        })
    });
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
            let settings = TrackSettings {
                constructor,
                ..TrackSettings::default()
            };
            let (tracker, lik) = setup(feats, 20, settings, &[], 2026);
            let id = BenchmarkId::new(name, format!("{constructor:?}").to_lowercase());
            bench_frame(&mut group, id, &tracker, &lik);
        }
    }
    // Two corrupted features; the threshold just above the clean frame's level.
    for constructor in [Constructor::Bayesian, Constructor::Consonant] {
        let open = TrackSettings {
            constructor,
            ..TrackSettings::default()
        };
        let (clean, clean_lik) = setup(&fine, 20, open.clone(), &[], 2026);
        let level = clean
            .full_conflict_level(&clean_lik)
            .expect("one entry per feature");
        for (policy, selection) in [
            ("largest", SelectionPolicy::LargestSubset),
            ("split4", SelectionPolicy::Splitting { min_size: 4 }),
        ] {
            let settings = TrackSettings {
                conflict_threshold: ConflictLevel::Finite(1.05 * level),
                selection,
                ..open.clone()
            };
            let (tracker, lik) = setup(&fine, 20, settings, &[0, 4], 2026);
            let frame = tracker.track(&lik).expect("one entry per feature");
            assert!(
                !frame.flags.excluded.is_empty() || frame.alternatives.len() > 1,
                "the corrupted features are left out, or split off"
            );
            let id = BenchmarkId::new(
                format!("faulty_{policy}"),
                format!("{constructor:?}").to_lowercase(),
            );
            bench_frame(&mut group, id, &tracker, &lik);
        }
    }
    group.finish();
    bench_scale(c);
    bench_rules(c, &paper_like);
}

/// One frame per combination rule (issue 30): the paper-like model (8 features, 400 poses,
/// Bayesian), every usable feature combined by the rule; `paper` is the selection + Dempster
/// default, `-a0.9` discounts every feature by 0.9 first. The cautious rule takes at most 20
/// cells, so it is timed on a 4 × 4 mesh (consonant, discounted) beside Dempster's there.
fn bench_rules(c: &mut Criterion, feats: &[Feat]) {
    use evitrack::evidence::Rule;
    use evitrack::track::{Combine, Discount};
    let mut group = c.benchmark_group("track_frame_rules");
    let (tracker, lik) = setup(feats, 20, TrackSettings::default(), &[], 2026);
    bench_frame(&mut group, BenchmarkId::new("paper", "400"), &tracker, &lik);
    for rule in Rule::ALL {
        for (suffix, discount) in [("", Discount::None), ("-a0.9", Discount::Fixed(0.9))] {
            if rule == Rule::Cautious || (!suffix.is_empty() && rule != Rule::Dempster) {
                continue;
            }
            let settings = TrackSettings {
                combine: Combine::All,
                rule,
                discount,
                ..TrackSettings::default()
            };
            let (tracker, lik) = setup(feats, 20, settings, &[], 2026);
            let id = BenchmarkId::new(format!("{}{suffix}", rule.name()), "400");
            bench_frame(&mut group, id, &tracker, &lik);
        }
    }
    for rule in [Rule::Dempster, Rule::Cautious] {
        let settings = TrackSettings {
            constructor: Constructor::Consonant,
            combine: Combine::All,
            rule,
            discount: Discount::Fixed(0.9),
            ..TrackSettings::default()
        };
        let (tracker, lik) = setup(feats, 4, settings, &[], 2026);
        bench_frame(
            &mut group,
            BenchmarkId::new(rule.name(), "16"),
            &tracker,
            &lik,
        );
    }
    group.finish();
}

/// 10,000 sample poses × 32 features of 3 states, every policy, threshold ∞ and finite.
fn bench_scale(c: &mut Criterion) {
    let d = 32;
    let feats: Vec<Feat> = (0..d)
        .map(|i| {
            let a = (i as f64 * 180.0 / d as f64).to_radians();
            Feat {
                coef: [a.cos(), a.sin()],
                states: 3,
            }
        })
        .collect();
    let open = TrackSettings::default();
    let (clean, clean_lik) = setup(&feats, 100, open.clone(), &[], 2026);
    let level = clean
        .full_conflict_level(&clean_lik)
        .expect("one entry per feature");
    let mut group = c.benchmark_group("track_frame_32_features_10000_poses");
    group.sample_size(10);
    for (policy, selection) in [
        ("largest", SelectionPolicy::LargestSubset),
        ("lowest2", SelectionPolicy::LowestConflict { min_size: 2 }),
        ("split2", SelectionPolicy::Splitting { min_size: 2 }),
    ] {
        for (name, threshold, corrupt) in [
            ("inf_clean", ConflictLevel::Infinite, &[][..]),
            ("finite_clean", ConflictLevel::Finite(1.05 * level), &[][..]),
            (
                "finite_faulty",
                ConflictLevel::Finite(1.05 * level),
                &[0, 16][..],
            ),
        ] {
            let settings = TrackSettings {
                conflict_threshold: threshold,
                selection,
                ..open.clone()
            };
            let (tracker, lik) = setup(&feats, 100, settings, corrupt, 2026);
            bench_frame(&mut group, BenchmarkId::new(policy, name), &tracker, &lik);
        }
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
