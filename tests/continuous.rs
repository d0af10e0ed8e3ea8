//! The continuous evidential tracker through the public seam: synthetic feature maps with a known
//! answer (`estimator::test_maps`), rejection of a stuck feature, plausibility regions, the
//! contour product against Dempster's rule on a discretised candidate set, model files, bad input.

use evitrack::estimator::test_maps::{
    feature_row, feature_value, workspace_mesh, workspace_points,
};
use evitrack::estimator::{
    load, Continuous, ContinuousSettings, EstimatorError, Labelled, PoseEstimator, TrainingSet,
};
use evitrack::evidence::{contour_product, dempster_all, MassFunction, Subset};
use evitrack::track::ThresholdRule;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

const FEATURES: usize = 6;

/// The 1 mm mesh and a 100-pose validation set of the synthetic maps, measured with `noise`.
struct Fixture {
    names: Vec<String>,
    poses: Vec<[f64; 2]>,
    rows: Vec<Vec<Option<f64>>>,
    valid_poses: Vec<[f64; 2]>,
    valid_rows: Vec<Vec<Option<f64>>>,
    noise: f64,
}

impl Fixture {
    fn new(noise: f64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let poses = workspace_mesh(20);
        let rows = poses
            .iter()
            .map(|&q| feature_row(FEATURES, q, noise, &mut rng))
            .collect();
        let valid_poses = workspace_points(100, &mut rng);
        let valid_rows = valid_poses
            .iter()
            .map(|&q| feature_row(FEATURES, q, noise, &mut rng))
            .collect();
        Self {
            names: (0..FEATURES).map(|i| format!("f{i}")).collect(),
            poses,
            rows,
            valid_poses,
            valid_rows,
            noise,
        }
    }

    fn fit(&self, settings: &ContinuousSettings, validation: bool) -> Continuous {
        let mut data = TrainingSet::new(
            &self.names,
            Labelled {
                poses: &self.poses,
                rows: &self.rows,
            },
        );
        if validation {
            data.validation = Some(Labelled {
                poses: &self.valid_poses,
                rows: &self.valid_rows,
            });
        }
        Continuous::fit(settings, &data).expect("fits")
    }

    /// Test frames at `count` random poses, with the fixture's noise.
    fn frames(&self, count: usize, seed: u64) -> Vec<([f64; 2], Vec<Option<f64>>)> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        workspace_points(count, &mut rng)
            .into_iter()
            .map(|q| (q, feature_row(FEATURES, q, self.noise, &mut rng)))
            .collect()
    }
}

