//! The conformance suite: what every registered method must do, checked on each one as
//! scikit-learn's `check_estimator` does. A new method gets every check by registering
//! (`tests/toy_method.rs` puts a toy method through it from its own file).
//!
//! Checked: a deterministic fit; a model file that round-trips bit for bit and gives the same
//! estimates; missing, non-finite and miscounted features; a corrupted, truncated or foreign
//! file refused naming its path; poses beyond the workspace refused; consistent flags (the
//! missing features named, excluded and combined features disjoint, finite poses and radii);
//! `start_motion` of a per-frame method equal to its per-frame estimates, and deterministic for
//! every method.

use std::path::Path;

use evitrack::dataset::Rect;
use evitrack::estimator::test_maps::{feature_row, workspace_mesh};
use evitrack::estimator::{
    EstimatorError, EstimatorSettings, Labelled, Method, PoseEstimate, PoseEstimator, TrainingSet,
};
use evitrack::model::{ModelSettings, StateCounts};
use evitrack::model_file::Provenance;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

const FEATURES: usize = 4;
const NOISE: f64 = 0.01;
const WORKSPACE: Rect = Rect {
    x_min: -9.5,
    x_max: 9.5,
    y_min: 38.0,
    y_max: 57.0,
};

/// A small synthetic training set (a 12 × 12 mesh, a validation path with times) and test frames.
pub struct Data {
    names: Vec<String>,
    poses: Vec<[f64; 2]>,
    rows: Vec<Vec<Option<f64>>>,
    valid_poses: Vec<[f64; 2]>,
    valid_rows: Vec<Vec<Option<f64>>>,
    valid_times: Vec<f64>,
    /// Test frames: (time, truth, features).
    pub frames: Vec<(f64, [f64; 2], Vec<Option<f64>>)>,
}

/// A straight path at 6 mm/s, 10 frames/s, across the workspace.
fn path(frames: usize, from: [f64; 2]) -> Vec<(f64, [f64; 2])> {
    (0..frames)
        .map(|k| {
            let t = k as f64 / 10.0;
            (t, [from[0] + 4.1 * t, from[1] + 4.4 * t])
        })
        .collect()
}

impl Data {
    /// The data every method of the suite is fitted and run on.
    pub fn new() -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let poses = workspace_mesh(12);
        let rows = poses
            .iter()
            .map(|&q| feature_row(FEATURES, q, NOISE, &mut rng))
            .collect();
        let valid = path(20, [-8.0, 39.0]);
        let valid_rows = valid
            .iter()
            .map(|&(_, q)| feature_row(FEATURES, q, NOISE, &mut rng))
            .collect();
        let frames = path(12, [-6.0, 41.0])
            .into_iter()
            .map(|(t, q)| (t, q, feature_row(FEATURES, q, NOISE, &mut rng)))
            .collect();
        Self {
            names: (0..FEATURES).map(|i| format!("f{i}")).collect(),
            poses,
            rows,
            valid_poses: valid.iter().map(|v| v.1).collect(),
            valid_rows,
            valid_times: valid.iter().map(|v| v.0).collect(),
            frames,
        }
    }

    /// The training set, with the workspace declared in the provenance.
    pub fn training(&self) -> TrainingSet<'_> {
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
        data.provenance =
            Provenance::new(Some("conformance".into()), 7).with_workspace(Some(WORKSPACE));
        data
    }
}

/// Settings small enough for every method to fit in well under a second.
pub fn settings() -> EstimatorSettings {
    let mut settings = EstimatorSettings::default();
    settings.evidential.model = ModelSettings {
        states: StateCounts::All(4),
        ..ModelSettings::default()
    };
    settings.particle_filter.particles = 500;
    settings
}

fn bits(estimates: &[PoseEstimate]) -> Vec<Option<[u64; 2]>> {
    estimates
        .iter()
        .map(|e| e.pose.map(|p| [p[0].to_bits(), p[1].to_bits()]))
        .collect()
}

fn per_frame(estimator: &dyn PoseEstimator, data: &Data) -> Vec<PoseEstimate> {
    data.frames
        .iter()
        .map(|(_, _, row)| estimator.estimate(row).unwrap())
        .collect()
}

fn over_time(estimator: &dyn PoseEstimator, data: &Data) -> Vec<PoseEstimate> {
    let mut motion = estimator.start_motion();
    data.frames
        .iter()
        .map(|(t, _, row)| motion.next(*t, row).unwrap())
        .collect()
}

