//! Model files: versioned JSON, validated on load.
//!
//! Layout (version 1): `format_version`, `sample_poses` ([x, y] per sample), `features` (per
//! feature: `name`, `requested_states`, `hmm` (initial, transitions, means, variances),
//! `log_likelihood`, `n_observations`, `states` (HMM state of every sample pose),
//! `removed_states`, `imputed`), `conflict_threshold` (number or null), `validation_errors`
//! (one per feature, or null) and `feature_config` (the features' settings, or null). The frame of a feature is its HMM states minus the removed ones;
//! on load the refinings are rebuilt from `states` and checked.

use super::{check_poses, check_validation_errors, EvidentialModel, FeatureModel, ModelError};
use crate::features::FeatureConfig;
use crate::hmm::GaussianHmm;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Version of the model file format written by this build (the only one it reads).
pub const FORMAT_VERSION: u32 = 1;

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct ModelFile {
    format_version: u32,
    sample_poses: Vec<[f64; 2]>,
    features: Vec<FeatureRecord>,
    conflict_threshold: Option<f64>,
    validation_errors: Option<Vec<f64>>,
    /// The feature configuration the model was trained with (optional: models trained on
    /// features computed elsewhere have none).
    #[serde(default)]
    feature_config: Option<FeatureConfig>,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct FeatureRecord {
    name: String,
    requested_states: usize,
    hmm: GaussianHmm,
    log_likelihood: f64,
    n_observations: usize,
    states: Vec<usize>,
    removed_states: Vec<usize>,
    imputed: Vec<usize>,
}

impl EvidentialModel {
    /// The model as versioned JSON text.
    pub fn to_json(&self) -> Result<String, ModelError> {
        let file = ModelFile {
            format_version: FORMAT_VERSION,
            sample_poses: self.sample_poses.clone(),
            features: self
                .features
                .iter()
                .map(|f| FeatureRecord {
                    name: f.name.clone(),
                    requested_states: f.requested_states,
                    hmm: f.hmm.clone(),
                    log_likelihood: f.log_likelihood,
                    n_observations: f.n_observations,
                    states: f.states.clone(),
                    removed_states: f.removed_states.clone(),
                    imputed: f.imputed.clone(),
                })
                .collect(),
            conflict_threshold: self.conflict_threshold,
            validation_errors: self.validation_errors.clone(),
            feature_config: self.feature_config.clone(),
        };
        serde_json::to_string_pretty(&file)
            .map_err(|e| ModelError::Corrupted(format!("cannot serialise the model: {e}")))
    }

    /// Reads a model from JSON text, checking the format version first, then every part: HMM
    /// parameters, one state per sample pose, removed states, refinings, threshold and
    /// validation errors.
    pub fn from_json(text: &str) -> Result<Self, ModelError> {
        let value: serde_json::Value =
            serde_json::from_str(text).map_err(|e| ModelError::Corrupted(e.to_string()))?;
        let version = value
            .as_object()
            .ok_or_else(|| ModelError::Corrupted("the top level is not a JSON object".into()))?
            .get("format_version")
            .ok_or(ModelError::MissingVersion)?;
        if version.as_u64() != Some(u64::from(FORMAT_VERSION)) {
            return Err(ModelError::UnsupportedVersion {
                found: version.to_string(),
                supported: FORMAT_VERSION,
            });
        }
        // Parsed again from the text so that errors carry line and column.
        let file: ModelFile =
            serde_json::from_str(text).map_err(|e| ModelError::Corrupted(e.to_string()))?;
        check_poses(&file.sample_poses).map_err(|e| ModelError::Corrupted(e.to_string()))?;
        if file.features.is_empty() {
            return Err(ModelError::Corrupted("the model has no features".into()));
        }
        let n = file.sample_poses.len();
        let mut features = Vec::with_capacity(file.features.len());
        for r in file.features {
            let bad = |what: String| ModelError::Corrupted(format!("feature `{}`: {what}", r.name));
            if features.iter().any(|f: &FeatureModel| f.name == r.name) {
                return Err(bad("the name appears twice".into()));
            }
            if r.states.len() != n {
                return Err(bad(format!(
                    "{} states for {n} sample poses",
                    r.states.len()
                )));
            }
            if !r.log_likelihood.is_finite() {
                return Err(bad("log_likelihood is not finite".into()));
            }
            if r.n_observations == 0 || r.n_observations > n {
                return Err(bad(format!(
                    "n_observations {} is not in 1..={n}",
                    r.n_observations
                )));
            }
            if r.requested_states == 0 {
                return Err(bad("requested_states is 0".into()));
            }
            if r.imputed.iter().any(|&i| i >= n) || r.imputed.windows(2).any(|w| w[0] >= w[1]) {
                return Err(bad(
                    "imputed must list sample indices in increasing order".into()
                ));
            }
            let removed = r.removed_states.clone();
            let model = FeatureModel::from_parts(
                r.name.clone(),
                r.requested_states,
                r.hmm,
                r.log_likelihood,
                r.n_observations,
                r.states,
                r.imputed,
            )
            .map_err(|e| match e {
                ModelError::Corrupted(_) => e,
                other => ModelError::Corrupted(other.to_string()),
            })?;
            if model.removed_states != removed {
                return Err(bad(format!(
                    "removed_states {removed:?} disagree with the states assigned to samples (unused: {:?})",
                    model.removed_states
                )));
            }
            features.push(model);
        }
        if let Some(t) = file.conflict_threshold {
            if !(t.is_finite() && t >= 0.0) {
                return Err(ModelError::Corrupted(format!(
                    "conflict_threshold {t} must be finite and >= 0"
                )));
            }
        }
        if let Some(e) = &file.validation_errors {
            check_validation_errors(e, features.len())
                .map_err(|e| ModelError::Corrupted(e.to_string()))?;
        }
        Ok(EvidentialModel {
            sample_poses: file.sample_poses,
            features,
            conflict_threshold: file.conflict_threshold,
            validation_errors: file.validation_errors,
            feature_config: file.feature_config,
        })
    }

    /// Writes the model to `path` as versioned JSON.
    pub fn save(&self, path: impl AsRef<Path>) -> Result<(), ModelError> {
        let path = path.as_ref();
        std::fs::write(path, self.to_json()?).map_err(|source| ModelError::Io {
            path: path.to_path_buf(),
            source,
        })
    }

    /// Reads and validates a model file written by [`EvidentialModel::save`].
    pub fn load(path: impl AsRef<Path>) -> Result<Self, ModelError> {
        let path = path.as_ref();
        let text = std::fs::read_to_string(path).map_err(|source| ModelError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Self::from_json(&text).map_err(|e| ModelError::File {
            path: path.to_path_buf(),
            source: Box::new(e),
        })
    }
}
