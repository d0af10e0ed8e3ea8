//! Baseline model files: bit-for-bit round trips, corrupted and foreign files named, the
//! feature configuration they carry, fits shared by a workbench.

use super::*;

/// Feature rows of random poses, some with a missing feature.
fn frames(seed: u64) -> Vec<Vec<Option<f64>>> {
    held_out(40, seed)
        .into_iter()
        .enumerate()
        .map(|(i, p)| {
            let mut row = smooth(p);
            if i % 5 == 0 {
                row[i % 4] = None;
            }
            row
        })
        .collect()
}

/// Estimates bit for bit: poses and radii compared by their bits.
fn bits(estimator: &dyn PoseEstimator, rows: &[Vec<Option<f64>>]) -> Vec<Vec<u64>> {
    rows.iter()
        .map(|row| {
            let e = estimator.estimate(row).unwrap();
            e.pose
                .into_iter()
                .flatten()
                .chain(e.uncertainty_radius)
                .map(f64::to_bits)
                .chain(e.flags.missing.iter().map(|&m| m as u64))
                .collect()
        })
        .collect()
}

#[test]
fn model_files_round_trip_bit_for_bit() {
    let data = Data::new(15, smooth);
    let estimators: [Box<dyn PoseEstimator>; 3] = [
        Box::new(knn(&data, 5, KnnWeights::Distance)),
        Box::new(Gp::fit(&GpSettings::default(), &data.training()).unwrap()),
        Box::new(Centre::fit(&CentreSettings::default(), &data.training()).unwrap()),
    ];
    let dir = tempfile::tempdir().unwrap();
    let rows = frames(6);
    for estimator in &estimators {
        let path = dir.path().join(format!("{}.json", estimator.method()));
        let text = estimator.to_json().unwrap();
        std::fs::write(&path, &text).unwrap();
        let loaded = load(&path).unwrap();
        assert_eq!(loaded.method(), estimator.method());
        assert_eq!(loaded.feature_names(), estimator.feature_names());
        assert_eq!(
            bits(loaded.as_ref(), &rows),
            bits(estimator.as_ref(), &rows)
        );
        assert_eq!(loaded.to_json().unwrap(), text);
    }
    let gp = Gp::load(&dir.path().join("gp.json")).unwrap();
    assert_eq!(gp.hyperparameters().length_scales.len(), 4);
}

/// A fitted model file of each method, as text.
fn model_texts() -> Vec<(&'static str, String)> {
    let data = Data::new(5, linear);
    vec![
        ("knn", knn(&data, 2, KnnWeights::Uniform).to_json().unwrap()),
        (
            "gp",
            Gp::fit(&GpSettings::default(), &data.training())
                .unwrap()
                .to_json()
                .unwrap(),
        ),
        (
            "centre",
            Centre::fit(&CentreSettings::default(), &data.training())
                .unwrap()
                .to_json()
                .unwrap(),
        ),
    ]
}

fn from_json(method: &str, text: &str) -> Result<Box<dyn PoseEstimator>, EstimatorError> {
    Ok(match method {
        "knn" => Box::new(Knn::from_json(text)?),
        "gp" => Box::new(Gp::from_json(text)?),
        _ => Box::new(Centre::from_json(text)?),
    })
}

/// `text` with the JSON value at `pointer` replaced.
fn edit(text: &str, pointer: &str, value: serde_json::Value) -> String {
    let mut json: serde_json::Value = serde_json::from_str(text).unwrap();
    *json.pointer_mut(pointer).unwrap() = value;
    serde_json::to_string(&json).unwrap()
}

