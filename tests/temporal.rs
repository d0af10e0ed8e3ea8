//! The temporal methods through the seam (issue 17): the temporal evidential tracker, the
//! continuous tracker over time and the particle filter on a synthetic path with a burst of dropped frames — predicted estimates,
//! determinism, model files that round-trip bit for bit and corrupted ones that are named.

use evitrack::estimator::test_maps::{feature_row, workspace_mesh};
use evitrack::estimator::{
    ContinuousTemporal, EstimatorError, EstimatorSettings, Labelled, Method, ParticleFilter,
    PoseEstimate, PoseEstimator, TemporalEvidential, TemporalSettings, TrainingSet,
};
use evitrack::model::{ModelSettings, StateCounts};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

const FEATURES: usize = 4;
const NOISE: f64 = 0.01;
/// Frames a filter may take to settle before its errors are checked.
const SETTLE: usize = 6;
/// Frames 12 to 16 of the path are dropped.
const DROPPED: std::ops::Range<usize> = 12..17;

struct Data {
    names: Vec<String>,
    poses: Vec<[f64; 2]>,
    rows: Vec<Vec<Option<f64>>>,
    valid_poses: Vec<[f64; 2]>,
    valid_rows: Vec<Vec<Option<f64>>>,
    valid_times: Vec<f64>,
}

/// A straight path at 6 mm/s, 10 frames/s, from (−7, 40) towards (7, 55).
fn path(frames: usize) -> (Vec<f64>, Vec<[f64; 2]>) {
    let direction = [14.0 / 20.5, 15.0 / 20.5];
    (0..frames)
        .map(|k| {
            let t = k as f64 / 10.0;
            (
                t,
                [-7.0 + 6.0 * t * direction[0], 40.0 + 6.0 * t * direction[1]],
            )
        })
        .unzip()
}

impl Data {
    fn new() -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let poses = workspace_mesh(20);
        let rows = poses
            .iter()
            .map(|&q| feature_row(FEATURES, q, NOISE, &mut rng))
            .collect();
        let (valid_times, valid_poses) = path(20);
        let valid_rows = valid_poses
            .iter()
            .map(|&q| feature_row(FEATURES, q, NOISE, &mut rng))
            .collect();
        Self {
            names: (0..FEATURES).map(|i| format!("f{i}")).collect(),
            poses,
            rows,
            valid_poses,
            valid_rows,
            valid_times,
        }
    }

    fn training(&self) -> TrainingSet<'_> {
        let mut data = TrainingSet::new(
            &self.names,
            Labelled {
                poses: &self.poses,
                rows: &self.rows,
            },
        );
        data.validation = Some(Labelled {
            poses: &self.valid_poses,
            rows: &self.valid_rows,
        });
        data.validation_times = Some(&self.valid_times);
        data
    }
}

fn settings(reliability: Option<f64>) -> EstimatorSettings {
    let mut settings = EstimatorSettings::default();
    settings.evidential.model = ModelSettings {
        states: StateCounts::All(6),
        ..ModelSettings::default()
    };
    settings.temporal = TemporalSettings {
        max_speed: 20.0,
        reliability,
        ..TemporalSettings::default()
    };
    settings.particle_filter.particles = 1000;
    settings
}

/// The test path's truth and its estimates, frames in `DROPPED` lost.
fn run(estimator: &dyn PoseEstimator) -> (Vec<[f64; 2]>, Vec<PoseEstimate>) {
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let (times, truth) = path(30);
    let mut motion = estimator.start_motion();
    let estimates = times
        .iter()
        .zip(&truth)
        .enumerate()
        .map(|(k, (&t, &q))| {
            let row = if DROPPED.contains(&k) {
                vec![None; FEATURES]
            } else {
                feature_row(FEATURES, q, NOISE, &mut rng)
            };
            motion.next(t, &row).unwrap()
        })
        .collect();
    (truth, estimates)
}

fn bits(estimates: &[PoseEstimate]) -> Vec<[u64; 2]> {
    estimates
        .iter()
        .map(|e| e.pose.map_or([0; 2], |p| [p[0].to_bits(), p[1].to_bits()]))
        .collect()
}

