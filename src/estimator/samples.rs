//! The sample rows a method keeps and the checks of loaded samples, shared by the methods that
//! store their samples (k-NN, the GP, the continuous tracker).

use super::inputs::complete_samples;
use super::{EstimatorError, TrainingSet};
use crate::model_file::{self, check_finite};

/// A corrupted-file error, as the loaders of these methods return it.
fn corrupted(what: impl Into<String>) -> EstimatorError {
    model_file::corrupted(what).into()
}

/// Sample poses (mm) and their feature rows.
pub(super) type Samples = (Vec<[f64; 2]>, Vec<Vec<f64>>);

/// The sample rows a baseline keeps (every value present and finite) and their poses.
pub(super) fn kept_samples(data: &TrainingSet, method: &str) -> Result<Samples, EstimatorError> {
    let kept = complete_samples(data, method)?;
    let poses = kept.iter().map(|&i| data.sample.poses[i]).collect();
    let rows = kept
        .iter()
        .map(|&i| {
            data.sample.rows[i]
                .iter()
                .map(|v| v.unwrap_or(0.0))
                .collect()
        })
        .collect();
    Ok((poses, rows))
}

/// Checks loaded sample poses and feature rows: as many rows as poses (at least one), `dim`
/// values per row, everything finite.
pub(super) fn check_samples(
    poses: &[[f64; 2]],
    rows: &[Vec<f64>],
    dim: usize,
) -> Result<(), EstimatorError> {
    if poses.is_empty() {
        return Err(corrupted("`sample_poses` is empty"));
    }
    if rows.len() != poses.len() {
        return Err(corrupted(format!(
            "`sample_features` has {} rows for {} sample poses",
            rows.len(),
            poses.len()
        )));
    }
    for (i, p) in poses.iter().enumerate() {
        check_finite(&format!("sample_poses[{i}]"), p)?;
    }
    for (i, r) in rows.iter().enumerate() {
        if r.len() != dim {
            return Err(corrupted(format!(
                "`sample_features[{i}]` has {} values for {dim} features",
                r.len()
            )));
        }
        check_finite(&format!("sample_features[{i}]"), r)?;
    }
    Ok(())
}