#[test]
fn corrupted_and_foreign_model_files_are_named() {
    use serde_json::json;
    let texts = model_texts();
    for (method, text) in &texts {
        let message = |text: &str| match from_json(method, text) {
            Ok(_) => panic!("{method}: accepted {text}"),
            Err(e) => e.to_string(),
        };
        // Another method's file.
        let other = &texts.iter().find(|(m, _)| m != method).unwrap().1;
        let error = from_json(method, other).unwrap_err();
        assert!(
            matches!(
                &error,
                EstimatorError::File(ModelFileError::WrongMethod { expected, .. }) if expected == method
            ),
            "{method}: {error}"
        );
        let version = message(&edit(text, "/format_version", json!(99)));
        assert!(version.contains("version 99 is not supported"), "{version}");
        if matches!(*method, "knn" | "gp") {
            // A version-1 file's abstention limit was set on another detection score.
            let old = message(&edit(text, "/format_version", json!(1)));
            assert!(
                old.contains("version 1 is not supported") && old.contains("retrain"),
                "{old}"
            );
        }
        let truncated = message(&text[..text.len() / 2]);
        assert!(truncated.contains("EOF"), "{truncated}");
        assert!(message("[1, 2]").contains("not a JSON object"));
        let unknown = message(&edit(text, "/settings", json!({"bogus": 1})));
        assert!(unknown.contains("bogus"), "{unknown}");
        let names = message(&edit(text, "/feature_names", json!(["a", "a", "b", "c"])));
        assert!(names.contains("appears twice"), "{names}");
    }
    let text = |m: &str| &texts.iter().find(|(method, _)| *method == m).unwrap().1;
    // NaN is written as null.
    for (method, pointer, field) in [
        ("knn", "/sample_features/3/1", "sample_features[3][1]"),
        (
            "gp",
            "/hyperparameters/noise_std",
            "hyperparameters.noise_std",
        ),
        ("gp", "/standardisation/means/2", "standardisation.means[2]"),
        ("centre", "/min/1", "min[1]"),
    ] {
        let error = from_json(method, &edit(text(method), pointer, json!(null))).unwrap_err();
        let message = error.to_string();
        assert!(message.contains(&format!("`{field}` is null")), "{message}");
    }
    // Lengths and values that do not fit.
    for (method, pointer, value, needle) in [
        (
            "knn",
            "/standardisation/scales",
            json!([1.0, 1.0, 1.0]),
            "`standardisation.scales` has 3 values where 4 are expected",
        ),
        (
            "knn",
            "/sample_features/0",
            json!([1.0]),
            "`sample_features[0]` has 1 values",
        ),
        (
            "knn",
            "/sample_poses",
            json!([[0.0, 40.0]]),
            "1 sample poses",
        ),
        ("knn", "/settings/k", json!(100), "`settings.k` is 100"),
        (
            "knn",
            "/standardisation/scales/1",
            json!(0.0),
            "`standardisation.scales[1]` is not positive",
        ),
        (
            "gp",
            "/hyperparameters/length_scales",
            json!([1.0]),
            "`hyperparameters.length_scales` has 1 values for 4 features",
        ),
        (
            "gp",
            "/hyperparameters/signal_std",
            json!(-1.0),
            "`hyperparameters.signal_std` is -1",
        ),
        (
            "gp",
            "/output/means",
            json!([0.0]),
            "`output.means` has 1 values where 2 are expected",
        ),
        (
            "centre",
            "/max/0",
            json!(-100.0),
            "`min` x is above `max` x",
        ),
        ("centre", "/feature_names", json!([]), "no features"),
    ] {
        let error = from_json(method, &edit(text(method), pointer, value)).unwrap_err();
        let message = error.to_string();
        assert!(message.contains(needle), "{method} {pointer}: {message}");
    }
    // Through `load`: the path is named, and unknown methods are refused.
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("model.json");
    std::fs::write(&path, edit(text("gp"), "/method", json!("svm"))).unwrap();
    let message = load(&path).unwrap_err().to_string();
    assert!(
        message.contains("model.json") && message.contains("unknown method `svm`"),
        "{message}"
    );
    std::fs::write(&path, edit(text("knn"), "/format_version", json!(7))).unwrap();
    let message = load(&path).unwrap_err().to_string();
    assert!(
        message.contains("model.json") && message.contains("version 7"),
        "{message}"
    );
    let missing = load(&dir.path().join("absent.json")).unwrap_err();
    assert!(matches!(missing, EstimatorError::Io { .. }), "{missing}");
}

#[test]
fn the_feature_configuration_travels_with_the_model() {
    use evitrack::features::FeatureConfig;
    let config = FeatureConfig::with_barycentre();
    let names = config.check().unwrap().names();
    let poses = grid(5);
    let rows: Vec<Vec<Option<f64>>> = poses
        .iter()
        .map(|p| {
            (0..names.len())
                .map(|i| Some(p[0] * (i as f64 + 1.0) + p[1] / (i as f64 + 2.0)))
                .collect()
        })
        .collect();
    let labelled = Labelled {
        poses: &poses,
        rows: &rows,
    };
    let training = TrainingSet::new(&names, labelled).with_config(&config);
    let dir = tempfile::tempdir().unwrap();
    let estimators: [Box<dyn PoseEstimator>; 3] = [
        Box::new(Knn::fit(&KnnSettings::default(), &training).unwrap()),
        Box::new(Gp::fit(&GpSettings::default(), &training).unwrap()),
        Box::new(Centre::fit(&CentreSettings::default(), &training).unwrap()),
    ];
    for estimator in &estimators {
        assert_eq!(estimator.feature_config(), Some(&config));
        let path = dir.path().join(format!("{}.json", estimator.method()));
        std::fs::write(&path, estimator.to_json().unwrap()).unwrap();
        assert_eq!(load(&path).unwrap().feature_config(), Some(&config));
    }
    // A configuration naming other features is refused.
    let other = names.iter().map(|n| format!("{n}_")).collect::<Vec<_>>();
    let training = TrainingSet::new(&other, labelled).with_config(&config);
    let error = Centre::fit(&CentreSettings::default(), &training).unwrap_err();
    assert!(
        matches!(
            error,
            EstimatorError::Model(ModelError::InvalidInput { .. })
        ),
        "{error}"
    );
}

