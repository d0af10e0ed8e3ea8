//! The baseline estimators (k-NN, Gaussian process, workspace centre) through the public seam:
//! known answers on synthetic features, missing features, model files that round-trip bit for
//! bit and corrupted ones that are named, settings checks.

use evitrack::estimator::{
    load, Centre, CentreSettings, EstimatorError, EstimatorSettings, Gp, GpSettings, Knn,
    KnnSettings, KnnWeights, Labelled, Method, PoseEstimate, PoseEstimator, TrainingSet,
};
use evitrack::experiment::Workbench;
use evitrack::model::ModelError;
use evitrack::model_file::{ModelFileError, Provenance};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Poses on a `side` × `side` grid over [−9.5, 9.5] × [38, 57], in serpentine order.
fn grid(side: usize) -> Vec<[f64; 2]> {
    let step = 19.0 / (side - 1) as f64;
    (0..side * side)
        .map(|i| {
            let (r, c) = (i / side, i % side);
            let c = if r % 2 == 0 { c } else { side - 1 - c };
            [-9.5 + c as f64 * step, 38.0 + r as f64 * step]
        })
        .collect()
}

/// An invertible linear map of the pose to 4 features.
fn linear(p: [f64; 2]) -> Vec<Option<f64>> {
    let [x, y] = p;
    [
        x + 0.5 * y,
        -0.3 * x + y,
        2.0 * x - y + 3.0,
        0.7 * x + 0.2 * y,
    ]
    .map(Some)
    .to_vec()
}

/// A smooth nonlinear (and still invertible on the grid) map of the pose to 4 features.
fn smooth(p: [f64; 2]) -> Vec<Option<f64>> {
    let [x, y] = p;
    let v = y - 47.5;
    [
        (x / 12.0).sin() + 0.02 * v,
        (v / 15.0).cos() * 0.5 + v / 20.0,
        0.01 * x * v + x / 10.0,
        (0.05 * (x + v)).exp(),
    ]
    .map(Some)
    .to_vec()
}

fn names(n: usize) -> Vec<String> {
    (0..n).map(|i| format!("f{i}")).collect()
}

fn rows(poses: &[[f64; 2]], map: fn([f64; 2]) -> Vec<Option<f64>>) -> Vec<Vec<Option<f64>>> {
    poses.iter().map(|&p| map(p)).collect()
}

/// Random poses strictly inside the grid.
fn held_out(n: usize, seed: u64) -> Vec<[f64; 2]> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n)
        .map(|_| [rng.random_range(-9.0..9.0), rng.random_range(38.5..56.5)])
        .collect()
}

fn error(estimate: &PoseEstimate, truth: [f64; 2]) -> f64 {
    let p = estimate.pose.expect("an estimate");
    (p[0] - truth[0]).hypot(p[1] - truth[1])
}

/// Mean and largest error over held-out poses.
fn errors(
    estimator: &dyn PoseEstimator,
    map: fn([f64; 2]) -> Vec<Option<f64>>,
    seed: u64,
) -> (f64, f64) {
    let truth = held_out(200, seed);
    let e: Vec<f64> = truth
        .iter()
        .map(|&t| error(&estimator.estimate(&map(t)).unwrap(), t))
        .collect();
    (
        e.iter().sum::<f64>() / e.len() as f64,
        e.iter().fold(0.0, |a, &b| a.max(b)),
    )
}

struct Data {
    names: Vec<String>,
    poses: Vec<[f64; 2]>,
    rows: Vec<Vec<Option<f64>>>,
}

impl Data {
    fn new(side: usize, map: fn([f64; 2]) -> Vec<Option<f64>>) -> Self {
        let poses = grid(side);
        Self {
            names: names(map([0.0, 40.0]).len()),
            rows: rows(&poses, map),
            poses,
        }
    }

    fn training(&self) -> TrainingSet<'_> {
        TrainingSet::new(
            &self.names,
            Labelled {
                poses: &self.poses,
                rows: &self.rows,
            },
        )
    }
}