fn distance(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

fn learned() -> ContinuousSettings {
    ContinuousSettings {
        learn_threshold: true,
        threshold_rule: ThresholdRule::Quantile(0.99),
        ..ContinuousSettings::default()
    }
}

#[test]
fn known_maps_are_learned_and_inverted() {
    let fixture = Fixture::new(1e-4);
    let model = fixture.fit(&ContinuousSettings::default(), true);
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    // The learned maps are the true ones to well within a percent of their range (≈ 2.6).
    for q in workspace_points(100, &mut rng) {
        let learned = model.feature_map(q);
        for (i, v) in learned.iter().enumerate() {
            assert!((v - feature_value(i, q)).abs() < 2e-3, "f{i} at {q:?}");
        }
    }
    // Inverting them gives the pose back: every feature combined, errors of micrometres.
    let errors: Vec<f64> = fixture
        .frames(100, 6)
        .iter()
        .map(|(q, row)| {
            let e = model.estimate(row).unwrap();
            assert_eq!(e.group.as_deref(), Some(&[0, 1, 2, 3, 4, 5][..]));
            assert!(e.flags.excluded.is_empty() && !e.flags.fallback);
            distance(e.pose.unwrap(), *q)
        })
        .collect();
    let mean = errors.iter().sum::<f64>() / errors.len() as f64;
    let worst = errors.iter().copied().fold(0.0, f64::max);
    // Measured: 0.00045 mean, 0.0019 worst.
    assert!(mean < 1e-3 && worst < 5e-3, "mean {mean}, worst {worst}");
}

#[test]
fn regions_cover_the_chosen_share_and_shrink_with_the_noise() {
    let coverage_and_area = |noise: f64| {
        let fixture = Fixture::new(noise);
        let model = fixture.fit(&ContinuousSettings::default(), true);
        let frames = fixture.frames(300, 8);
        let (mut covered, mut area) = (0, 0.0);
        for (q, row) in &frames {
            let e = model.estimate(row).unwrap();
            let region = e.region.expect("six features fix a point");
            assert!((region.level - model.region_level()).abs() < 1e-15);
            assert_eq!(e.uncertainty_radius, Some(region.semi_major));
            covered += usize::from(region.covers(*q));
            area += region.area;
        }
        (
            covered as f64 / frames.len() as f64,
            area / frames.len() as f64,
        )
    };
    let (coverage, area) = coverage_and_area(0.002);
    // Measured 0.940 and 0.927 (calibrated on 100 validation poses, tested on 300).
    assert!((0.87..=0.97).contains(&coverage), "{coverage}");
    let (coverage_quiet, area_quiet) = coverage_and_area(0.0005);
    assert!((0.87..=0.97).contains(&coverage_quiet), "{coverage_quiet}");
    // Four times less noise: the region's sides shrink about four times, its area about 16.
    let ratio = area / area_quiet;
    assert!((12.0..=22.0).contains(&ratio), "{ratio}");
}

#[test]
fn a_stuck_feature_is_left_out_and_detected() {
    let fixture = Fixture::new(0.002);
    let model = fixture.fit(&learned(), true);
    assert!(model.threshold_learned());
    let threshold = model.threshold().value();
    assert!(threshold.is_finite() && threshold > 0.0);
    let open = fixture.fit(&ContinuousSettings::default(), true);
    let (mut errors, mut open_errors) = (Vec::new(), Vec::new());
    for (q, row) in fixture.frames(40, 9) {
        let mut stuck = row.clone();
        stuck[2] = Some(feature_value(2, q) + 0.6);
        let e = model.estimate(&stuck).unwrap();
        assert_eq!(e.flags.excluded, vec![2], "at {q:?}");
        assert!(e.conflict_level.unwrap() <= threshold);
        assert!(e.detection_score.unwrap() > 10.0 * threshold);
        errors.push(distance(e.pose.unwrap(), q));
        open_errors.push(distance(open.estimate(&stuck).unwrap().pose.unwrap(), q));
    }
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    // Left out, the stuck feature costs little; combined, it pulls the estimate away.
    // Measured: 0.0094 mm left out, 1.21 mm combined.
    assert!(mean(&errors) < 0.015, "{}", mean(&errors));
    assert!(
        mean(&open_errors) > 50.0 * mean(&errors),
        "{}",
        mean(&open_errors)
    );
}

/// The consonant functions of a group on a candidate set: contour exp(−½ z²), focal sets the
/// candidates by decreasing contour, the missing height on ∅ (no candidate explains all of it).
fn consonant_on(contour: &[f64]) -> MassFunction {
    let n = contour.len();
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&a, &b| contour[b].total_cmp(&contour[a]));
    let mut focal = Vec::new();
    for k in 0..n {
        let next = if k + 1 < n {
            contour[order[k + 1]]
        } else {
            0.0
        };
        let m = contour[order[k]] - next;
        if m > 0.0 {
            focal.push((
                Subset::from_indices(n, order[..=k].iter().copied()).unwrap(),
                m,
            ));
        }
    }
    let empty = 1.0 - contour[order[0]];
    if empty > 0.0 {
        focal.push((Subset::empty(n), empty));
    }
    MassFunction::unnormalised(n, focal).unwrap()
}

