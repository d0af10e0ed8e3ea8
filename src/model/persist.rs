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
use super::{EvidentialModel, FeatureFrames, FeatureModel, ModelError, ModelParts};
use crate::features::FeatureConfig;
use crate::hmm::GaussianHmm;
use crate::model_file::{self, corrupted, ModelFileError, Provenance, Stamp};
use crate::track::{GroupError, TrackSettings};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Version of the model file format written by this build (the only one it reads). 3: the
/// stated covariance adds the sample poses' cells, so a version-2 file's calibrated radius,
/// learned without them, is refused rather than applied to wider regions.
pub const FORMAT_VERSION: u32 = 3;

/// The `method` field of an evidential model file.
pub const METHOD: &str = "evidential";

/// The file: its stamp, provenance and feature configuration first; the names are the
/// features' own.
#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct ModelFile {
    #[serde(flatten)]
    stamp: Stamp,
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

impl EvidentialModel {
    /// The model as versioned JSON text.
    pub fn to_json(&self) -> Result<String, ModelFileError> {
        let parts = self.parts();
        let file = ModelFile {
            stamp: Stamp::new(METHOD, FORMAT_VERSION),
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
        model_file::to_text(&file)
    }

    /// Reads a model from JSON text, checking the format version and method first, then every
    /// part: HMM parameters, one state per sample pose, removed states, refinings, tracker
    /// settings, feature configuration and validation errors.
    pub fn from_json(text: &str) -> Result<Self, ModelFileError> {
        let file: ModelFile = model_file::parse_with_nulls(text, METHOD, FORMAT_VERSION)?;
        check_poses(&file.sample_poses).map_err(|e| corrupted(e.to_string()))?;
        file.provenance
            .check_poses("sample_poses", &file.sample_poses)?;
        if file.features.is_empty() {
            return Err(corrupted("the model has no features"));
        }
        let n = file.sample_poses.len();
        let mut features = Vec::with_capacity(file.features.len());
        for r in file.features {
            features.push(feature_from_record(r, n)?);
        }
        let names: Vec<String> = features.iter().map(|f| f.name.clone()).collect();
        check_names(&names).map_err(|e| corrupted(e.to_string()))?;
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
        .map_err(|e| corrupted(e.to_string()))
    }

    /// Writes the model to `path` as versioned JSON.
    pub fn save(&self, path: impl AsRef<Path>) -> Result<(), ModelFileError> {
        model_file::write_text(path.as_ref(), &self.to_json()?)
    }

    /// Reads and validates a model file written by [`EvidentialModel::save`].
    pub fn load(path: impl AsRef<Path>) -> Result<Self, ModelFileError> {
        model_file::load(path.as_ref(), Self::from_json)
    }
}

/// One feature of a model file, checked against the `n` sample poses.
fn feature_from_record(r: FeatureRecord, n: usize) -> Result<FeatureModel, ModelFileError> {
    let bad = |what: String| corrupted(format!("feature `{}`: {what}", r.name));
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
        ModelError::File(f) => f,
        other => corrupted(other.to_string()),
    })?;
    if model.removed_states != removed {
        return Err(corrupted(format!(
            "feature `{name}`: removed_states {removed:?} disagree with the states assigned to samples (unused: {:?})",
            model.removed_states
        )));
    }
    Ok(model)
}
