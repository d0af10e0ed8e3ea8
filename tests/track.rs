//! Integration tests of the tracker on a synthetic problem whose features are exact functions of
//! the pose, with the model built in the test through `Refining::from_assignment`.

use evitrack::evidence::{
    dempster_all, from_likelihoods, pignistic, pointwise_estimate, relative_plausibility,
    ConflictLevel, Constructor, LikelihoodIssue, MassFunction, Refining,
};
use evitrack::track::{
    FeatureIssue, FrameEstimate, GroupError, PoseRule, SelectionPolicy, TrackSettings,
    TrackedFeature, Tracker, TrackerModel,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

mod groups;

/// A scalar feature a·p + b quantised into `states` equal bins over [lo, hi], with Gaussian
/// likelihoods (σ = half a bin) around the bin centres.
#[derive(Clone, Copy)]
struct Feat {
    coef: [f64; 2],
    lo: f64,
    hi: f64,
    states: usize,
}

impl Feat {
    fn value(&self, p: [f64; 2]) -> f64 {
        self.coef[0] * p[0] + self.coef[1] * p[1]
    }
    fn width(&self) -> f64 {
        (self.hi - self.lo) / self.states as f64
    }
    fn state(&self, v: f64) -> usize {
        (((v - self.lo) / self.width()).floor().max(0.0) as usize).min(self.states - 1)
    }
    fn likelihoods(&self, v: f64) -> Vec<f64> {
        let w = self.width();
        let sigma = 0.5 * w;
        (0..self.states)
            .map(|j| {
                let c = self.lo + (j as f64 + 0.5) * w;
                (-(v - c).powi(2) / (2.0 * sigma * sigma)).exp()
            })
            .collect()
    }
}

const X: Feat = Feat {
    coef: [1.0, 0.0],
    lo: -0.5,
    hi: 19.5,
    states: 20,
};
const Y: Feat = Feat {
    coef: [0.0, 1.0],
    lo: -0.5,
    hi: 19.5,
    states: 20,
};
const X_COARSE: Feat = Feat {
    coef: [1.0, 0.0],
    lo: -0.5,
    hi: 19.5,
    states: 7,
};
const Y_COARSE: Feat = Feat {
    coef: [0.0, 1.0],
    lo: -0.5,
    hi: 19.5,
    states: 7,
};
const SUM: Feat = Feat {
    coef: [1.0, 1.0],
    lo: -0.5,
    hi: 38.5,
    states: 10,
};
const DIFF: Feat = Feat {
    coef: [1.0, -1.0],
    lo: -19.5,
    hi: 19.5,
    states: 10,
};

/// The 20 × 20 mesh with ε = 1 mm.
fn mesh() -> Vec<[f64; 2]> {
    (0..20)
        .flat_map(|y| (0..20).map(move |x| [x as f64, y as f64]))
        .collect()
}

fn model(feats: &[Feat], validation: &[Option<f64>]) -> TrackerModel {
    let poses = mesh();
    let features = feats
        .iter()
        .enumerate()
        .map(|(i, f)| {
            let assignment: Vec<usize> = poses.iter().map(|&p| f.state(f.value(p))).collect();
            TrackedFeature {
                refining: Refining::from_assignment(f.states, &assignment)
                    .expect("every bin holds a node"),
                validation_error: validation.get(i).copied().flatten(),
            }
        })
        .collect();
    TrackerModel::new(poses, features).expect("valid model")
}

fn tracker(feats: &[Feat], settings: TrackSettings) -> Tracker {
    Tracker::new(model(feats, &[]), settings.check().expect("valid settings")).expect("tracker")
}

fn frame(feats: &[Feat], p: [f64; 2]) -> Vec<Option<Vec<f64>>> {
    feats
        .iter()
        .map(|f| Some(f.likelihoods(f.value(p))))
        .collect()
}

fn points(n: usize, seed: u64) -> Vec<[f64; 2]> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n)
        .map(|_| [rng.random_range(0.0..19.0), rng.random_range(0.0..19.0)])
        .collect()
}