fn knn(data: &Data, k: usize, weights: KnnWeights) -> Knn {
    Knn::fit(&KnnSettings { k, weights }, &data.training()).unwrap()
}

#[test]
fn gp_recovers_a_linear_map() {
    // Spacing 19/13 mm: 196 samples keep the test fast.
    let data = Data::new(14, linear);
    let gp = Gp::fit(&GpSettings::default(), &data.training()).unwrap();
    let (mean, max) = errors(&gp, linear, 1);
    assert!(mean < 0.01, "mean error {mean} mm, largest {max} mm");
}

#[test]
fn gp_recovers_a_smooth_nonlinear_map() {
    let data = Data::new(14, smooth);
    let gp = Gp::fit(&GpSettings::default(), &data.training()).unwrap();
    let (mean, max) = errors(&gp, smooth, 2);
    assert!(mean < 0.01, "mean error {mean} mm, largest {max} mm");
}

#[test]
fn knn_error_is_bounded_by_the_grid_spacing() {
    // Spacing 1 mm.
    let data = Data::new(20, linear);
    for weights in [KnnWeights::Uniform, KnnWeights::Distance] {
        for k in [1, 4, 6] {
            let (mean, max) = errors(&knn(&data, k, weights), linear, 3);
            assert!(mean < 0.5, "{weights:?} k={k}: mean error {mean} mm");
            assert!(max < 1.0, "{weights:?} k={k}: largest error {max} mm");
        }
    }
}

#[test]
fn knn_returns_a_sample_pose_its_features_match_exactly() {
    let data = Data::new(10, linear);
    let knn = knn(&data, 6, KnnWeights::Distance);
    for i in [0, 17, 99] {
        let estimate = knn.estimate(&data.rows[i]).unwrap();
        assert_eq!(estimate.pose, Some(data.poses[i]));
        assert_eq!(estimate.uncertainty_radius, Some(0.0));
        assert_eq!(knn.neighbours(&data.rows[i]).unwrap()[0], (i, 0.0));
    }
}

#[test]
fn knn_breaks_distance_ties_by_the_lower_sample_index() {
    let names = names(1);
    let poses = [[0.0, 40.0], [5.0, 40.0], [1.0, 41.0], [2.0, 42.0]];
    // Samples 0 and 1 share a feature value; sample 2 and 3 are as far on either side of 1.0.
    let rows = vec![
        vec![Some(1.0)],
        vec![Some(1.0)],
        vec![Some(0.0)],
        vec![Some(2.0)],
    ];
    let training = TrainingSet::new(
        &names,
        Labelled {
            poses: &poses,
            rows: &rows,
        },
    );
    let settings = |k| KnnSettings {
        k,
        weights: KnnWeights::Uniform,
    };
    let one = Knn::fit(&settings(1), &training).unwrap();
    assert_eq!(one.estimate(&[Some(1.0)]).unwrap().pose, Some([0.0, 40.0]));
    let three = Knn::fit(&settings(3), &training).unwrap();
    let order: Vec<usize> = three
        .neighbours(&[Some(1.0)])
        .unwrap()
        .iter()
        .map(|n| n.0)
        .collect();
    assert_eq!(order, [0, 1, 2]);
}

#[test]
fn knn_uniform_weights_average_the_neighbours() {
    let names = names(1);
    let poses = [[0.0, 40.0], [2.0, 44.0], [10.0, 50.0]];
    let rows = vec![vec![Some(0.0)], vec![Some(1.0)], vec![Some(10.0)]];
    let training = TrainingSet::new(
        &names,
        Labelled {
            poses: &poses,
            rows: &rows,
        },
    );
    let settings = KnnSettings {
        k: 2,
        weights: KnnWeights::Uniform,
    };
    let estimate = Knn::fit(&settings, &training)
        .unwrap()
        .estimate(&[Some(0.4)])
        .unwrap();
    assert_eq!(estimate.pose, Some([1.0, 42.0]));
    // RMS distance of the two neighbours from their mean.
    let radius = estimate.uncertainty_radius.unwrap();
    assert!((radius - 5f64.sqrt()).abs() < 1e-12, "{radius}");
    // Distance weights ∝ 1/0.4 and 1/0.6: the nearer sample weighs 1.5 times more.
    let distance = Knn::fit(
        &KnnSettings {
            k: 2,
            ..KnnSettings::default()
        },
        &training,
    )
    .unwrap()
    .estimate(&[Some(0.4)])
    .unwrap();
    let p = distance.pose.unwrap();
    assert!(
        (p[0] - 0.8).abs() < 1e-12 && (p[1] - 41.6).abs() < 1e-12,
        "{p:?}"
    );
}