/// Moves the first pose of a model file (a field named like `poses`, `centre`, or the corners
/// `min`/`max` of the centre baseline's box, in an inner
/// model file too) to `to`; false when the file holds none.
fn move_first_pose(value: &mut serde_json::Value, to: [f64; 2]) -> bool {
    let is_pair = |v: &serde_json::Value| {
        v.as_array()
            .is_some_and(|p| p.len() == 2 && p.iter().all(|x| x.is_f64()))
    };
    match value {
        serde_json::Value::Object(map) => {
            for (key, v) in map.iter_mut() {
                if key == "provenance" {
                    continue;
                }
                if key.contains("pose") || ["centre", "min", "max"].contains(&key.as_str()) {
                    if is_pair(v) {
                        *v = serde_json::json!(to);
                        return true;
                    }
                    if let Some(items) = v
                        .as_array_mut()
                        .filter(|i| !i.is_empty() && i.iter().all(is_pair))
                    {
                        items[0] = serde_json::json!(to);
                        return true;
                    }
                }
                if move_first_pose(v, to) {
                    return true;
                }
            }
            false
        }
        serde_json::Value::Array(items) => items.iter_mut().any(|v| move_first_pose(v, to)),
        serde_json::Value::String(text) => {
            let Ok(mut inner) = serde_json::from_str::<serde_json::Value>(text) else {
                return false;
            };
            let moved = inner.is_object() && move_first_pose(&mut inner, to);
            if moved {
                *text = serde_json::to_string_pretty(&inner).unwrap();
            }
            moved
        }
        _ => false,
    }
}

/// Loads `text` as `method`'s file at `path` and expects a refusal that names the path.
fn refused(method: Method, path: &Path, text: &str, what: &str) -> String {
    std::fs::write(path, text).unwrap();
    let error = match evitrack::estimator::load_text(method, path, text) {
        Ok(_) => panic!("{method}: {what} was loaded"),
        Err(e) => e.to_string(),
    };
    assert!(
        error.contains(&path.display().to_string()),
        "{method}: {what}: the error does not name the file: {error}"
    );
    error
}

/// Every check of the suite on one method.
pub fn check_method(method: Method, settings: &EstimatorSettings, data: &Data, other: Method) {
    let training = data.training();
    let fitted = method.fit(settings, &training).unwrap();
    assert_eq!(fitted.method(), method.name());
    assert_eq!(fitted.feature_names(), data.names.as_slice());

    // A deterministic fit.
    let json = fitted.to_json().unwrap();
    let again = method.fit(settings, &training).unwrap();
    assert_eq!(json, again.to_json().unwrap(), "{method}: two fits differ");

    // The model file round-trips bit for bit, through the method's entry and through `load`.
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("model.json");
    std::fs::write(&file, &json).unwrap();
    let loaded = evitrack::estimator::load(&file).unwrap();
    assert_eq!(loaded.method(), method.name());
    assert_eq!(
        loaded.to_json().unwrap(),
        json,
        "{method}: round trip changed the file"
    );
    let by_entry = evitrack::estimator::load_text(method, &file, &json).unwrap();
    assert_eq!(by_entry.to_json().unwrap(), json);
    // The calibration learned on the validation motion rides in the file; a broken one is refused.
    let value: serde_json::Value = serde_json::from_str(&json).unwrap();
    let calibration = value
        .get("calibration")
        .expect("fitted with a validation motion");
    assert_eq!(calibration["validation_frames"], data.valid_rows.len());
    let mut broken = value.clone();
    broken["calibration"]["floor"] = serde_json::json!(-1.0);
    let broken = serde_json::to_string(&broken).unwrap();
    let error = refused(
        method,
        &dir.path().join("broken.json"),
        &broken,
        "a negative floor",
    );
    assert!(error.contains("calibration.floor"), "{method}: {error}");
    let estimates = per_frame(fitted.as_ref(), data);
    assert_eq!(bits(&estimates), bits(&per_frame(loaded.as_ref(), data)));
    assert_eq!(
        bits(&over_time(fitted.as_ref(), data)),
        bits(&over_time(loaded.as_ref(), data)),
        "{method}: the loaded model tracks a motion differently"
    );

    // Estimates on clean frames are finite and their flags consistent.
    for (k, e) in estimates.iter().enumerate() {
        check_flags(method, &format!("clean frame {k}"), e, &data.frames[k].2);
        assert!(e.flags.missing.is_empty(), "{method} frame {k}");
    }

    // start_motion: a per-frame method estimates each frame alone; every method is deterministic.
    let tracked = over_time(fitted.as_ref(), data);
    assert_eq!(bits(&tracked), bits(&over_time(fitted.as_ref(), data)));
    if !method.entry().over_time {
        assert_eq!(
            tracked, estimates,
            "{method}: start_motion differs from estimate"
        );
    }

    // Missing, non-finite and miscounted features.
    let row = &data.frames[3].2;
    let mut holes = row.clone();
    holes[1] = None;
    let e = fitted.estimate(&holes).unwrap();
    check_flags(method, "one missing feature", &e, &holes);
    let none = vec![None; FEATURES];
    let e = fitted.estimate(&none).unwrap();
    check_flags(method, "every feature missing", &e, &none);
    for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
        let mut broken = row.clone();
        broken[2] = Some(bad);
        // A non-finite value is missing data or an error; never a non-finite pose.
        match fitted.estimate(&broken) {
            Ok(e) => check_flags(method, &format!("feature = {bad}"), &e, &broken),
            Err(e) => assert!(!e.to_string().is_empty()),
        }
    }
    for count in [FEATURES - 1, FEATURES + 1] {
        match fitted.estimate(&vec![Some(1.0); count]) {
            Err(EstimatorError::FeatureCount { expected, found }) => {
                assert_eq!((expected, found), (FEATURES, count), "{method}")
            }
            other => panic!("{method}: {count} values gave {other:?}"),
        }
    }

    // Corrupted, truncated and foreign files are refused, naming the path.
    let bad = dir.path().join("bad.json");
    refused(method, &bad, &json[..json.len() / 2], "a truncated file");
    refused(method, &bad, "not json at all", "a file of text");
    let foreign = other.fit(settings, &training).unwrap().to_json().unwrap();
    let error = refused(method, &bad, &foreign, "another method's file");
    assert!(error.contains(other.name()), "{method}: {error}");
    let mut value: serde_json::Value = serde_json::from_str(&json).unwrap();
    value["format_version"] = serde_json::json!(999);
    refused(
        method,
        &bad,
        &value.to_string(),
        "a file of an unknown format version",
    );

    // Poses beyond the workspace are refused.
    let mut value: serde_json::Value = serde_json::from_str(&json).unwrap();
    assert!(
        move_first_pose(&mut value, [WORKSPACE.x_max + 100.0, WORKSPACE.y_max]),
        "{method}: the model file holds no poses to check"
    );
    refused(
        method,
        &bad,
        &value.to_string(),
        "a pose beyond the workspace",
    );
}

