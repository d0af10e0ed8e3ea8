//! Model files: versioned JSON, self-contained, validated on load.
//!
//! Layout (version 2): `format_version`, `method` (`"evidential"`), `provenance` (`crate_version`,
//! `scenario`, `seed`), `feature_config` (the features' settings, or null), `track` (constructor,
//! conflict threshold (a number or `"inf"`), selection, estimator, uncertainty share),
//! `threshold_learned`, `validation_errors` (one per feature, or null), `group_errors` (optional:
//! `features` and `error` of each group, the splitting policy's reliabilities), `sample_poses` ([x, y] per
//! sample) and `features` (per feature: `name`, `requested_states`, `hmm` (initial, transitions,
//! means, variances), `log_likelihood`, `n_observations`, `states` (HMM state of every sample
//! pose), `removed_states`, `imputed`). The frame of a feature is its HMM states minus the removed
//! ones; on load the refinings are rebuilt from `states` and checked. Version 1 files (no tracker
//! settings, no provenance) are refused with a message saying so.

use super::frames::{check_names, check_poses};
use super::{EvidentialModel, FeatureFrames, FeatureModel, ModelError, ModelParts, Provenance};
use crate::features::FeatureConfig;
use crate::hmm::GaussianHmm;
use crate::track::{GroupError, TrackSettings};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Version of the model file format written by this build (the only one it reads).
pub const FORMAT_VERSION: u32 = 2;

/// The `method` field of an evidential model file.
pub const METHOD: &str = "evidential";

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct ModelFile {
    format_version: u32,
    method: String,
    provenance: Provenance,
    feature_config: Option<FeatureConfig>,
    track: TrackSettings,
    threshold_learned: bool,
    validation_errors: Option<Vec<f64>>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    group_errors: Vec<GroupError>,
    sample_poses: Vec<[f64; 2]>,
    features: Vec<FeatureRecord>,
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

/// Reads `format_version` and `method` first, so an old or foreign file is named as such rather
/// than reported as a field-by-field mismatch.
pub(crate) fn check_header(value: &serde_json::Value) -> Result<(), ModelError> {
    let object = value
        .as_object()
        .ok_or_else(|| ModelError::Corrupted("the top level is not a JSON object".into()))?;
    let version = object
        .get("format_version")
        .ok_or(ModelError::MissingVersion)?;
    if version.as_u64() != Some(u64::from(FORMAT_VERSION)) {
        return Err(ModelError::UnsupportedVersion {
            found: version.to_string(),
            supported: FORMAT_VERSION,
        });
    }
    match object.get("method").and_then(|m| m.as_str()) {
        Some(METHOD) => Ok(()),
        Some(other) => Err(ModelError::WrongMethod {
            found: other.to_string(),
            expected: METHOD,
        }),
        None => Err(ModelError::Corrupted(
            "no `method` field (a string naming the estimation method)".into(),
        )),
    }
}

impl EvidentialModel {
    /// The model as versioned JSON text.
    pub fn to_json(&self) -> Result<String, ModelError> {
        let parts = self.parts();
        let file = ModelFile {
            format_version: FORMAT_VERSION,
            method: METHOD.to_string(),
            provenance: parts.provenance.clone(),
            feature_config: parts.feature_config.clone(),
            track: parts.track.clone(),
            threshold_learned: parts.threshold_learned,
            validation_errors: parts.validation_errors.clone(),
            group_errors: parts.group_errors.clone(),
            sample_poses: parts.frames.sample_poses.clone(),
            features: parts
                .frames
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
        };
        serde_json::to_string_pretty(&file)
            .map_err(|e| ModelError::Corrupted(format!("cannot serialise the model: {e}")))
    }

    /// Reads a model from JSON text, checking the format version and method first, then every
    /// part: HMM parameters, one state per sample pose, removed states, refinings, tracker
    /// settings, feature configuration and validation errors.
    pub fn from_json(text: &str) -> Result<Self, ModelError> {
        let value: serde_json::Value =
            serde_json::from_str(text).map_err(|e| ModelError::Corrupted(e.to_string()))?;
        check_header(&value)?;
        // Parsed again from the text so that errors carry line and column.
        let file: ModelFile =
            serde_json::from_str(text).map_err(|e| ModelError::Corrupted(e.to_string()))?;
        check_poses(&file.sample_poses).map_err(|e| ModelError::Corrupted(e.to_string()))?;
        file.provenance
            .check_poses("sample_poses", &file.sample_poses)
            .map_err(ModelError::Corrupted)?;
        if file.features.is_empty() {
            return Err(ModelError::Corrupted("the model has no features".into()));
        }
        let n = file.sample_poses.len();
        let mut features = Vec::with_capacity(file.features.len());
        for r in file.features {
            features.push(feature_from_record(r, n)?);
        }
        let names: Vec<String> = features.iter().map(|f| f.name.clone()).collect();
        check_names(&names).map_err(|e| ModelError::Corrupted(e.to_string()))?;
        let frames = FeatureFrames {
            sample_poses: file.sample_poses,
            features,
        };
        EvidentialModel::new(ModelParts {
            frames,
            feature_config: file.feature_config,
            track: file.track,
            threshold_learned: file.threshold_learned,
            validation_errors: file.validation_errors,
            group_errors: file.group_errors,
            provenance: file.provenance,
        })
        .map_err(|e| ModelError::Corrupted(e.to_string()))
    }

    /// Writes the model to `path` as versioned JSON.
    pub fn save(&self, path: impl AsRef<Path>) -> Result<(), ModelError> {
        let path = path.as_ref();
        crate::atomic::write(path, self.to_json()?.as_bytes()).map_err(|source| ModelError::Io {
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

/// One feature of a model file, checked against the `n` sample poses.
fn feature_from_record(r: FeatureRecord, n: usize) -> Result<FeatureModel, ModelError> {
    let bad = |what: String| ModelError::Corrupted(format!("feature `{}`: {what}", r.name));
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
    let name = r.name.clone();
    let removed = r.removed_states.clone();
    let model = FeatureModel::from_parts(
        r.name,
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
        return Err(ModelError::Corrupted(format!(
            "feature `{name}`: removed_states {removed:?} disagree with the states assigned to samples (unused: {:?})",
            model.removed_states
        )));
    }
    Ok(model)
}