fn dist(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

fn mean_error(t: &Tracker, feats: &[Feat], pts: &[[f64; 2]]) -> f64 {
    pts.iter()
        .map(|&p| {
            dist(
                t.track(&frame(feats, p))
                    .unwrap()
                    .estimate
                    .expect("estimate"),
                p,
            )
        })
        .sum::<f64>()
        / pts.len() as f64
}

#[test]
fn synthetic_problem_reaches_the_quantisation_floor() {
    let feats = [X, Y, SUM, DIFF];
    let pts = points(400, 7);
    for constructor in [Constructor::Bayesian, Constructor::Consonant] {
        let map = tracker(
            &feats,
            TrackSettings {
                constructor,
                estimator: PoseRule::Map,
                ..TrackSettings::default()
            },
        );
        let mean = tracker(
            &feats,
            TrackSettings {
                constructor,
                ..TrackSettings::default()
            },
        );
        let e_map = mean_error(&map, &feats, &pts);
        let e_mean = mean_error(&mean, &feats, &pts);
        eprintln!("{constructor:?}: map {e_map:.4}, weighted mean {e_mean:.4}");
        // Nearest-node floor for a regular mesh: 0.3826 ε on average.
        assert!((0.33..0.43).contains(&e_map), "MAP error {e_map}");
        assert!(
            e_mean < 0.3826 && e_mean < e_map,
            "weighted mean {e_mean} vs MAP {e_map}"
        );
    }
}

/// The reference: extend every feature of the group onto the sample poses and combine with the
/// general Dempster's rule.
fn reference(
    t: &Tracker,
    constructor: Constructor,
    lik: &[Option<Vec<f64>>],
    group: &[usize],
) -> (f64, MassFunction) {
    let exts: Vec<MassFunction> = group
        .iter()
        .map(|&i| {
            let m = from_likelihoods(constructor, lik[i].as_ref().unwrap())
                .unwrap()
                .mass;
            t.model().features()[i].refining.extend(&m).unwrap()
        })
        .collect();
    let c = dempster_all(&exts).unwrap();
    (c.conflict_level, c.mass.expect("finite conflict"))
}

#[test]
fn fast_path_equals_general_combination() {
    let feats = [X, Y, X_COARSE, Y_COARSE, SUM, DIFF];
    for constructor in [Constructor::Bayesian, Constructor::Consonant] {
        for estimator in [PoseRule::WeightedMean, PoseRule::Pignistic, PoseRule::Map] {
            let t = tracker(
                &feats,
                TrackSettings {
                    constructor,
                    estimator,
                    ..TrackSettings::default()
                },
            );
            for p in points(15, 11) {
                let lik = frame(&feats, p);
                let est = t.track(&lik).unwrap();
                assert_eq!(est.group, (0..feats.len()).collect::<Vec<_>>());
                let (level, m) = reference(&t, constructor, &lik, &est.group);
                let k = est.conflict_level.unwrap();
                assert!((k - level).abs() < 1e-12 * (1.0 + level), "{k} vs {level}");
                assert!(
                    (t.full_conflict_level(&lik).unwrap() - level).abs() < 1e-12 * (1.0 + level)
                );
                let rp = relative_plausibility(&m).unwrap();
                for (a, b) in est.plausibility.iter().zip(&rp) {
                    assert!((a - b).abs() < 1e-12, "{a} vs {b}");
                }
                let want = match estimator {
                    PoseRule::WeightedMean => pointwise_estimate(&rp, t.model().poses()).unwrap(),
                    PoseRule::Pignistic => {
                        pointwise_estimate(&pignistic(&m).unwrap(), t.model().poses()).unwrap()
                    }
                    PoseRule::Map => {
                        let best = (0..rp.len()).fold(0, |b, q| if rp[q] > rp[b] { q } else { b });
                        t.model().poses()[best]
                    }
                };
                let got = est.estimate.unwrap();
                assert!(dist(got, want) < 1e-9, "{estimator:?}: {got:?} vs {want:?}");
            }
        }
    }
}

#[test]
fn pairwise_conflicts_equal_the_general_combination() {
    let feats = [X, Y, X_COARSE, SUM, DIFF];
    for constructor in [Constructor::Bayesian, Constructor::Consonant] {
        let t = tracker(
            &feats,
            TrackSettings {
                constructor,
                ..TrackSettings::default()
            },
        );
        let p = [4.3, 12.8];
        let mut lik = frame(&feats, p);
        lik[0] = Some(X.likelihoods(16.0)); // corrupted: pairwise conflicts become large
        let k = t.pairwise_conflicts(&lik).unwrap();
        for (i, row) in k.iter().enumerate() {
            for (j, kij) in row.iter().enumerate().skip(i + 1) {
                let (level, _) = reference(&t, constructor, &lik, &[i, j]);
                let got = kij.unwrap();
                assert!(
                    (got - level).abs() < 1e-9 * (1.0 + level),
                    "{constructor:?} {i},{j}: {got} vs {level}"
                );
            }
        }
    }
}

#[test]
fn corrupted_feature_is_left_out_and_estimate_stays_close() {
    let feats = [X, Y, X_COARSE, Y_COARSE, SUM, DIFF];
    let pts = points(60, 23);
    for constructor in [Constructor::Bayesian, Constructor::Consonant] {
        let everything = tracker(
            &feats,
            TrackSettings {
                constructor,
                ..TrackSettings::default()
            },
        );
        // The threshold applies to group levels too: just above the clean frames' levels.
        let threshold = 1.05
            * pts
                .iter()
                .map(|&p| everything.full_conflict_level(&frame(&feats, p)).unwrap())
                .fold(0.0f64, f64::max);
        assert!(threshold > 0.0 && threshold.is_finite());
        let t = tracker(
            &feats,
            TrackSettings {
                constructor,
                conflict_threshold: ConflictLevel::Finite(threshold),
                ..TrackSettings::default()
            },
        );
        let (mut excluded, mut err_gated, mut err_open) = (0, 0.0, 0.0);
        for (n, &p) in pts.iter().enumerate() {
            let clean = t.track(&frame(&feats, p)).unwrap();
            let mut lik = frame(&feats, p);
            // Every other frame, the fine x feature reports x shifted by 10 mm.
            if n % 2 == 1 {
                let wrong = if p[0] < 9.5 { p[0] + 10.0 } else { p[0] - 10.0 };
                lik[0] = Some(X.likelihoods(wrong));
            } else {
                assert_eq!(
                    clean.group.len(),
                    feats.len(),
                    "clean frames keep every feature"
                );
                continue;
            }
            let k = t.pairwise_conflicts(&lik).unwrap();
            let worst = (1..feats.len())
                .filter_map(|j| k[0][j])
                .fold(0.0f64, f64::max);
            let gated = t.track(&lik).unwrap();
            if worst > threshold {
                excluded += 1;
                assert!(
                    !gated.group.contains(&0),
                    "corrupted feature kept: {:?}",
                    gated.group
                );
                assert!(gated.flags.excluded.contains(&0));
            }
            let e = gated.estimate.unwrap();
            err_gated += dist(e, p);
            err_open += dist(everything.track(&lik).unwrap().estimate.unwrap(), p);
            assert!(
                dist(e, clean.estimate.unwrap()) < 1.5,
                "{p:?}: {e:?} vs clean {:?}",
                clean.estimate
            );
        }
        let frames = (pts.len() / 2) as f64;
        eprintln!(
            "{constructor:?}: excluded {excluded}, gated {:.3}, open {:.3}",
            err_gated / frames,
            err_open / frames
        );
        assert!(
            excluded as f64 >= 0.9 * frames,
            "excluded on {excluded} of {frames} frames"
        );
        assert!(
            err_gated < 0.5 * err_open,
            "gating helps: {err_gated} vs {err_open}"
        );
    }
}

#[test]
fn bad_inputs_give_flags_not_panics() {
    // Every pair of these features has some positive conflict (no pair is independent).
    let feats = [X, X_COARSE, SUM, DIFF];
    let t = Tracker::new(
        model(&feats, &[Some(2.0), Some(0.7), None, Some(0.9)]),
        TrackSettings {
            conflict_threshold: ConflictLevel::Finite(0.0),
            ..TrackSettings::default()
        }
        .check()
        .unwrap(),
    )
    .unwrap();
    let p = [6.2, 9.9];
    // Nothing usable.
    let none = t.track(&[None, None, None, None]).unwrap();
    assert_eq!(none.estimate, None);
    assert!(none.flags.no_usable_feature && none.flags.any());
    assert_eq!(none.flags.missing().collect::<Vec<_>>(), vec![0, 1, 2, 3]);
    let nan = t
        .track(&[
            Some(vec![f64::NAN; 20]),
            Some(vec![0.0; 7]),
            Some(vec![1.0; 3]),
            Some(vec![-1.0; 10]),
        ])
        .unwrap();
    assert_eq!(nan.estimate, None);
    assert_eq!(
        nan.flags.unusable,
        vec![
            (0, FeatureIssue::Likelihood(LikelihoodIssue::NonFinite)),
            (1, FeatureIssue::Likelihood(LikelihoodIssue::AllZero)),
            (
                2,
                FeatureIssue::WrongLength {
                    expected: 10,
                    found: 3
                }
            ),
            (3, FeatureIssue::Likelihood(LikelihoodIssue::Negative)),
        ]
    );
    // Wrong number of entries is an error, not a panic.
    assert!(t.track(&[None]).is_err());
    // Threshold 0: every pair with positive conflict is incompatible → fallback to the feature with
    // the lowest validation error (feature 1, 0.7 mm), flagged.
    let k = t.pairwise_conflicts(&frame(&feats, p)).unwrap();
    assert!((0..4).all(|i| (0..4).all(|j| i == j || k[i][j].unwrap() > 0.0)));
    let mut lik = frame(&feats, p);
    let fb = t.track(&lik).unwrap();
    assert!(fb.flags.fallback);
    assert_eq!(fb.group, vec![1]);
    assert_eq!(fb.flags.excluded, vec![0, 2, 3]);
    // The coarse x feature alone: x within its bin, y at the middle of the mesh.
    let e = fb.estimate.unwrap();
    assert!(
        (e[0] - p[0]).abs() < X_COARSE.width() && (e[1] - 9.5).abs() < 1e-9,
        "{e:?}"
    );
    // With feature 1 missing, the next best validation error (feature 3).
    lik[1] = None;
    let fb = t.track(&lik).unwrap();
    assert!(fb.flags.fallback);
    assert_eq!(fb.group, vec![3]);
    // One usable feature is not a fallback.
    let single = t
        .track(&[None, Some(X_COARSE.likelihoods(p[0])), None, None])
        .unwrap();
    assert!(!single.flags.fallback);
    assert_eq!(single.group, vec![1]);
    assert!(single.estimate.is_some());
    // Infinite pairwise conflict is never an edge, even with an infinite threshold.
    let open = tracker(&[X, X_COARSE], TrackSettings::default());
    let mut sharp = vec![0.0; 20];
    sharp[0] = 1.0;
    let mut far = vec![0.0; 7];
    far[6] = 1.0;
    let est = open.track(&[Some(sharp), Some(far)]).unwrap();
    assert!(est.flags.fallback);
    assert_eq!(est.group, vec![0]);
    assert_eq!(
        open.pairwise_conflicts(&[Some(vec![1.0; 20]), None])
            .unwrap()[0][1],
        None
    );
}

/// A random model on `n_poses` sample poses: some features are relabelled copies of earlier
/// ones (so the same state tuple recurs across features and groups), and few states on many
/// poses make cells of many poses.
fn random_model(rng: &mut ChaCha8Rng) -> (TrackerModel, Vec<usize>) {
    let n_poses = rng.random_range(6..30);
    let n_features = rng.random_range(2..6);
    let poses: Vec<[f64; 2]> = (0..n_poses)
        .map(|q| [q as f64, (q * q % 7) as f64])
        .collect();
    let mut assignments: Vec<(usize, Vec<usize>)> = Vec::new();
    for i in 0..n_features {
        if i > 0 && rng.random_bool(0.3) {
            let (n, a) = assignments[rng.random_range(0..i)].clone();
            let shift = rng.random_range(0..n);
            assignments.push((n, a.iter().map(|&s| (s + shift) % n).collect()));
        } else {
            let n = rng.random_range(2..5);
            // The first n poses take every state, so the refining is valid.
            let a = (0..n_poses)
                .map(|q| if q < n { q } else { rng.random_range(0..n) })
                .collect();
            assignments.push((n, a));
        }
    }
    let states = assignments.iter().map(|(n, _)| *n).collect();
    let features = assignments
        .iter()
        .map(|(n, a)| TrackedFeature {
            refining: Refining::from_assignment(*n, a).unwrap(),
            validation_error: None,
        })
        .collect();
    (TrackerModel::new(poses, features).unwrap(), states)
}

mod fast_paths {
    use super::*;
    use evitrack::evidence::conflict_level_all;
    use proptest::prelude::{any, prop_assert, prop_assert_eq, proptest, ProptestConfig};
    use rand::Rng;

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]
        /// Every group's level of conflict and every sample pose's relative plausibility, from
        /// the tracker's exact shortcuts on cells, equal Dempster's rule on the measurement
        /// functions extended to the individual sample poses.
        #[test]
        fn every_group_equals_dempster_on_the_sample_poses(seed in any::<u64>(), consonant in any::<bool>()) {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let (model, states) = random_model(&mut rng);
            let constructor = if consonant { Constructor::Consonant } else { Constructor::Bayesian };
            let settings = TrackSettings { constructor, ..TrackSettings::default() };
            let t = Tracker::new(model.clone(), settings.check().unwrap()).unwrap();
            let lik: Vec<Vec<f64>> = states
                .iter()
                .map(|&n| {
                    let mut g: Vec<f64> = (0..n)
                        .map(|_| if rng.random_bool(0.3) { 0.0 } else { rng.random_range(0.0..1.0) })
                        .collect();
                    g[rng.random_range(0..n)] = 1.0;
                    g
                })
                .collect();
            let f = states.len();
            for group in 1u32..1 << f {
                let members: Vec<usize> = (0..f).filter(|i| group >> i & 1 == 1).collect();
                let only: Vec<Option<Vec<f64>>> = (0..f)
                    .map(|i| (group >> i & 1 == 1).then(|| lik[i].clone()))
                    .collect();
                let on_poses: Vec<MassFunction> = members
                    .iter()
                    .map(|&i| {
                        let m = from_likelihoods(constructor, &lik[i]).unwrap().mass;
                        model.features()[i].refining.extend(&m).unwrap()
                    })
                    .collect();
                let reference = conflict_level_all(&on_poses).unwrap();
                let fast = t.full_conflict_level(&only).unwrap();
                if reference.is_finite() {
                    prop_assert!((fast - reference).abs() <= 1e-9 * (1.0 + reference),
                        "group {members:?}: fast {fast}, Dempster {reference}");
                    let combined = dempster_all(&on_poses).unwrap().mass.unwrap();
                    let pl = combined.contour();
                    let total: f64 = pl.iter().sum();
                    let est = t.track(&only).unwrap();
                    prop_assert_eq!(&est.group, &members);
                    for (q, (&got, &want)) in est.plausibility.iter().zip(&pl).enumerate() {
                        prop_assert!((got - want / total).abs() <= 1e-9,
                            "group {members:?}, pose {q}: {got} vs {}", want / total);
                    }
                } else {
                    prop_assert_eq!(fast, f64::INFINITY, "group {:?}", members);
                }
            }
        }
    }
}