#[test]
fn centre_is_the_middle_of_the_sample_bounding_box() {
    let data = Data::new(20, linear);
    let centre = Centre::fit(&CentreSettings::default(), &data.training()).unwrap();
    assert_eq!(centre.centre(), [0.0, 47.5]);
    for t in held_out(20, 4) {
        let estimate = centre.estimate(&linear(t)).unwrap();
        assert_eq!(error(&estimate, t), t[0].hypot(t[1] - 47.5));
        assert_eq!(estimate.uncertainty_radius, None);
    }
    // Not the mean of the poses: the middle of their box.
    let names = names(1);
    let poses = [[0.0, 40.0], [1.0, 40.0], [10.0, 50.0]];
    let rows = vec![vec![Some(1.0)], vec![None], vec![Some(3.0)]];
    let training = TrainingSet::new(
        &names,
        Labelled {
            poses: &poses,
            rows: &rows,
        },
    );
    let lopsided = Centre::fit(&CentreSettings::default(), &training).unwrap();
    assert_eq!(lopsided.estimate(&[None]).unwrap().pose, Some([5.0, 45.0]));
    let nothing = centre.estimate(&[None; 4]).unwrap();
    assert_eq!(nothing.pose, Some([0.0, 47.5]));
    assert_eq!(nothing.flags.missing, [0, 1, 2, 3]);
}

#[test]
fn missing_features_are_flagged_and_never_give_nan() {
    let data = Data::new(20, linear);
    let knn = knn(&data, 6, KnnWeights::Distance);
    let gp = Gp::fit(&GpSettings::default(), &Data::new(8, linear).training()).unwrap();
    let centre = Centre::fit(&CentreSettings::default(), &data.training()).unwrap();
    let truth = [1.3, 45.2];
    let mut row = linear(truth);
    row[2] = None;
    // Three of four linear features still pin the pose down: the search runs on them alone, as
    // a k-NN fitted on those three would.
    let estimate = knn.estimate(&row).unwrap();
    assert_eq!(estimate.flags.missing, [2]);
    assert!(error(&estimate, truth) < 0.5);
    let three = |r: &Vec<Option<f64>>| vec![r[0], r[1], r[3]];
    let rows: Vec<_> = data.rows.iter().map(three).collect();
    let names = names(3);
    let labelled = Labelled {
        poses: &data.poses,
        rows: &rows,
    };
    let knn3 = Knn::fit(knn.settings(), &TrainingSet::new(&names, labelled)).unwrap();
    let corner = [8.3, 39.2];
    let mut far = linear(corner);
    far[2] = None;
    let estimate = knn.estimate(&far).unwrap();
    assert_eq!(estimate.pose, knn3.estimate(&three(&far)).unwrap().pose);
    assert!(error(&estimate, corner) < 0.5);
    let estimate = gp.estimate(&row).unwrap();
    assert_eq!((estimate.pose, estimate.uncertainty_radius), (None, None));
    assert_eq!(estimate.flags.missing, [2]);
    assert_eq!(estimate.flag_words(&data.names), "missing:f2 no_estimate");
    // Non-finite values count as missing.
    row[1] = Some(f64::NAN);
    row[3] = Some(f64::INFINITY);
    let estimate = knn.estimate(&row).unwrap();
    assert_eq!(estimate.flags.missing, [1, 2, 3]);
    assert!(estimate.pose.unwrap().iter().all(|v| v.is_finite()));
    let none = [None; 4];
    let estimate = knn.estimate(&none).unwrap();
    assert_eq!((estimate.pose, estimate.uncertainty_radius), (None, None));
    assert_eq!(estimate.flags.missing, [0, 1, 2, 3]);
    // Every pattern of missing values: finite estimates or none, never NaN.
    for mask in 0..16u32 {
        let row: Vec<Option<f64>> = linear(truth)
            .into_iter()
            .enumerate()
            .map(|(i, v)| v.filter(|_| mask & (1 << i) == 0))
            .collect();
        for estimator in [&knn as &dyn PoseEstimator, &gp, &centre] {
            let estimate = estimator.estimate(&row).unwrap();
            let numbers = estimate.pose.into_iter().flatten();
            assert!(
                numbers
                    .chain(estimate.uncertainty_radius)
                    .all(f64::is_finite),
                "{} with mask {mask:04b}: {estimate:?}",
                estimator.method()
            );
        }
    }
}

