//! The evidential model (paper §3.3–3.5, §4.3, §5.1–5.2), complete and self-contained: the
//! feature configuration, the frames of discernment of the features and their refinings onto the
//! sample poses, the tracker settings with the conflict threshold, the per-feature validation
//! errors and where the model came from.
//!
//! Training sees plain data only: the sample poses Q̃ of the sample trajectory and the feature
//! matrix measured along it (rows = samples, in trajectory order). Each feature gets one Gaussian
//! [`hmm`](crate::hmm) fitted on its column; the HMM states that receive at least one sample form
//! the feature's frame Θᵢ, and the state of every sample gives the refining ωᵢ: Θᵢ → Q̃
//! ([`FeatureFrames`]). A state that receives no sample is removed, and the model records it.
//!
//! Missing values (`None` or non-finite) are dropped from the HMM fit; such a sample is given the
//! state of the nearest sample pose (Euclidean, ties to the lower index) whose value is present, so
//! that every refining covers every sample pose. The model records which samples were imputed. A
//! feature with no value at all is an error.
//!
//! State counts are given per feature or tuned per feature within bounds (§5.2): by the Bayesian
//! information criterion of the HMM fit ([`Tuning::Bic`]), or by any score supplied through the
//! [`StateCountTuner`] hook (the tracker's validation error: [`Tuning::Validation`]).
//!
//! An [`EvidentialModel`] is built whole by [`EvidentialModel::new`] (the estimator's fit does it,
//! see [`crate::estimator`]), saved as versioned JSON ([`FORMAT_VERSION`]) and validated on load.

mod feature;
mod frames;
mod persist;
mod settings;

pub use feature::{FeatureModel, FeatureSummary};
pub use frames::{FeatureFrames, StateCountTuner, TunerError};
pub use persist::{FORMAT_VERSION, METHOD};
pub use settings::{ModelSettings, StateCounts, Tuning, MAX_STATES};

use crate::evidence::EvidenceError;
use crate::features::FeatureConfig;
use crate::hmm::HmmError;
use crate::model_file::ModelFileError;
use crate::model_file::Provenance;
use crate::track::{GroupError, TrackSettings};
use thiserror::Error;

/// Errors of model training, use, and persistence.
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum ModelError {
    /// No sample poses were given.
    #[error("no sample poses: the sample trajectory must have at least one sample")]
    NoSamples,
    /// No features were given.
    #[error("no features: give at least one feature column")]
    NoFeatures,
    /// The feature matrix does not have one row per sample pose.
    #[error(
        "{rows} feature rows for {poses} sample poses: give one row of features per sample pose"
    )]
    RowCount {
        /// Rows of the feature matrix.
        rows: usize,
        /// Number of sample poses.
        poses: usize,
    },
    /// A row of the feature matrix has the wrong length.
    #[error("feature row {row} has {got} values but there are {expected} feature names")]
    RowLength {
        /// Index of the row (sample).
        row: usize,
        /// Number of feature names.
        expected: usize,
        /// Length of the row.
        got: usize,
    },
    /// A feature column has the wrong length.
    #[error("feature `{feature}` has {got} values for {expected} sample poses")]
    ColumnLength {
        /// Feature name.
        feature: String,
        /// Number of sample poses.
        expected: usize,
        /// Number of values.
        got: usize,
    },
    /// A sample pose has a non-finite coordinate.
    #[error("sample pose {index} is not finite: {pose:?}")]
    NonFinitePose {
        /// Index of the pose.
        index: usize,
        /// The pose.
        pose: [f64; 2],
    },
    /// Two features share a name.
    #[error("feature name `{0}` appears twice: feature names must be unique")]
    DuplicateFeature(String),
    /// A feature has no finite value on the whole sample trajectory.
    #[error("feature `{feature}` has no finite value on the sample trajectory; drop it or fix its extraction")]
    NoValues {
        /// Feature name.
        feature: String,
    },
    /// A setting is out of range or does not fit the data.
    #[error("invalid model setting `{field}`: {reason}")]
    Settings {
        /// The offending field.
        field: &'static str,
        /// What is wrong and what is allowed.
        reason: String,
    },
    /// Validation tuning was asked for without a tuner.
    #[error("tuning method `validation` needs the tracker: call EvidentialModel::train_with_tuner with a StateCountTuner, or use `given` or `bic`")]
    TunerRequired,
    /// A tuner failed or returned a non-finite score.
    #[error("state-count tuner failed on feature `{feature}` with {states} states: {source}")]
    Tuner {
        /// Feature name.
        feature: String,
        /// Candidate state count.
        states: usize,
        /// What went wrong.
        source: TunerError,
    },
    /// Fitting or using a feature's HMM failed.
    #[error("feature `{feature}`: {source}")]
    Hmm {
        /// Feature name.
        feature: String,
        /// The HMM error.
        source: HmmError,
    },
    /// A refining could not be built.
    #[error("feature `{feature}`: invalid refining: {source}")]
    Refining {
        /// Feature name.
        feature: String,
        /// The evidence error.
        source: EvidenceError,
    },
    /// A value passed to the model (tracker settings, validation errors, per-frame features) is
    /// invalid.
    #[error("invalid {what}: {reason}")]
    InvalidInput {
        /// What was given.
        what: &'static str,
        /// What is wrong.
        reason: String,
    },
    /// Reading, checking or writing a model file failed.
    #[error(transparent)]
    File(#[from] ModelFileError),
}