/// Dropped frames get the prediction, flagged, closer to the path than the last estimate;
/// other frames (after the first `SETTLE`, which a filter needs to settle)
/// are measured and track the path.
fn check_predictions(method: &str, truth: &[[f64; 2]], estimates: &[PoseEstimate], max_error: f64) {
    let last = estimates[DROPPED.start - 1].pose.unwrap();
    for (k, e) in estimates.iter().enumerate() {
        assert_eq!(
            e.flags.predicted,
            DROPPED.contains(&k),
            "{method} frame {k}"
        );
        let pose = e
            .pose
            .unwrap_or_else(|| panic!("{method} frame {k}: no estimate"));
        if DROPPED.contains(&k) {
            // The motion model carries the pose on along the path: closer than holding the last
            // estimate would be.
            let error = (pose[0] - truth[k][0]).hypot(pose[1] - truth[k][1]);
            let held = (last[0] - truth[k][0]).hypot(last[1] - truth[k][1]);
            assert!(
                error < held,
                "{method} frame {k}: predicted {error} mm off, holding {held}"
            );
        } else if k >= SETTLE {
            let error = (pose[0] - truth[k][0]).hypot(pose[1] - truth[k][1]);
            assert!(error < max_error, "{method} frame {k}: error {error}");
        }
    }
}

/// The estimates are the same on a second run and after a model-file round trip through
/// `from_json`; the file with `field` edited from `good` to `bad` is refused, naming the field.
fn check_model_file<T: PoseEstimator>(
    estimator: &dyn PoseEstimator,
    estimates: &[PoseEstimate],
    from_json: fn(&str) -> Result<T, EstimatorError>,
    (field, good, bad): (&str, &str, &str),
) {
    assert_eq!(bits(&run(estimator).1), bits(estimates), "deterministic");
    // The method's own file (its calibration rides beside it) round-trips through `from_json`.
    let inner = evitrack::estimator::underlying(estimator);
    let text = inner.to_json().unwrap();
    let loaded = from_json(&text).unwrap();
    assert_eq!(bits(&run(&loaded).1), bits(&run(inner).1), "round trip");
    let broken = text.replace(
        &format!("\"{field}\": {good}"),
        &format!("\"{field}\": {bad}"),
    );
    assert_ne!(broken, text, "`{field}: {good}` is in the file");
    let error = match from_json(&broken) {
        Ok(_) => panic!("`{field}: {bad}` was accepted"),
        Err(e) => e.to_string(),
    };
    assert!(error.contains(field), "{error}");
}

#[test]
fn the_temporal_evidential_tracker_predicts_lost_frames_and_round_trips() {
    let data = Data::new();
    let fitted = TemporalEvidential::fit(
        &settings(None).evidential,
        &settings(None).temporal,
        &data.training(),
    )
    .unwrap();
    let (alpha, learned) = fitted.reliability();
    assert!(learned, "learned on the validation motion");
    assert!(evitrack::estimator::RELIABILITY_CANDIDATES.contains(&alpha));
    // On a straight path the velocity line helps, so it is kept; a file whose line is neither
    // the settings' nor 0 is refused, naming the field.
    assert_eq!(fitted.velocity_frames(), 3);
    let text = fitted.to_json().unwrap();
    let broken = text.replace("\n  \"velocity_frames\": 3,", "\n  \"velocity_frames\": 2,");
    assert_ne!(broken, text);
    let error = TemporalEvidential::from_json(&broken)
        .unwrap_err()
        .to_string();
    assert!(error.contains("velocity_frames"), "{error}");

    let estimator = Method::EVIDENTIAL_TEMPORAL
        .fit(&settings(Some(0.9)), &data.training())
        .unwrap();
    let (truth, estimates) = run(estimator.as_ref());
    check_predictions("evidential_temporal", &truth, &estimates, 3.0);
    // The per-frame tracker has no estimate where the frames were lost.
    let per_frame = Method::EVIDENTIAL
        .fit(&settings(Some(0.9)), &data.training())
        .unwrap();
    let (_, alone) = run(per_frame.as_ref());
    assert!(DROPPED.clone().all(|k| alone[k].pose.is_none()));

    check_model_file(
        estimator.as_ref(),
        &estimates,
        TemporalEvidential::from_json,
        ("reliability", "0.9", "2.0"),
    );
}

#[test]
fn the_particle_filter_tracks_predicts_lost_frames_and_round_trips() {
    let data = Data::new();
    // σ given: learned on this 20-frame validation path it is 32 mm/s (the settling frames
    // weigh most in its error), and after the 5 lost frames that spread reaches a second mode
    // of these maps 10 mm away (frame 17, measured). Learning is tested below.
    let mut s = settings(None);
    s.particle_filter.motion_noise = Some(8.0);
    let estimator = Method::PARTICLE_FILTER.fit(&s, &data.training()).unwrap();
    let (truth, estimates) = run(estimator.as_ref());
    check_predictions("particle_filter", &truth, &estimates, 1.5);
    check_model_file(
        estimator.as_ref(),
        &estimates,
        ParticleFilter::from_json,
        ("particles", "1000", "0"),
    );
}