/// Flags that mean what they say: the missing features named (non-finite ones as missing or
/// not), the combined and excluded features disjoint and usable, finite poses and radii.
fn check_flags(method: Method, what: &str, e: &PoseEstimate, row: &[Option<f64>]) {
    let absent: Vec<usize> = (0..row.len()).filter(|&i| row[i].is_none()).collect();
    let unusable: Vec<usize> = (0..row.len())
        .filter(|&i| !row[i].is_some_and(f64::is_finite))
        .collect();
    assert!(
        e.flags.missing == absent || e.flags.missing == unusable,
        "{method}, {what}: missing features {absent:?} flagged as {:?}",
        e.flags.missing
    );
    if let Some(p) = e.pose {
        assert!(p.iter().all(|x| x.is_finite()), "{method}, {what}: {e:?}");
    }
    if let Some(r) = e.uncertainty_radius {
        assert!(r >= 0.0 && !r.is_nan(), "{method}, {what}: {e:?}");
    }
    if let Some(group) = &e.group {
        assert!(group.windows(2).all(|w| w[0] < w[1]), "{method}, {what}");
        for i in group {
            assert!(
                row[*i].is_some_and(f64::is_finite),
                "{method}, {what}: {e:?}"
            );
            assert!(!e.flags.excluded.contains(i), "{method}, {what}: {e:?}");
        }
    }
    for i in &e.flags.excluded {
        assert!(row[*i].is_some(), "{method}, {what}: {e:?}");
    }
    if let Some(level) = e.conflict_level {
        assert!(level >= 0.0, "{method}, {what}: {e:?}");
    }
}

/// Checks one built-in method, with the next built-in one's file as the foreign file.
fn check_built_in(method: Method) {
    let built_in: Vec<Method> = Method::all()[..evitrack::estimator::BUILT_IN.len()].to_vec();
    let k = built_in.iter().position(|&m| m == method).unwrap();
    let other = built_in[(k + 1) % built_in.len()];
    check_method(method, &settings(), &Data::new(), other);
}

macro_rules! conformance_tests {
    ($($test:ident: $method:ident,)*) => {
        $(
            #[test]
            fn $test() {
                check_built_in(Method::$method);
            }
        )*

        #[test]
        fn every_built_in_method_has_its_conformance_test() {
            let tested = [$(Method::$method),*];
            for m in &Method::all()[..evitrack::estimator::BUILT_IN.len()] {
                assert!(tested.contains(m), "{m} has no conformance test: add it to the list");
            }
        }
    };
}

conformance_tests! {
    evidential_conforms: EVIDENTIAL,
    evidential_temporal_conforms: EVIDENTIAL_TEMPORAL,
    continuous_conforms: CONTINUOUS,
    continuous_temporal_conforms: CONTINUOUS_TEMPORAL,
    knn_conforms: KNN,
    gp_conforms: GP,
    particle_filter_conforms: PARTICLE_FILTER,
    centre_conforms: CENTRE,
}