/// Everything a complete [`EvidentialModel`] is made of, for [`EvidentialModel::new`].
#[derive(Debug, Clone, PartialEq)]
pub struct ModelParts {
    /// The trained frames and refinings.
    pub frames: FeatureFrames,
    /// The feature configuration the frames' features were extracted with (`None` for features
    /// computed elsewhere; such a model cannot track images, only feature rows).
    pub feature_config: Option<FeatureConfig>,
    /// Tracker settings, with the conflict threshold to use (learned or given).
    pub track: TrackSettings,
    /// Whether `track.conflict_threshold` was learned on a validation motion (§4.3).
    pub threshold_learned: bool,
    /// Each feature's own mean error on a validation motion (ranks the fallback), if measured.
    pub validation_errors: Option<Vec<f64>>,
    /// Each group's mean error on the validation motion (the splitting policy's reliabilities;
    /// empty when not measured).
    pub group_errors: Vec<GroupError>,
    /// Where the model came from.
    pub provenance: Provenance,
}

/// The complete evidential model: what tracking needs, and nothing set after the fact.
#[derive(Debug, Clone, PartialEq)]
pub struct EvidentialModel {
    parts: ModelParts,
}

impl EvidentialModel {
    /// Checks and assembles a model: the feature configuration (when given) names exactly the
    /// frames' features, the tracker settings pass their check, and the validation errors are one
    /// finite value ≥ 0 per feature.
    pub fn new(parts: ModelParts) -> Result<Self, ModelError> {
        if let Some(config) = &parts.feature_config {
            let set = config.check().map_err(|e| ModelError::InvalidInput {
                what: "feature configuration",
                reason: e.to_string(),
            })?;
            let names = set.names();
            if names != parts.frames.feature_names() {
                return Err(ModelError::InvalidInput {
                    what: "feature configuration",
                    reason: format!(
                        "it names the features {names:?}, but the model has {:?}",
                        parts.frames.feature_names()
                    ),
                });
            }
        }
        parts
            .track
            .clone()
            .check()
            .map_err(|e| ModelError::InvalidInput {
                what: "tracker settings",
                reason: e.to_string(),
            })?;
        if let Some(e) = &parts.validation_errors {
            check_validation_errors(e, parts.frames.n_features())?;
        }
        for g in &parts.group_errors {
            g.check(parts.frames.n_features())
                .map_err(|reason| ModelError::InvalidInput {
                    what: "group errors",
                    reason: format!("group {:?}: {reason}", g.features),
                })?;
        }
        Ok(Self { parts })
    }

    /// The parts the model was built from.
    pub fn parts(&self) -> &ModelParts {
        &self.parts
    }

    /// The trained frames and refinings.
    pub fn frames(&self) -> &FeatureFrames {
        &self.parts.frames
    }

    /// The sample poses Q̃, in trajectory order.
    pub fn sample_poses(&self) -> &[[f64; 2]] {
        self.parts.frames.sample_poses()
    }

    /// Feature names, in feature order.
    pub fn feature_names(&self) -> Vec<&str> {
        self.parts.frames.feature_names()
    }

    /// The feature configuration the model was trained with, when recorded.
    pub fn feature_config(&self) -> Option<&FeatureConfig> {
        self.parts.feature_config.as_ref()
    }

    /// The tracker settings, with the conflict threshold.
    pub fn track_settings(&self) -> &TrackSettings {
        &self.parts.track
    }

    /// Whether the conflict threshold was learned on a validation motion.
    pub fn threshold_learned(&self) -> bool {
        self.parts.threshold_learned
    }

    /// Per-feature validation errors, if measured.
    pub fn validation_errors(&self) -> Option<&[f64]> {
        self.parts.validation_errors.as_deref()
    }

    /// Per-group validation errors (empty when not measured).
    pub fn group_errors(&self) -> &[GroupError] {
        &self.parts.group_errors
    }

    /// Where the model came from.
    pub fn provenance(&self) -> &Provenance {
        &self.parts.provenance
    }

    /// The same model recording `provenance` instead (a fit shared with another run).
    pub fn with_provenance(&self, provenance: Provenance) -> Self {
        Self {
            parts: ModelParts {
                provenance,
                ..self.parts.clone()
            },
        }
    }

    /// The same model with other tracker settings (checked).
    pub fn with_track_settings(&self, track: TrackSettings) -> Result<Self, ModelError> {
        Self::new(ModelParts {
            track,
            ..self.parts.clone()
        })
    }
}

pub(crate) fn check_validation_errors(e: &[f64], n_features: usize) -> Result<(), ModelError> {
    if e.len() != n_features {
        return Err(ModelError::InvalidInput {
            what: "validation errors",
            reason: format!("{} values for {n_features} features", e.len()),
        });
    }
    if let Some(i) = e.iter().position(|x| !(x.is_finite() && *x >= 0.0)) {
        return Err(ModelError::InvalidInput {
            what: "validation errors",
            reason: format!("value {i} is {}, must be finite and >= 0", e[i]),
        });
    }
    Ok(())
}