/// σ and ε are learned on the validation motion among their candidates, kept when given,
/// defaulted without a validation motion, and written to the model file, whose earlier format
/// (version 4, the recovery off by default) is refused by name.
#[test]
fn the_particle_filter_learns_its_motion_noise_and_outlier_share() {
    let data = Data::new();
    let s = settings(None);
    let fit = |particle: &evitrack::estimator::ParticleSettings, data: &TrainingSet| {
        ParticleFilter::fit(particle, &s.temporal, &s.continuous, data).unwrap()
    };
    let learned = fit(&s.particle_filter, &data.training());
    let (sigma, sigma_learned) = learned.motion_noise();
    let (eps, eps_learned) = learned.outlier_share();
    assert!(sigma_learned && eps_learned);
    assert!(
        [1.0, 2.0, 4.0, 8.0, 16.0, 32.0, 64.0].contains(&sigma),
        "{sigma}"
    );
    assert!([0.001, 0.01, 0.05, 0.2].contains(&eps), "{eps}");

    let mut given = s.particle_filter.clone();
    given.motion_noise = Some(3.0);
    given.outlier_share = Some(0.07);
    let kept = fit(&given, &data.training());
    assert_eq!(kept.motion_noise(), (3.0, false));
    assert_eq!(kept.outlier_share(), (0.07, false));

    let mut alone = data.training();
    alone.validation = None;
    alone.validation_times = None;
    let defaults = fit(&s.particle_filter, &alone);
    assert_eq!(defaults.motion_noise(), (16.0, false));
    assert_eq!(defaults.outlier_share(), (0.05, false));

    let text = learned.to_json().unwrap();
    let loaded = ParticleFilter::from_json(&text).unwrap();
    assert_eq!(loaded.motion_noise(), (sigma, true));
    assert_eq!(loaded.outlier_share(), (eps, true));
    let broken = text.replace(
        &format!("\"motion_noise\": {sigma:?}"),
        "\"motion_noise\": -1.0",
    );
    assert_ne!(broken, text);
    let error = ParticleFilter::from_json(&broken).unwrap_err().to_string();
    assert!(error.contains("motion_noise"), "{error}");
    let old = text.replace("\"format_version\": 5", "\"format_version\": 4");
    assert_ne!(old, text);
    let error = ParticleFilter::from_json(&old).unwrap_err().to_string();
    assert!(error.contains("version") && error.contains('4'), "{error}");
}

#[test]
fn the_continuous_tracker_over_time_predicts_lost_frames_and_round_trips() {
    let data = Data::new();
    let fitted = ContinuousTemporal::fit(
        &settings(None).continuous,
        &settings(None).temporal,
        &data.training(),
    )
    .unwrap();
    assert!(fitted.reliability().1, "learned on the validation motion");
    let estimator = Method::CONTINUOUS_TEMPORAL
        .fit(&settings(Some(0.9)), &data.training())
        .unwrap();
    let (truth, estimates) = run(estimator.as_ref());
    // Frame 10 is ambiguous on these synthetic maps (3.3 mm per frame too).
    check_predictions("continuous_temporal", &truth, &estimates, 4.0);
    // On the measured frames it is no worse than the per-frame tracker, which has no estimate
    // where the frames were lost.
    let per_frame = Method::CONTINUOUS
        .fit(&settings(Some(0.9)), &data.training())
        .unwrap();
    let (_, alone) = run(per_frame.as_ref());
    assert!(DROPPED.clone().all(|k| alone[k].pose.is_none()));
    let measured_error = |e: &[PoseEstimate]| -> f64 {
        (0..truth.len())
            .filter(|k| !DROPPED.contains(k))
            .map(|k| {
                let p = e[k].pose.unwrap();
                (p[0] - truth[k][0]).hypot(p[1] - truth[k][1])
            })
            .sum()
    };
    assert!(measured_error(&estimates) <= measured_error(&alone) * 1.01);
    check_model_file(
        estimator.as_ref(),
        &estimates,
        ContinuousTemporal::from_json,
        ("reliability", "0.9", "-1.0"),
    );
}

