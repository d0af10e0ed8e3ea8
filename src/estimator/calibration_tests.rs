use super::*;

fn workspace() -> Rect {
    Rect {
        x_min: 0.0,
        x_max: 10.0,
        y_min: 0.0,
        y_max: 10.0,
    }
}

fn estimate(pose: [f64; 2], sigma: f64, score: Option<f64>) -> PoseEstimate {
    PoseEstimate {
        pose: Some(pose),
        detection_score: score,
        covariance: Some([[sigma * sigma, 0.0], [0.0, sigma * sigma]]),
        ..Default::default()
    }
}

/// Estimates off the truth by a Gaussian error of the stated σ, drawn from a fixed stream.
fn draws(n: usize, seed: u64) -> (Vec<PoseEstimate>, Vec<[f64; 2]>) {
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let unit = Normal::new(0.0, 1.0).unwrap();
    let mut estimates = Vec::new();
    let mut truth = Vec::new();
    for i in 0..n {
        // σ varies by frame: a method that knows its σ gets tight regions where it is sure.
        let sigma = 0.05 + 0.2 * (i % 5) as f64;
        let t = [5.0, 5.0];
        let e = [
            t[0] + sigma * unit.sample(&mut rng),
            t[1] + sigma * unit.sample(&mut rng),
        ];
        estimates.push(estimate(e, sigma, Some(unit.sample(&mut rng).abs())));
        truth.push(t);
    }
    (estimates, truth)
}

#[test]
fn the_conformal_quantile_is_the_rank_of_n_plus_one() {
    let values: Vec<f64> = (1..=9).map(f64::from).collect();
    assert_eq!(conformal_quantile(&values, 0.9), Some(9.0));
    assert_eq!(conformal_quantile(&values, 0.5), Some(5.0));
    assert_eq!(conformal_quantile(&values, 0.95), None, "rank 10 of 9");
    assert_eq!(conformal_quantile(&[f64::NAN, 1.0], 0.3), Some(1.0));
    assert_eq!(conformal_quantile(&[f64::NAN, 1.0], 0.6), None);
}

#[test]
fn the_render_check_runs_by_default_where_its_limit_can_be_learned() {
    let mut settings = ConfidenceSettings::default();
    // At share 0.005 the limit is the ⌈0.995 (n + 1)⌉-th of n mismatches: n ≥ 199.
    assert!(!settings.render_check_on(None));
    assert!(!settings.render_check_on(Some(198)));
    assert!(settings.render_check_on(Some(199)));
    settings.render_share = 0.05;
    assert!(settings.render_check_on(Some(19)));
    settings.render_check = Some(false);
    assert!(!settings.render_check_on(Some(400)));
    settings.render_check = Some(true);
    assert!(settings.render_check_on(None) && settings.render_check_required());
}

#[test]
fn calibrated_regions_hold_the_nominal_share_of_exchangeable_frames() {
    let settings = ConfidenceSettings::default();
    let (validation, truth) = draws(400, 1);
    let calibration = Calibration::from_validation(&validation, &truth, workspace(), &settings);
    let (test, test_truth) = draws(4000, 2);
    let mut covered = 0;
    let mut areas = [0.0; 5];
    for (i, (mut e, t)) in test.into_iter().zip(test_truth).enumerate() {
        e.detection_score = None;
        calibration.apply(&mut e);
        assert!(!e.flags.abstained);
        let region = e.region.unwrap();
        covered += usize::from(region.covers(t));
        areas[i % 5] = region.area;
    }
    let share = covered as f64 / 4000.0;
    assert!((0.88..=0.92).contains(&share), "coverage {share}");
    // The region follows the stated σ: the surest frames get the smallest regions.
    assert!(areas.windows(2).all(|w| w[0] < w[1]), "{areas:?}");
    // χ² with 2 degrees of freedom at 0.9: r = √(2 ln 10) ≈ 2.146.
    let q = calibration.radius.unwrap();
    assert!((q - 2.146).abs() < 0.15, "radius {q}");
}

/// Frames at (2.5, 5) or (7.5, 5) in turn, stating σ = 0.1; the right half errs 3× what it states.
fn halves(n: usize, seed: u64) -> (Vec<PoseEstimate>, Vec<[f64; 2]>) {
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let unit = Normal::new(0.0, 1.0).unwrap();
    (0..n)
        .map(|i| {
            let (t, spread) = match i % 2 {
                0 => ([2.5, 5.0], 0.1),
                _ => ([7.5, 5.0], 0.3),
            };
            let e = [
                t[0] + spread * unit.sample(&mut rng),
                t[1] + spread * unit.sample(&mut rng),
            ];
            (estimate(e, 0.1, None), t)
        })
        .unzip()
}

