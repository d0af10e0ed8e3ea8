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

mod files;

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
fn gp_scales_each_pose_coordinate_by_its_own_spread() {
    // A 19 × 4 mm strip: x and y spread differ by almost 5×, so an output scaled by the other
    // coordinate's spread misses by millimetres (every square mesh hides it).
    let side = 14;
    let poses: Vec<[f64; 2]> = (0..side * 4)
        .map(|i| {
            let (r, c) = (i / side, i % side);
            [-9.5 + c as f64 * 19.0 / 13.0, 46.0 + r as f64 * 4.0 / 3.0]
        })
        .collect();
    let data = Data {
        names: names(4),
        rows: rows(&poses, linear),
        poses,
    };
    let gp = Gp::fit(&GpSettings::default(), &data.training()).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    for _ in 0..50 {
        let truth = [rng.random_range(-9.0..9.0), rng.random_range(46.5..49.5)];
        let e = error(&gp.estimate(&linear(truth)).unwrap(), truth);
        assert!(e < 0.01, "{truth:?}: {e} mm");
    }
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