#[test]
fn without_a_velocity_line_predictions_stay_within_reach_of_the_last_estimate() {
    let data = Data::new();
    let mut still = settings(Some(0.9));
    still.temporal.velocity_frames = 0;
    for method in [
        Method::EVIDENTIAL_TEMPORAL,
        Method::CONTINUOUS_TEMPORAL,
        Method::PARTICLE_FILTER,
    ] {
        let estimator = method.fit(&still, &data.training()).unwrap();
        let (_, estimates) = run(estimator.as_ref());
        let last = estimates[DROPPED.start - 1].pose.unwrap();
        for k in DROPPED {
            assert!(estimates[k].flags.predicted, "{method:?} frame {k}");
            let pose = estimates[k].pose.unwrap();
            let reach = 20.0 * 0.1 * (k + 1 - DROPPED.start) as f64;
            let moved = (pose[0] - last[0]).hypot(pose[1] - last[1]);
            assert!(
                moved <= reach + 1e-9,
                "{method:?} frame {k}: moved {moved} > {reach}"
            );
        }
        // The continuous tracker holds the last estimate exactly.
        if method == Method::CONTINUOUS_TEMPORAL {
            assert!(DROPPED.clone().all(|k| estimates[k].pose == Some(last)));
        }
    }
}

/// `scenarios/coarse.toml` (issue 27): on coarse frames (2 mm mesh, 4 states) the velocity line
/// drifted and the temporal tracker was worse than per frame. The validation motion now turns the
/// line off, and the temporal tracker is below the per-frame one on every seed of 1–5; seed 1 is
/// held to the bands of its expectations (±3 % of its measured errors, both directions).
#[test]
fn on_coarse_frames_the_past_does_not_hurt() {
    use evitrack::experiment::run_all;
    use evitrack::scenario::{ScenarioSet, SeedList};
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/scenarios/coarse.toml");
    let set = ScenarioSet::load(std::path::Path::new(path)).unwrap();
    let runs = set.seeded(Some(&SeedList::Count(5))).unwrap();
    let outputs = run_all(&runs, 2, crate::bench(), &|_, _, _, _| {});
    for (run, output) in runs.iter().zip(outputs) {
        let output = output.unwrap_or_else(|e| panic!("{} failed: {e}", run.name()));
        let summary = &output.summary;
        let mean = |m: &str| summary.method(m).and_then(|m| m.error).unwrap().mean;
        let (per_frame, temporal) = (mean("evidential"), mean("evidential_temporal"));
        let seed = summary.seed;
        assert!(
            temporal < per_frame,
            "{} seed {seed}: {temporal} ≥ {per_frame}",
            run.name()
        );
        let fitted = (output.estimators.iter())
            .find_map(|e| {
                let inner = evitrack::estimator::underlying(e.as_ref());
                (inner as &dyn std::any::Any).downcast_ref::<TemporalEvidential>()
            })
            .unwrap();
        assert_eq!(fitted.velocity_frames(), 0, "{} seed {seed}", run.name());
        if seed == 1 {
            let missed = summary.regressions();
            assert!(missed.is_empty(), "{missed:#?}");
        }
    }
}

/// A small scenario with the filter's recovery on (`ESTIMATORS` and `LEARN` filled in): a
/// bright box strikes 30 % of the frames, where the recovery's single-frame fit (the filter's
/// maps) searches for the subset under the learned threshold.
const BESIDE: &str = r#"
name = "beside"
seed = 1
continuous = { learn_threshold = LEARN }
estimators = ESTIMATORS
[particle_filter]
particles = 1000
recovery_share = 0.3
[sample]
motion = { kind = "mesh", spacing = 2.0 }
[validation]
kind = "random_path"
seed = 11
speed = 6.0
duration = 3.0
fps = 20.0
[[tests]]
kind = "random_path"
seed = 23
speed = 6.0
duration = 3.0
fps = 20.0
[features.barycentre]
enabled = true
[[faults]]
kind = "occluder"
rect = [70, 40, 30, 30]
intensity = 255
share = 0.3
"#;

/// Each method's frames (as JSON: every bit, NaN included) of the `BESIDE` run with
/// `estimators` ([`records_of`]).
fn frames_beside(estimators: &[&str], learn: bool) -> Vec<(String, String)> {
    let list = format!("{estimators:?}");
    let text = BESIDE
        .replace("ESTIMATORS", &list)
        .replace("LEARN", &learn.to_string());
    let records = records_of(&text);
    estimators
        .iter()
        .map(|&m| {
            let own: Vec<_> = (records.iter()).filter(|r| r.method == m).collect();
            assert_eq!(own.len(), 60, "{m}");
            (m.to_string(), serde_json::to_string(&own).unwrap())
        })
        .collect()
}

