//! What every method checks of what it is given: a training set (feature names and
//! configuration, sample poses and rows), a frame's feature values, and the features a loaded
//! file's header names. Errors of a model file read through an estimator come back as
//! [`ModelFileError`]s naming the path.

use super::{EstimatorError, TrainingSet};
use crate::features::FeatureConfig;
use crate::model::ModelError;
use crate::model_file::{corrupted, Header, ModelFileError};

/// The header of a model file fitted on `data` by `method` (file format `version`).
pub(super) fn training_header(method: &str, version: u32, data: &TrainingSet) -> Header {
    Header {
        format_version: version,
        method: method.to_string(),
        provenance: data.provenance.clone(),
        feature_config: data.feature_config.cloned(),
        feature_names: data.feature_names.to_vec(),
    }
}

/// Checks a loaded header's features as [`check_features`] does at fitting time.
pub(super) fn check_header_features(header: &Header) -> Result<(), ModelFileError> {
    check_features(&header.feature_names, header.feature_config.as_ref())
        .map_err(|e| corrupted(e.to_string()))
}

/// What an estimator's `from_json` refused, as a model-file error (a file error as it is, any
/// other error as what is corrupted).
impl From<EstimatorError> for ModelFileError {
    fn from(e: EstimatorError) -> Self {
        match e {
            EstimatorError::File(f) | EstimatorError::Model(ModelError::File(f)) => f,
            other => corrupted(other.to_string()),
        }
    }
}

/// Checks what every baseline needs of a training set: feature names (at least one, unique,
/// matching the feature configuration when there is one), at least one sample pose, all finite,
/// and one row per pose with one value per feature.
pub(super) fn check_training(data: &TrainingSet) -> Result<(), EstimatorError> {
    check_features(data.feature_names, data.feature_config)?;
    let (poses, rows) = (data.sample.poses, data.sample.rows);
    if poses.is_empty() {
        return Err(ModelError::NoSamples.into());
    }
    if let Some(index) = poses.iter().position(|p| !p.iter().all(|v| v.is_finite())) {
        return Err(ModelError::NonFinitePose {
            index,
            pose: poses[index],
        }
        .into());
    }
    if rows.len() != poses.len() {
        return Err(ModelError::RowCount {
            rows: rows.len(),
            poses: poses.len(),
        }
        .into());
    }
    let expected = data.feature_names.len();
    if let Some(row) = rows.iter().position(|r| r.len() != expected) {
        return Err(ModelError::RowLength {
            row,
            expected,
            got: rows[row].len(),
        }
        .into());
    }
    Ok(())
}

/// Feature names are at least one and unique, and the configuration (if any) names exactly them.
pub(super) fn check_features(
    names: &[String],
    config: Option<&FeatureConfig>,
) -> Result<(), EstimatorError> {
    if names.is_empty() {
        return Err(ModelError::NoFeatures.into());
    }
    let mut sorted: Vec<&String> = names.iter().collect();
    sorted.sort();
    if let Some(w) = sorted.windows(2).find(|w| w[0] == w[1]) {
        return Err(ModelError::DuplicateFeature(w[0].clone()).into());
    }
    if let Some(config) = config {
        let configured = config.check()?.names();
        if configured != names {
            return Err(ModelError::InvalidInput {
                what: "feature configuration",
                reason: format!(
                    "it names the features {configured:?}, but the model has {names:?}"
                ),
            }
            .into());
        }
    }
    Ok(())
}

/// Indices of the samples whose every feature value is present and finite (the rows a method
/// that needs every feature can use). Errors when there is none.
pub(super) fn complete_samples(
    data: &TrainingSet,
    method: &str,
) -> Result<Vec<usize>, EstimatorError> {
    let kept: Vec<usize> = (0..data.sample.rows.len())
        .filter(|&i| {
            data.sample.rows[i]
                .iter()
                .all(|v| v.is_some_and(f64::is_finite))
        })
        .collect();
    if kept.is_empty() {
        return Err(EstimatorError::Training(format!(
            "no sample has every feature value present and finite, and {method} drops samples with a missing value"
        )));
    }
    Ok(kept)
}

/// A frame's values after the count check: non-finite values count as missing. Returns the
/// values and the ascending indices of the missing ones.
pub(super) fn frame_values(
    features: &[Option<f64>],
    expected: usize,
) -> Result<(Vec<Option<f64>>, Vec<usize>), EstimatorError> {
    if features.len() != expected {
        return Err(EstimatorError::FeatureCount {
            expected,
            found: features.len(),
        });
    }
    let values: Vec<Option<f64>> = features
        .iter()
        .map(|v| v.filter(|x| x.is_finite()))
        .collect();
    let missing = (0..expected).filter(|&i| values[i].is_none()).collect();
    Ok((values, missing))
}

/// A model-file error as an estimator's: a file that cannot be read stays
/// [`EstimatorError::Io`], as it always was.
impl From<ModelFileError> for EstimatorError {
    fn from(e: ModelFileError) -> Self {
        match e {
            ModelFileError::Io { path, source } => EstimatorError::Io {
                path: path.display().to_string(),
                source,
            },
            other => EstimatorError::File(other),
        }
    }
}

/// The Euclidean norm of `terms` without overflow in the squares: each term is divided by the
/// largest first; +∞ only when a term itself is. Methods call it only where their plain sum of
/// squares overflowed, so ordinary frames keep their bits.
pub(crate) fn scaled_norm(terms: impl Iterator<Item = f64> + Clone) -> f64 {
    let largest = terms.clone().fold(0.0, |m: f64, t| m.max(t.abs()));
    if largest == 0.0 || !largest.is_finite() {
        return largest;
    }
    largest * terms.map(|t| (t / largest).powi(2)).sum::<f64>().sqrt()
}

#[cfg(test)]
mod tests {
    use super::scaled_norm;

    #[test]
    fn the_scaled_norm_survives_squares_beyond_the_double_range() {
        let terms = [3e200, -4e200];
        assert!(terms.iter().map(|t| t * t).sum::<f64>().is_infinite());
        let norm = scaled_norm(terms.iter().copied());
        assert!((norm / 5e200 - 1.0).abs() < 1e-15, "{norm}");
        assert_eq!(scaled_norm([0.0, 0.0].into_iter()), 0.0);
        assert_eq!(scaled_norm([1.0, f64::INFINITY].into_iter()), f64::INFINITY);
    }
}