#[test]
fn the_contour_product_is_dempsters_rule_on_a_candidate_set() {
    let fixture = Fixture::new(0.002);
    let model = fixture.fit(&ContinuousSettings::default(), true);
    let sigma = model.residual_scales().to_vec();
    let mut checked_bound = 0;
    for (case, (q, row)) in fixture.frames(12, 10).into_iter().enumerate() {
        let group: Vec<usize> = if case % 2 == 0 {
            vec![0, 1, 2, 3, 4, 5]
        } else {
            vec![1, 3, 4]
        };
        // Candidates: a ring of poses around the truth, 0.01–0.08 mm away, and the truth.
        let mut candidates = vec![q];
        for k in 0..11 {
            let (r, a) = (0.01 + 0.007 * k as f64, 0.9 * k as f64);
            candidates.push([q[0] + r * a.cos(), q[1] + r * a.sin()]);
        }
        let contours: Vec<Vec<f64>> = group
            .iter()
            .map(|&i| {
                candidates
                    .iter()
                    .map(|&c| {
                        let z = (row[i].unwrap() - model.feature_map(c)[i]) / sigma[i];
                        (-0.5 * z * z).exp()
                    })
                    .collect()
            })
            .collect();
        let functions: Vec<MassFunction> = contours.iter().map(|c| consonant_on(c)).collect();
        let combined = dempster_all(&functions).unwrap();
        let mass = combined.mass.expect("not in total conflict");
        let dempster: Vec<f64> = (0..candidates.len())
            .map(|k| mass.plausibility(&Subset::singleton(candidates.len(), k)))
            .collect();
        // (1) Relative plausibility: the tracker's contour product equals Dempster's.
        let ours: Vec<f64> = candidates
            .iter()
            .map(|&c| {
                model
                    .relative_plausibility(&row, &group, c)
                    .unwrap()
                    .unwrap()
            })
            .collect();
        let top = |v: &[f64]| v.iter().copied().fold(0.0f64, f64::max);
        for k in 0..candidates.len() {
            let (a, b) = (ours[k] / top(&ours), dempster[k] / top(&dempster));
            assert!(
                (a - b).abs() < 1e-9 * a.max(b).max(1e-300),
                "case {case} candidate {k}"
            );
        }
        // The same through the evidence room's own contour-product shortcut.
        let shortcut = contour_product(&functions).unwrap().unwrap();
        for k in 0..candidates.len() {
            let (a, b) = (shortcut[k] / top(&shortcut), dempster[k] / top(&dempster));
            assert!((a - b).abs() < 1e-9);
        }
        // (2) Level: Dempster's conflict on the candidates, −log of the hypervolume their contour
        // vectors dominate, is at most the product's height's −log over the same candidates (the
        // largest single box); equal when one candidate is best for every feature.
        let height: f64 = (0..candidates.len())
            .map(|k| contours.iter().map(|c| c[k]).product::<f64>())
            .fold(0.0, f64::max);
        let height_level = -height.ln();
        assert!(
            combined.conflict_level <= height_level + 1e-9,
            "case {case}"
        );
        let dominant =
            (0..candidates.len()).any(|k| contours.iter().all(|c| c.iter().all(|&v| v <= c[k])));
        if dominant {
            assert!(
                (combined.conflict_level - height_level).abs() < 1e-9,
                "case {case}"
            );
        }
        checked_bound += 1;
        // And the tracker's level, over every pose rather than the candidates, is no higher, up
        // to its grid cells' linear model of the maps (they bend by ~0.5 σ within a cell here;
        // measured 0.45 above on 1.71).
        let level = model.group_level(&row, &group).unwrap().unwrap();
        assert!(
            level <= height_level + 0.3 * (1.0 + height_level),
            "case {case}: {level} > {height_level}"
        );
    }
    assert_eq!(checked_bound, 12);
    // A single candidate dominating: the identity holds exactly.
    let contours = [
        vec![0.9, 0.5, 0.2],
        vec![0.7, 0.7, 0.1],
        vec![0.95, 0.3, 0.3],
    ];
    let functions: Vec<MassFunction> = contours.iter().map(|c| consonant_on(c)).collect();
    let level = dempster_all(&functions).unwrap().conflict_level;
    assert!((level + (0.9f64 * 0.7 * 0.95).ln()).abs() < 1e-12);
}

#[test]
fn model_files_round_trip_and_corrupted_ones_are_named() {
    let fixture = Fixture::new(0.002);
    let model = fixture.fit(&learned(), true);
    let text = model.to_json().unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("model-continuous.json");
    std::fs::write(&path, &text).unwrap();
    let loaded = load(&path).unwrap();
    assert_eq!(loaded.method(), "continuous");
    assert_eq!(loaded.to_json().unwrap(), text);
    for (_, row) in fixture.frames(20, 12) {
        assert_eq!(
            loaded.estimate(&row).unwrap(),
            model.estimate(&row).unwrap()
        );
    }
    let mut value: serde_json::Value = serde_json::from_str(&text).unwrap();
    value["residual_scales"][1] = serde_json::json!(-1.0);
    let err = Continuous::from_json(&value.to_string())
        .unwrap_err()
        .to_string();
    assert!(err.contains("residual_scales[1]"), "{err}");
    let mut value: serde_json::Value = serde_json::from_str(&text).unwrap();
    value["hyperparameters"].as_array_mut().unwrap().pop();
    let err = Continuous::from_json(&value.to_string())
        .unwrap_err()
        .to_string();
    assert!(err.contains("hyperparameters"), "{err}");
    let mut value: serde_json::Value = serde_json::from_str(&text).unwrap();
    value["hyperparameters"][0]["noise_std"] = serde_json::Value::Null;
    let err = Continuous::from_json(&value.to_string())
        .unwrap_err()
        .to_string();
    assert!(err.contains("noise_std") && err.contains("null"), "{err}");
    let err =
        Continuous::from_json(&text.replace("\"format_version\": 1", "\"format_version\": 9"))
            .unwrap_err()
            .to_string();
    assert!(err.contains("version"), "{err}");
}