/// The frames of the scenario `text`, run on a workbench of its own that is dropped before
/// returning, so nothing it fitted stays live for the next run to share.
fn records_of(text: &str) -> Vec<evitrack::report::FrameRecord> {
    let set = evitrack::scenario::ScenarioSet::parse(text, "beside").unwrap();
    let bench = evitrack::experiment::Workbench::new();
    let output = evitrack::experiment::run_all(&[set.base], 1, &bench, &|_, _, _, _| {})
        .pop()
        .unwrap()
        .unwrap();
    output.records
}

/// A method's numbers do not depend on which others run beside it: the filter with its
/// recovery (its single-frame fit on maps the continuous fits may share), the continuous
/// tracker and its temporal form, each alone against all three in one run. What the filter's
/// recovery does depend on is its own `[continuous]` section (the threshold of that fit).
#[test]
fn each_methods_frames_are_the_same_alone_and_beside_the_others() {
    let methods = ["continuous", "continuous_temporal", "particle_filter"];
    let together = frames_beside(&methods, true);
    for (method, frames) in &together {
        let alone = frames_beside(&[method.as_str()], true);
        assert!(alone[0] == (method.clone(), frames.clone()), "{method}");
    }
    let unlearned = frames_beside(&["particle_filter"], false);
    assert_ne!(
        unlearned[0], together[2],
        "the threshold reaches the recovery"
    );
}

/// Each clean frame's error right after a struck one and every frame's error before the first
/// struck one, per temporal method, in the `BESIDE` run (a bright box on 30 % of the frames)
/// with `temporal.incoherent_frames` as given.
fn errors_around_struck(incoherent_frames: &str) -> Vec<(String, Vec<f64>, Vec<u64>)> {
    let methods = ["continuous_temporal", "evidential_temporal"];
    // The 1 mm mesh, 200 test frames, 400 validation frames and learned thresholds, as
    // `confidence.toml` (without a threshold no frame is beyond it).
    let text = "learn_threshold = true".to_string()
        + &BESIDE
            .replace("ESTIMATORS", &format!("{methods:?}"))
            .replace("LEARN", "true")
            .replace("spacing = 2.0", "spacing = 1.0")
            .replacen("duration = 3.0", "duration = 20.0", 1)
            .replacen("duration = 3.0", "duration = 10.0", 1)
        + &format!(
            "[model]\nstates = 24\n[temporal]\nincoherent_frames = \"{incoherent_frames}\"\n"
        );
    let records = records_of(&text);
    (methods.iter())
        .map(|&m| {
            let own: Vec<_> = (records.iter()).filter(|r| r.method == m).collect();
            let struck = |k: usize| own[k].faults.as_ref().is_some_and(|f| !f.faults.is_empty());
            let first = (0..own.len()).find(|&k| struck(k)).expect("a struck frame");
            let after: Vec<f64> = (1..own.len())
                .filter(|&k| struck(k - 1) && !struck(k))
                .map(|k| own[k].error.expect("an estimate"))
                .collect();
            let before = (own[..first].iter())
                .map(|r| r.error.expect("an estimate").to_bits())
                .collect();
            (m.to_string(), after, before)
        })
        .collect()
}

/// A bright box corrupts every global feature: carried as any frame, a struck frame's wrong
/// pose joins the next clean frame (the past counts as half the features) and pulls it off.
/// Outweighed by that frame's agreeing features (the default) or not carried, the clean frame's
/// error falls; the frames before the first struck one do not move.
#[test]
fn frames_whose_features_disagree_do_not_pull_the_next_clean_frame_off() {
    let carried = errors_around_struck("carried");
    for policy in ["outweighed", "skipped"] {
        let mended = errors_around_struck(policy);
        for ((method, pulled, early), (_, kept, early_mended)) in carried.iter().zip(&mended) {
            assert_eq!(early, early_mended, "{method}, {policy}");
            assert!(
                pulled.len() >= 5,
                "{method}: {} frames after a struck one",
                pulled.len()
            );
            let mean = |e: &[f64]| e.iter().sum::<f64>() / e.len() as f64;
            assert!(
                mean(kept) < 0.8 * mean(pulled),
                "{method}, {policy}: clean frames after a struck one {} mm off, carried {}",
                mean(kept),
                mean(pulled)
            );
        }
    }
}