#[test]
fn gp_uncertainty_grows_away_from_the_samples() {
    let data = Data::new(12, smooth);
    let gp = Gp::fit(&GpSettings::default(), &data.training()).unwrap();
    let radius = |p: [f64; 2]| gp.estimate(&smooth(p)).unwrap().uncertainty_radius.unwrap();
    let inside = radius([0.3, 47.1]);
    let outside = radius([25.0, 75.0]);
    assert!(inside > 0.0 && inside < 0.1, "{inside}");
    assert!(outside > 10.0 * inside, "{outside} vs {inside}");
}

#[test]
fn a_frame_with_the_wrong_feature_count_is_refused() {
    let data = Data::new(6, linear);
    let estimators: [Box<dyn PoseEstimator>; 3] = [
        Box::new(knn(&data, 3, KnnWeights::Distance)),
        Box::new(Gp::fit(&GpSettings::default(), &data.training()).unwrap()),
        Box::new(Centre::fit(&CentreSettings::default(), &data.training()).unwrap()),
    ];
    for estimator in &estimators {
        for found in [3, 5] {
            match estimator.estimate(&vec![Some(1.0); found]) {
                Err(EstimatorError::FeatureCount {
                    expected: 4,
                    found: f,
                }) => assert_eq!(f, found),
                other => panic!("{}: {other:?}", estimator.method()),
            }
        }
    }
}

#[test]
fn samples_with_missing_values_are_dropped_and_bad_training_sets_refused() {
    let mut data = Data::new(6, linear);
    data.rows[3][1] = None;
    data.rows[5][0] = Some(f64::NAN);
    let knn = knn(&data, 3, KnnWeights::Distance);
    assert_eq!(knn.sample_poses().len(), 34);
    assert!(!knn.sample_poses().contains(&data.poses[3]));
    let gp = Gp::fit(&GpSettings::default(), &data.training()).unwrap();
    assert_eq!(gp.sample_poses().len(), 34);
    // The centre ignores features, so it keeps every pose.
    let centre = Centre::fit(&CentreSettings::default(), &data.training()).unwrap();
    assert_eq!(centre.bounds(), ([-9.5, 38.0], [9.5, 57.0]));

    for row in &mut data.rows {
        row[0] = None;
    }
    let error = Knn::fit(&KnnSettings::default(), &data.training()).unwrap_err();
    assert!(matches!(error, EstimatorError::Training(_)), "{error}");
    let error = Gp::fit(&GpSettings::default(), &data.training()).unwrap_err();
    assert!(matches!(error, EstimatorError::Training(_)), "{error}");

    let mut data = Data::new(6, linear);
    data.poses[7][1] = f64::NAN;
    for error in [
        Knn::fit(&KnnSettings::default(), &data.training()).unwrap_err(),
        Gp::fit(&GpSettings::default(), &data.training()).unwrap_err(),
        Centre::fit(&CentreSettings::default(), &data.training()).unwrap_err(),
    ] {
        assert!(
            matches!(
                error,
                EstimatorError::Model(ModelError::NonFinitePose { index: 7, .. })
            ),
            "{error}"
        );
    }
    let mut data = Data::new(6, linear);
    data.rows.pop();
    let error = Centre::fit(&CentreSettings::default(), &data.training()).unwrap_err();
    assert!(matches!(
        error,
        EstimatorError::Model(ModelError::RowCount { .. })
    ));
    let data = Data::new(2, linear);
    let error = Knn::fit(&KnnSettings::default(), &data.training()).unwrap_err();
    assert!(error.to_string().contains("knn.k"), "{error}");
}