/// Each half's coverage of `calibration`'s regions on fresh frames.
fn coverage_by_half(calibration: &Calibration) -> [f64; 2] {
    let (test, truth) = halves(4000, 4);
    let mut covered = [0; 2];
    for (i, (mut e, t)) in test.into_iter().zip(truth).enumerate() {
        calibration.apply(&mut e);
        covered[i % 2] += usize::from(e.region.unwrap().covers(t));
    }
    covered.map(|c| c as f64 / 2000.0)
}

#[test]
fn a_quantile_per_cell_holds_the_coverage_in_each_half_where_one_quantile_cannot() {
    let (validation, truth) = halves(600, 3);
    let one = Calibration::from_validation(
        &validation,
        &truth,
        workspace(),
        &ConfidenceSettings::default(),
    );
    let [left, right] = coverage_by_half(&one);
    // One quantile: about right over all frames, too wide where the method is honest, too narrow
    // where it is overconfident.
    assert!(left > 0.97 && right < 0.8, "{left} {right}");
    let settings = ConfidenceSettings {
        cells: Some([2, 1]),
        ..ConfidenceSettings::default()
    };
    let per_cell = Calibration::from_validation(&validation, &truth, workspace(), &settings);
    let cells = per_cell.cell_radii.as_ref().unwrap();
    assert_eq!(cells.frames, vec![300, 300]);
    for coverage in coverage_by_half(&per_cell) {
        assert!((0.87..=0.93).contains(&coverage), "{coverage}");
    }
    // Written and read back with the model file's checks.
    let text = serde_json::to_string(&per_cell).unwrap();
    let back: Calibration = serde_json::from_str(&text).unwrap();
    assert_eq!(back, per_cell);
    assert!(back.check().is_ok());
    // Without the setting the file has no such field, and one without it reads as before.
    assert!(!serde_json::to_string(&one).unwrap().contains("cell_radii"));
}

#[test]
fn scores_beyond_clean_validation_frames_and_total_conflict_abstain() {
    let settings = ConfidenceSettings::default();
    let (validation, truth) = draws(200, 3);
    let calibration = Calibration::from_validation(&validation, &truth, workspace(), &settings);
    let limit = calibration.detection_limit.unwrap();
    assert!(calibration.validation_abstained <= 0.01);
    for (score, abstains) in [
        (limit, false),
        (limit * 1.5 + 1.0, true),
        (f64::INFINITY, true),
        (f64::NAN, true),
    ] {
        let mut e = estimate([5.0, 5.0], 0.1, Some(score));
        calibration.apply(&mut e);
        assert_eq!(e.flags.abstained, abstains, "score {score}");
        let region = e.region.unwrap();
        assert_eq!(
            region.covers([0.0, 10.0]),
            abstains,
            "the workspace's corner"
        );
        assert!(e.flag_words(&[]).contains("abstained") == abstains);
    }
    // A fallback, or a region beyond half the workspace, abstains too.
    let mut fallback = estimate([5.0, 5.0], 0.1, Some(0.0));
    fallback.flags.fallback = true;
    calibration.apply(&mut fallback);
    assert!(fallback.flags.abstained);
    let mut vague = estimate([5.0, 5.0], 20.0, Some(0.0));
    calibration.apply(&mut vague);
    assert!(vague.flags.abstained);
    // Without a pose there is nothing to abstain from.
    let mut none = estimate([5.0, 5.0], 0.1, Some(f64::INFINITY));
    none.pose = None;
    calibration.apply(&mut none);
    assert!(!none.flags.abstained && none.region.is_none());
}

#[test]
fn a_stretched_detection_limit_lies_beyond_the_quantile_by_its_distance_from_the_median() {
    let truth = vec![[5.0, 5.0]; 199];
    let limit = |offset: f64, stretch: f64| {
        // Scores 1…199 (median 100), shifted: the stretch does not depend on where zero is.
        let estimates: Vec<PoseEstimate> = (1..=199)
            .map(|i| estimate([5.0, 5.0], 0.1, Some(f64::from(i) + offset)))
            .collect();
        let settings = ConfidenceSettings {
            render_check: Some(false),
            detection_stretch: stretch,
            ..ConfidenceSettings::default()
        };
        Calibration::from_validation(&estimates, &truth, workspace(), &settings)
            .detection_limit
            .unwrap()
    };
    // The ⌈0.99 × 200⌉ = 198th score, then half of its 98 beyond the median further out.
    assert_eq!(limit(0.0, 0.0), 198.0);
    assert_eq!(limit(0.0, 0.5), 247.0);
    assert_eq!(limit(-1000.0, 0.5), 247.0 - 1000.0);
    // Infinite scores (total conflict) rank last and leave a finite median alone.
    let mut scores = vec![f64::INFINITY; 2];
    scores.extend((1..=7).map(f64::from));
    assert_eq!(stretched(10.0, &scores, 1.0), 10.0 + (10.0 - 5.0));
    assert_eq!(stretched(10.0, &[f64::INFINITY; 3], 1.0), 10.0);
    assert!(ConfidenceSettings {
        detection_stretch: -0.1,
        ..ConfidenceSettings::default()
    }
    .check()
    .unwrap_err()
    .contains("detection_stretch"));
}