#[test]
fn missing_and_non_finite_values_take_no_part() {
    let fixture = Fixture::new(0.002);
    let model = fixture.fit(&ContinuousSettings::default(), true);
    let (q, mut row) = fixture.frames(1, 13).remove(0);
    row[0] = None;
    row[4] = Some(f64::NAN);
    let e = model.estimate(&row).unwrap();
    assert_eq!(e.flags.missing, vec![0, 4]);
    assert_eq!(e.group.as_deref(), Some(&[1, 2, 3, 5][..]));
    assert!(distance(e.pose.unwrap(), q) < 0.05);
    // One feature left: a level curve, not a point, so no bounded region.
    let lone: Vec<Option<f64>> = (0..FEATURES).map(|i| row[i].filter(|_| i == 3)).collect();
    let e = model.estimate(&lone).unwrap();
    assert_eq!(e.group.as_deref(), Some(&[3][..]));
    assert!(e.pose.is_some() && e.region.is_none() && e.uncertainty_radius.is_none());
    // Absurd but finite values: no panic, an estimate inside the samples' box; a value no pose
    // explains is left out, and with every value absurd the level is infinite.
    let (q, mut wild) = fixture.frames(1, 15).remove(0);
    wild[2] = Some(1e300);
    let e = model.estimate(&wild).unwrap();
    assert!(!e.group.as_ref().unwrap().contains(&2));
    assert!(distance(e.pose.unwrap(), q) < 0.05);
    let all_wild = vec![Some(-1e300); FEATURES];
    let e = model.estimate(&all_wild).unwrap();
    let p = e.pose.unwrap();
    assert!(
        (-9.5..=9.5).contains(&p[0]) && (38.0..=57.0).contains(&p[1]),
        "{p:?}"
    );
    assert!(e.flags.fallback);
    // Nothing left: no estimate, no error.
    let e = model.estimate(&[None; FEATURES]).unwrap();
    assert!(e.pose.is_none() && e.group.is_none());
    assert!(matches!(
        model.estimate(&[Some(1.0)]),
        Err(EstimatorError::FeatureCount {
            expected: FEATURES,
            found: 1
        })
    ));
}

#[test]
fn without_a_validation_motion_the_noise_comes_from_held_out_samples() {
    let fixture = Fixture::new(0.002);
    let model = fixture.fit(&learned(), false);
    // No validation: nothing to learn a threshold on, Wilks' level for the region.
    assert!(!model.threshold_learned());
    assert!((model.region_level() - 0.1).abs() < 1e-12);
    for &s in model.residual_scales() {
        // Leave-one-out residuals hold the samples' noise (measured 1.00–1.07 × the noise: the
        // interpolation over 2 mm adds little on maps this smooth).
        assert!(s > 0.9 * fixture.noise && s < 1.3 * fixture.noise, "{s}");
    }
    let (q, row) = fixture.frames(1, 14).remove(0);
    assert!(distance(model.estimate(&row).unwrap().pose.unwrap(), q) < 0.05);
}

#[test]
fn settings_out_of_range_name_their_field() {
    let fixture = Fixture::new(0.002);
    let names = &fixture.names;
    let data = TrainingSet::new(
        names,
        Labelled {
            poses: &fixture.poses,
            rows: &fixture.rows,
        },
    );
    for (settings, field) in [
        (
            ContinuousSettings {
                region_share: 1.0,
                ..ContinuousSettings::default()
            },
            "continuous.region_share",
        ),
        (
            ContinuousSettings {
                grid_spacing: 0.0,
                ..ContinuousSettings::default()
            },
            "continuous.grid_spacing",
        ),
        (
            ContinuousSettings {
                threshold_rule: ThresholdRule::Quantile(1.5),
                ..ContinuousSettings::default()
            },
            "continuous.threshold_rule",
        ),
    ] {
        let err = Continuous::fit(&settings, &data).unwrap_err().to_string();
        assert!(err.contains(field), "{err}");
    }
}
