//! Ablation: each method fitted with every feature and with each one left out, on the report's
//! split; the change of its mean error on the held-out frames.

use crate::estimator::{EstimatorSettings, Labelled, Method, TrainingSet};

use super::information::Split;
use super::{FeatureReport, FeatureReportError};

type Rows = Vec<Vec<Option<f64>>>;

/// Fills each feature's ablation and the methods' errors with every feature.
pub(super) fn fill(
    report: &mut FeatureReport,
    names: &[String],
    split: &Split,
    methods: &[Method],
    progress: &mut dyn FnMut(&str, usize, usize),
) -> Result<(), FeatureReportError> {
    let n = names.len();
    if methods.is_empty() {
        return Ok(());
    }
    if n < 2 {
        report
            .notes
            .push("one feature: nothing to leave out, no ablation".into());
        return Ok(());
    }
    for &method in methods {
        if method.entry().over_time {
            return Err(FeatureReportError::Method {
                method: method.name().into(),
                message: "it tracks over time, and the report's held-out frames are not a \
                          motion: list per-frame methods"
                    .into(),
            });
        }
    }
    let settings = EstimatorSettings::default();
    let total = methods.len() * (n + 1);
    let mut done = 0;
    for &method in methods {
        let label = format!("ablation {}", method.name());
        progress(&label, done, total);
        let all = mean_error(method, &settings, split, names, None, "with every feature")?;
        done += 1;
        report.method_errors.insert(method.name().into(), all);
        for f in 0..n {
            progress(&label, done, total);
            let stage = format!("without `{}`", names[f]);
            let without = mean_error(method, &settings, split, names, Some(f), &stage)?;
            report.features[f]
                .ablation
                .insert(method.name().into(), without - all);
            done += 1;
        }
    }
    progress("ablation", done, total);
    Ok(())
}

/// The rows without column `left_out`.
fn drop_column(rows: &[Vec<Option<f64>>], left_out: Option<usize>) -> Rows {
    rows.iter()
        .map(|r| {
            (r.iter().enumerate())
                .filter(|&(j, _)| Some(j) != left_out)
                .map(|(_, v)| *v)
                .collect()
        })
        .collect()
}

/// The method's mean error (mm) on the held-out frames, fitted on the fit frames without
/// feature `left_out`; a frame without an estimate counts as the workspace diagonal.
fn mean_error(
    method: Method,
    settings: &EstimatorSettings,
    split: &Split,
    names: &[String],
    left_out: Option<usize>,
    stage: &str,
) -> Result<f64, FeatureReportError> {
    let failed = |source| FeatureReportError::Estimator {
        method: method.name().into(),
        stage: stage.into(),
        source,
    };
    let kept_names: Vec<String> = (names.iter().enumerate())
        .filter(|&(j, _)| Some(j) != left_out)
        .map(|(_, name)| name.clone())
        .collect();
    let fit_rows = drop_column(&split.fit_rows, left_out);
    let held_rows = drop_column(&split.held_rows, left_out);
    let training = TrainingSet {
        missing_penalty: split.missing_penalty,
        ..TrainingSet::new(
            &kept_names,
            Labelled {
                poses: &split.fit_poses,
                rows: &fit_rows,
            },
        )
    };
    let estimator = method.fit(settings, &training).map_err(failed)?;
    let mut sum = 0.0;
    for (row, truth) in held_rows.iter().zip(&split.held_poses) {
        let estimate = estimator.estimate(row).map_err(failed)?;
        sum += estimate.pose.map_or(split.missing_penalty, |p| {
            (p[0] - truth[0]).hypot(p[1] - truth[1])
        });
    }
    Ok(sum / held_rows.len() as f64)
}
