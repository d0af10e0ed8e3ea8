//! The detection score sees every feature, whatever its length scale, and the calibration it is
//! held to rides through the model file.

use super::*;
use crate::estimator::{
    load_text, underlying, Calibrated, Calibration, ConfidenceSettings, Labelled, Method,
};

/// A 9 × 9 mesh of poses (1 mm apart) and three features of them: x, y and a smooth mix.
fn mesh() -> (Vec<[f64; 2]>, Vec<Vec<f64>>) {
    let poses: Vec<[f64; 2]> = (0..81)
        .map(|i| [f64::from(i % 9), 40.0 + f64::from(i / 9)])
        .collect();
    let rows = poses.iter().map(|p| features(*p)).collect();
    (poses, rows)
}

fn features(p: [f64; 2]) -> Vec<f64> {
    let (x, y) = (p[0], p[1] - 40.0);
    vec![x, y, (0.3 * x).sin() + 0.1 * y * y]
}

/// A GP on the mesh with the given length scales, fitted by hand (no optimisation).
fn gp(length_scales: Vec<f64>) -> Gp {
    let (poses, rows) = mesh();
    let names = ["x".to_string(), "y".to_string(), "mix".to_string()];
    let present: Vec<Vec<Option<f64>>> = (rows.iter())
        .map(|r| r.iter().map(|v| Some(*v)).collect())
        .collect();
    let data = TrainingSet::new(
        &names,
        Labelled {
            poses: &poses,
            rows: &present,
        },
    );
    let file = GpFile {
        header: training_header(Gp::METHOD, Gp::FORMAT_VERSION, &data),
        settings: GpSettings::default(),
        standardisation: Standardisation::fit(&rows, 3),
        output: Standardisation::fit(&pose_rows(&poses), 2),
        hyperparameters: GpHyperparameters {
            length_scales,
            signal_std: 1.0,
            noise_std: 0.01,
        },
        log_marginal_likelihood: 0.0,
        sample_poses: poses,
        sample_features: rows,
    };
    Gp::factor(file).expect("factors")
}

fn score(gp: &Gp, values: &[f64]) -> f64 {
    let features: Vec<Option<f64>> = values.iter().map(|v| Some(*v)).collect();
    gp.estimate(&features).unwrap().detection_score.unwrap()
}

#[test]
fn the_score_sees_a_feature_the_kernel_ignores() {
    // The kernel ignores the mix (length scale 1000): shifting it by three of its standard
    // deviations barely moves the pose, nor the nearest sample's ARD-scaled distance.
    let gp = gp(vec![1.0, 1.0, 1000.0]);
    let spread = gp.file.standardisation.scales[2];
    let pose = [4.3, 43.6];
    let clean = features(pose);
    let mut struck = clean.clone();
    struck[2] += 3.0 * spread;
    let (clean_score, struck_score) = (score(&gp, &clean), score(&gp, &struck));
    assert!(clean_score < 0.2, "clean {clean_score}");
    assert!(
        struck_score > 2.5 && struck_score > 15.0 * clean_score,
        "struck {struck_score} against clean {clean_score}"
    );
    let ard = |v: &[f64]| {
        let h = &gp.file.hyperparameters;
        let q: Vec<f64> = (v.iter().enumerate())
            .map(|(d, x)| gp.file.standardisation.apply(d, *x) / h.length_scales[d])
            .collect();
        (gp.factor.inputs.chunks_exact(3))
            .map(|row| squared_distance(row, &q).sqrt())
            .fold(f64::INFINITY, f64::min)
    };
    assert!((ard(&struck) - ard(&clean)).abs() < 0.01);
    // A value far beyond the samples overflows the squares: the score is still finite and huge
    // (the calibration abstains), not infinite.
    let mut wild = clean;
    wild[0] = 1e200;
    let far = score(&gp, &wild);
    assert!(far.is_finite() && far > 1e199, "{far}");
}

#[test]
fn on_the_samples_the_score_is_small_and_its_calibration_round_trips() {
    let gp = gp(vec![1.0, 1.0, 1000.0]);
    let (poses, rows) = mesh();
    for (p, r) in poses.iter().zip(&rows).step_by(7) {
        let e = gp
            .estimate(&r.iter().map(|v| Some(*v)).collect::<Vec<_>>())
            .unwrap();
        // The local surface misses the mix (not quite quadratic) by a little, most at the edges.
        let score = e.detection_score.unwrap();
        assert!(score < 0.5, "{score} at {p:?}");
    }
    // Calibrated on a clean path between the samples, then written and read back: the same
    // regions, scores and abstentions, the struck frame abstaining.
    let path: Vec<[f64; 2]> = (0..200)
        .map(|i| {
            let t = f64::from(i) * 0.05;
            [4.0 + 3.0 * t.sin(), 44.0 + 3.0 * (0.7 * t).cos()]
        })
        .collect();
    let path_rows: Vec<Vec<Option<f64>>> = (path.iter())
        .map(|p| features(*p).into_iter().map(Some).collect())
        .collect();
    let names = ["x".to_string(), "y".to_string(), "mix".to_string()];
    let sample_rows: Vec<Vec<Option<f64>>> = (rows.iter())
        .map(|r| r.iter().map(|v| Some(*v)).collect())
        .collect();
    let data = TrainingSet {
        validation: Some(Labelled {
            poses: &path,
            rows: &path_rows,
        }),
        ..TrainingSet::new(
            &names,
            Labelled {
                poses: &poses,
                rows: &sample_rows,
            },
        )
    };
    let calibration = Calibration::learn(&gp, &data, &ConfidenceSettings::default())
        .unwrap()
        .expect("a validation motion");
    assert!(calibration.detection_limit.is_some_and(|l| l > 0.0));
    let calibrated = Calibrated::new(Box::new(gp.clone()), calibration.clone());
    let text = calibrated.to_json().unwrap();
    let loaded = load_text(Method::GP, Path::new("gp.json"), &text).unwrap();
    let read = underlying(loaded.as_ref());
    assert_eq!(read.method(), Gp::METHOD);
    let mut struck = features([5.5, 45.5]);
    struck[2] += 3.0 * gp.file.standardisation.scales[2];
    let mut frames = path_rows.clone();
    frames.push(struck.into_iter().map(Some).collect());
    let mut abstained = Vec::new();
    for (i, frame) in frames.iter().enumerate() {
        let (a, b) = (
            calibrated.estimate(frame).unwrap(),
            loaded.estimate(frame).unwrap(),
        );
        assert_eq!(format!("{a:?}"), format!("{b:?}"), "frame {i}");
        if a.flags.abstained {
            abstained.push(i);
        }
    }
    // The clean path abstains on about 1 % of its frames (the limit is its 199th of 200).
    assert_eq!(abstained.last(), Some(&path.len()));
    assert!(abstained.len() <= 3, "{abstained:?}");
    assert_eq!(
        calibration.validation_abstained,
        (abstained.len() - 1) as f64 / 200.0
    );
}
