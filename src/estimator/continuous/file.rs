//! The continuous tracker's model file: its fields, and reading them back with every check.

use std::path::Path;

use serde::{Deserialize, Serialize};

use super::surrogate::{Surrogate, SurrogateHyperparameters};
use super::{Continuous, ContinuousSettings, MAX_CONTINUOUS_FEATURES};
use crate::estimator::inputs::check_header_features;
use crate::estimator::samples::check_samples;
use crate::estimator::EstimatorError;
use crate::evidence::ConflictLevel;
use crate::model_file::{self, check_finite, corrupted, Header};
use crate::standardisation::Standardisation;

/// The model file, and the fitted state.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct ContinuousFile {
    #[serde(flatten)]
    pub(super) header: Header,
    pub(super) settings: ContinuousSettings,
    pub(super) pose_standardisation: Standardisation,
    pub(super) feature_standardisation: Standardisation,
    /// One per feature.
    pub(super) hyperparameters: Vec<SurrogateHyperparameters>,
    /// σ_i of each feature (raw units) and where it came from (`validation` or `leave_one_out`).
    pub(super) residual_scales: Vec<f64>,
    pub(super) residual_source: String,
    /// The threshold the tracker applies, and whether it was learned.
    pub(super) conflict_threshold: ConflictLevel,
    pub(super) threshold_learned: bool,
    /// The region holds the poses with χ²(q) − χ²(q̂) ≤ this (−2 log of the plausibility level).
    pub(super) region_chi2: f64,
    /// The kept samples' poses (mm) and raw feature values.
    pub(super) sample_poses: Vec<[f64; 2]>,
    pub(super) sample_features: Vec<Vec<f64>>,
}

impl Continuous {
    /// Reads a model file's text, checking every field, then factors the kernel matrix as
    /// fitting did.
    ///
    /// # Errors
    /// [`EstimatorError::File`] naming what is wrong.
    pub fn from_json(text: &str) -> Result<Self, EstimatorError> {
        let file: ContinuousFile = model_file::parse(text, Self::METHOD, Self::FORMAT_VERSION)?;
        let dim = file.header.feature_names.len();
        check_header_features(&file.header)?;
        if dim > MAX_CONTINUOUS_FEATURES {
            return Err(corrupted(format!(
                "{dim} features: the continuous tracker takes at most {MAX_CONTINUOUS_FEATURES}"
            ))
            .into());
        }
        file.settings
            .check()
            .map_err(|e| corrupted(format!("`settings`: {e}")))?;
        file.pose_standardisation
            .check(2, "pose_standardisation")
            .map_err(model_file::corrupted)?;
        file.header
            .provenance
            .check_poses("sample_poses", &file.sample_poses)?;
        file.feature_standardisation
            .check(dim, "feature_standardisation")
            .map_err(model_file::corrupted)?;
        if file.hyperparameters.len() != dim {
            return Err(corrupted(format!(
                "`hyperparameters` has {} entries for {dim} features",
                file.hyperparameters.len()
            ))
            .into());
        }
        let mut named = vec![("region_chi2".to_string(), file.region_chi2)];
        for (i, h) in file.hyperparameters.iter().enumerate() {
            named.extend([
                (
                    format!("hyperparameters[{i}].length_scales[0]"),
                    h.length_scales[0],
                ),
                (
                    format!("hyperparameters[{i}].length_scales[1]"),
                    h.length_scales[1],
                ),
                (format!("hyperparameters[{i}].signal_std"), h.signal_std),
                (format!("hyperparameters[{i}].noise_std"), h.noise_std),
            ]);
        }
        for (field, v) in named {
            if !(v.is_finite() && v > 0.0) {
                return Err(corrupted(format!("`{field}` is {v}, not a positive number")).into());
            }
        }
        if file.residual_scales.len() != dim {
            return Err(corrupted(format!(
                "`residual_scales` has {} values for {dim} features",
                file.residual_scales.len()
            ))
            .into());
        }
        if let Some(i) = (file.residual_scales.iter()).position(|s| !(s.is_finite() && *s >= 0.0)) {
            return Err(
                corrupted(format!("`residual_scales[{i}]` is not a finite number ≥ 0")).into(),
            );
        }
        if !file.conflict_threshold.is_valid() {
            return Err(corrupted("`conflict_threshold` must be a number ≥ 0 or \"inf\"").into());
        }
        let likelihoods: Vec<f64> = (file.hyperparameters.iter())
            .map(|h| h.log_marginal_likelihood)
            .collect();
        check_finite("hyperparameters[].log_marginal_likelihood", &likelihoods)?;
        check_samples(&file.sample_poses, &file.sample_features, dim)?;
        (file.feature_standardisation)
            .check_rows(
                &file.sample_features,
                "sample_features",
                "feature_standardisation",
            )
            .and_then(|()| {
                (file.pose_standardisation).check_rows(
                    &file.sample_poses,
                    "sample_poses",
                    "pose_standardisation",
                )
            })
            .map_err(corrupted)?;
        let surrogate = Surrogate::new(
            file.pose_standardisation.clone(),
            file.feature_standardisation.clone(),
            &file.hyperparameters,
            &file.sample_poses,
            &file.sample_features,
            file.settings.grid_spacing,
            false,
        )
        .map_err(corrupted)?;
        Ok(Self::assemble(file, surrogate))
    }

    /// Reads a model file written from [`PoseEstimator::to_json`](crate::estimator::PoseEstimator::to_json).
    ///
    /// # Errors
    /// [`EstimatorError::Io`] when it cannot be read; [`EstimatorError::File`] naming the path
    /// and what is wrong otherwise.
    pub fn load(path: &Path) -> Result<Self, EstimatorError> {
        Ok(model_file::load(path, Self::from_json)?)
    }
}