#[test]
fn settings_are_checked_and_name_the_field() {
    let error = KnnSettings {
        k: 0,
        ..KnnSettings::default()
    }
    .check()
    .unwrap_err();
    assert!(error.to_string().contains("`knn.k`"), "{error}");
    let data = Data::new(4, linear);
    assert!(Knn::fit(
        &KnnSettings {
            k: 0,
            ..KnnSettings::default()
        },
        &data.training()
    )
    .is_err());
    let error = toml::from_str::<KnnSettings>("k = 3\nneighbours = 2").unwrap_err();
    assert!(
        error.to_string().contains("unknown field `neighbours`"),
        "{error}"
    );
    let error = toml::from_str::<KnnSettings>("weights = \"gaussian\"").unwrap_err();
    assert!(error.to_string().contains("gaussian"), "{error}");
    let parsed: KnnSettings = toml::from_str("weights = \"uniform\"").unwrap();
    assert_eq!((parsed.k, parsed.weights), (6, KnnWeights::Uniform));

    let error = toml::from_str::<GpSettings>("max_fit_samples = 10\nrestarts = 2").unwrap_err();
    assert!(
        error.to_string().contains("unknown field `restarts`"),
        "{error}"
    );
    for (text, field) in [
        ("max_fit_samples = 0", "gp.max_fit_samples"),
        ("starts = 0", "gp.starts"),
        ("initial_length_scale = -1.0", "gp.initial_length_scale"),
        ("initial_noise = 0.0", "gp.initial_noise"),
    ] {
        let settings: GpSettings = toml::from_str(text).unwrap();
        let error = settings.check().unwrap_err();
        assert!(error.to_string().contains(field), "{text}: {error}");
    }
    assert!(toml::from_str::<CentreSettings>("k = 1").is_err());
    assert!(toml::from_str::<CentreSettings>("")
        .unwrap()
        .check()
        .is_ok());
}

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
        let version = message(&edit(text, "/format_version", json!(2)));
        assert!(version.contains("version 2 is not supported"), "{version}");
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
fn knn_standardises_the_features() {
    // Scaled and shifted features, and a constant one (whose mean on the samples is not exactly
    // 0.1 in floating point), find the same neighbours.
    fn plain(p: [f64; 2]) -> Vec<Option<f64>> {
        vec![Some(p[0]), Some(0.2 * p[1])]
    }
    fn scaled(p: [f64; 2]) -> Vec<Option<f64>> {
        vec![Some(1000.0 * p[0] + 5.0), Some(p[1]), Some(0.1)]
    }
    let (plain_data, scaled_data) = (Data::new(12, plain), Data::new(12, scaled));
    for weights in [KnnWeights::Uniform, KnnWeights::Distance] {
        let (a, b) = (knn(&plain_data, 4, weights), knn(&scaled_data, 4, weights));
        for t in held_out(50, 8) {
            // The constant is off by a hair in the frame: scale 1 keeps that a hair.
            let mut frame = scaled(t);
            frame[2] = Some(0.1 + 1e-7);
            let (pa, pb) = (a.estimate(&plain(t)).unwrap(), b.estimate(&frame).unwrap());
            let (pa, pb) = (pa.pose.unwrap(), pb.pose.unwrap());
            assert!(
                (pa[0] - pb[0]).abs() < 1e-9 && (pa[1] - pb[1]).abs() < 1e-9,
                "{pa:?} {pb:?}"
            );
        }
    }
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