/// A sweep's variants that train on the same data share the Gaussian-process fits: the shared
/// fit, handed out under each run's provenance, writes the same model file as fitting afresh,
/// and any change to the training data makes a new fit.
#[test]
fn a_workbench_shares_fits_between_identical_training_sets_only() {
    let data = Data::new(8, smooth);
    let mut nudged = Data::new(8, smooth);
    nudged.rows[5][2] = nudged.rows[5][2].map(|v| v + 1e-3);
    fn with<'a>(data: &'a Data, name: &str) -> TrainingSet<'a> {
        TrainingSet {
            provenance: Provenance::new(Some(name.to_string()), 7),
            ..data.training()
        }
    }
    let (data, nudged) = (&data, &nudged);
    let settings = EstimatorSettings::default();
    let bench = Workbench::new();
    for (k, method) in [Method::GP, Method::CONTINUOUS].into_iter().enumerate() {
        let json = |e: Box<dyn PoseEstimator>| e.to_json().unwrap();
        let first = json(bench.fit(method, &settings, &with(data, "a")).unwrap());
        let second = json(bench.fit(method, &settings, &with(data, "b")).unwrap());
        assert_eq!(
            bench.shared_fits(),
            2 * k + 1,
            "{method}: one fit for both runs"
        );
        assert_eq!(
            second,
            json(method.fit(&settings, &with(data, "b")).unwrap())
        );
        assert_ne!(first, second, "{method}: each run keeps its own provenance");
        assert_eq!(first.replace("\"a\"", "\"b\""), second);
        let changed = json(bench.fit(method, &settings, &with(nudged, "b")).unwrap());
        assert_eq!(
            bench.shared_fits(),
            2 * k + 2,
            "{method}: changed data, new fit"
        );
        assert_eq!(
            changed,
            json(method.fit(&settings, &with(nudged, "b")).unwrap())
        );
        assert_ne!(changed, second);
    }
    // Methods with cheap fits are fitted on every call and never held.
    let knn = bench.fit(Method::KNN, &settings, &with(data, "a")).unwrap();
    assert_eq!(knn.method(), "knn");
    assert_eq!(bench.shared_fits(), 4);
}

/// The temporal methods' fits (and the paper tracker's) are shared too: between runs of one
/// training seed, handed out byte for byte as a fresh fit for that run would be, and fitted
/// again for another seed (the particle filter draws from it).
#[test]
fn a_workbench_shares_temporal_fits_within_one_seed_only() {
    let data = Data::new(8, smooth);
    let poses: Vec<[f64; 2]> = (0..40)
        .map(|i| {
            let a = i as f64 * 0.25;
            [4.0 * a.cos(), 47.5 + 4.0 * a.sin()]
        })
        .collect();
    let rows: Vec<Vec<Option<f64>>> = poses.iter().map(|&p| smooth(p)).collect();
    let times: Vec<f64> = (0..40).map(|i| i as f64 * 0.1).collect();
    let with = |name: &str, seed: u64| TrainingSet {
        provenance: Provenance::new(Some(name.to_string()), seed),
        validation: Some(Labelled {
            poses: &poses,
            rows: &rows,
        }),
        validation_times: Some(&times),
        ..data.training()
    };
    let settings = EstimatorSettings::default();
    let bench = Workbench::new();
    let json = |e: Box<dyn PoseEstimator>| e.to_json().unwrap();
    let methods = [
        Method::EVIDENTIAL,
        Method::EVIDENTIAL_TEMPORAL,
        Method::CONTINUOUS_TEMPORAL,
        Method::PARTICLE_FILTER,
    ];
    let mut fits = 0;
    for method in methods {
        let first = json(bench.fit(method, &settings, &with("a", 7)).unwrap());
        let second = json(bench.fit(method, &settings, &with("b", 7)).unwrap());
        fits += 1;
        assert_eq!(bench.shared_fits(), fits, "{method}: one fit, two runs");
        assert_eq!(
            second,
            json(method.fit(&settings, &with("b", 7)).unwrap()),
            "{method}: the shared fit is the run's own"
        );
        // The run's name, in the file and in the inner model file it embeds as a string.
        let renamed = first
            .replace("\"a\"", "\"b\"")
            .replace("\\\"a\\\"", "\\\"b\\\"");
        assert_eq!(renamed, second, "{method}");
        let reseeded = json(bench.fit(method, &settings, &with("b", 8)).unwrap());
        fits += usize::from(method.entry().over_time);
        assert_eq!(bench.shared_fits(), fits, "{method}: another seed");
        assert_eq!(
            reseeded,
            json(method.fit(&settings, &with("b", 8)).unwrap())
        );
    }
}