#[test]
fn too_few_validation_frames_give_whole_workspace_regions() {
    let (validation, truth) = draws(5, 4);
    let calibration = Calibration::from_validation(
        &validation,
        &truth,
        workspace(),
        &ConfidenceSettings::default(),
    );
    assert_eq!(calibration.radius, None, "rank 6 of 5");
    let mut e = estimate([5.0, 5.0], 0.1, None);
    calibration.apply(&mut e);
    assert!(e.flags.abstained);
}

#[test]
fn the_calibration_rides_in_the_model_file_and_is_checked() {
    let (validation, truth) = draws(50, 5);
    let calibration = Calibration::from_validation(
        &validation,
        &truth,
        workspace(),
        &ConfidenceSettings::default(),
    );
    let inner = "{\n  \"format_version\": 1,\n  \"method\": \"x\"\n}";
    let text = with_calibration(inner, &calibration).unwrap();
    let (rest, found) = split_calibration(&text).unwrap();
    assert_eq!(found.as_ref(), Some(&calibration));
    let rest: serde_json::Value = serde_json::from_str(&rest).unwrap();
    assert_eq!(
        rest,
        serde_json::from_str::<serde_json::Value>(inner).unwrap()
    );
    let (same, none) = split_calibration(inner).unwrap();
    assert_eq!((same.as_str(), none), (inner, None));
    let broken = text.replace(
        &format!("\"floor\": {}", calibration.floor),
        "\"floor\": -1.0",
    );
    assert_ne!(broken, text);
    assert!(split_calibration(&broken)
        .unwrap_err()
        .contains("calibration.floor"));
    // Found by the fuzz corpus: a workspace edge at 1e300 made abstaining regions infinite.
    let mut value: serde_json::Value = serde_json::from_str(&text).unwrap();
    value["calibration"]["workspace"]["x_max"] = serde_json::json!(1e300);
    let broken = serde_json::to_string(&value).unwrap();
    assert!(split_calibration(&broken)
        .unwrap_err()
        .contains("calibration.workspace"));
}

#[test]
fn a_calibration_motion_replaces_the_validation_motion() {
    use crate::estimator::{EstimatorSettings, Labelled, Method, TrainingSet};
    // k-NN on the pose itself as its two features: its error is the features' distortion.
    let poses: Vec<[f64; 2]> = (0..100)
        .map(|i| [f64::from(i % 10), f64::from(i / 10)])
        .collect();
    let rows_of = |shift: f64| -> Vec<Vec<Option<f64>>> {
        (poses.iter().enumerate())
            .map(|(i, p)| {
                let wobble = if i % 2 == 0 { shift } else { -shift };
                vec![Some(p[0] + wobble), Some(p[1] - wobble)]
            })
            .collect()
    };
    let (sample, close, far) = (rows_of(0.0), rows_of(0.05), rows_of(0.4));
    let names = vec!["x".to_string(), "y".to_string()];
    let labelled = |rows| Labelled {
        poses: &poses,
        rows,
    };
    let training = TrainingSet::new(&names, labelled(&sample));
    let settings = EstimatorSettings::default();
    let knn = Method::KNN.fit(&settings, &training).unwrap();
    let learn = |data: &TrainingSet| {
        Calibration::learn(knn.as_ref(), data, &ConfidenceSettings::default())
            .unwrap()
            .expect("a motion to calibrate on")
    };
    let validation_only = TrainingSet {
        validation: Some(labelled(&close)),
        ..training.clone()
    };
    let both = TrainingSet {
        calibration: Some(labelled(&far)),
        ..validation_only.clone()
    };
    let calibration_only = TrainingSet {
        calibration: Some(labelled(&far)),
        ..training.clone()
    };
    assert!(
        Calibration::learn(knn.as_ref(), &training, &ConfidenceSettings::default())
            .unwrap()
            .is_none()
    );
    let (on_validation, on_calibration) = (learn(&validation_only), learn(&both));
    assert_ne!(on_validation, on_calibration);
    assert_eq!(on_calibration, learn(&calibration_only));
}
