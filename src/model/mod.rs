//! The evidential model (paper §3.3–3.5, §5.1–5.2): the frames of discernment of the features and
//! their refinings onto the sample poses.
//!
//! Training sees plain data only: the sample poses Q̃ of the sample trajectory and the feature
//! matrix measured along it (rows = samples, in trajectory order). Each feature gets one Gaussian
//! [`hmm`](crate::hmm) fitted on its column; the HMM states that receive at least one sample form
//! the feature's frame Θᵢ, and the state of every sample gives the refining ωᵢ: Θᵢ → Q̃. A state
//! that receives no sample is removed, and the model records it.
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
//! Models are saved as versioned JSON ([`FORMAT_VERSION`]) and validated on load.

mod persist;

pub use persist::FORMAT_VERSION;

use crate::evidence::{EvidenceError, Refining};
use crate::features::FeatureConfig;
use crate::hmm::{AssignmentRule, GaussianHmm, HmmError, HmmSettings};
use serde::{Deserialize, Serialize};
use std::fmt;
use std::path::PathBuf;
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
    /// A value passed to the model (threshold, validation errors, per-frame features) is invalid.
    #[error("invalid {what}: {reason}")]
    InvalidInput {
        /// What was given.
        what: &'static str,
        /// What is wrong.
        reason: String,
    },
    /// A model file has no `format_version` field.
    #[error("not a model file: no `format_version` field (expected {FORMAT_VERSION})")]
    MissingVersion,
    /// A model file has a format version this build cannot read.
    #[error("model file format version {found} is not supported (this build reads version {supported}); retrain the model or use a matching evitrack")]
    UnsupportedVersion {
        /// Version in the file.
        found: String,
        /// Version this build reads.
        supported: u32,
    },
    /// A model file is not valid JSON or does not describe a valid model.
    #[error("corrupted model file: {0}")]
    Corrupted(String),
    /// Reading or writing a model file failed.
    #[error("model file {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// Loading a model file failed (the path, then the reason).
    #[error("model file {path}: {source}")]
    File {
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        source: Box<ModelError>,
    },
}

/// State counts: one for every feature, or one per feature in feature order.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum StateCounts {
    /// The same count for every feature.
    All(usize),
    /// One count per feature.
    PerFeature(Vec<usize>),
}

impl Default for StateCounts {
    fn default() -> Self {
        StateCounts::All(3)
    }
}

impl StateCounts {
    /// The count of each of `n_features` features; errors when a list has the wrong length or a
    /// count is 0.
    pub fn resolve(
        &self,
        n_features: usize,
        field: &'static str,
    ) -> Result<Vec<usize>, ModelError> {
        let counts = match self {
            StateCounts::All(n) => vec![*n; n_features],
            StateCounts::PerFeature(v) => {
                if v.len() != n_features {
                    return Err(ModelError::Settings {
                        field,
                        reason: format!(
                            "{} counts for {n_features} features: give one count or one per feature",
                            v.len()
                        ),
                    });
                }
                v.clone()
            }
        };
        if let Some(i) = counts.iter().position(|&n| n == 0) {
            return Err(ModelError::Settings {
                field,
                reason: format!("count for feature {i} is 0, must be at least 1"),
            });
        }
        Ok(counts)
    }
}

/// How the state count of each feature is chosen (§5.2), each feature separately.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(tag = "method", rename_all = "snake_case", deny_unknown_fields)]
pub enum Tuning {
    /// Use [`ModelSettings::states`] as given.
    #[default]
    Given,
    /// The count within bounds (inclusive) with the lowest Bayesian information criterion
    /// −2 ln L + p ln N of the HMM fit; ties go to fewer states.
    Bic {
        /// Lower bounds.
        min_states: StateCounts,
        /// Upper bounds.
        max_states: StateCounts,
    },
    /// The count within bounds (inclusive) with the lowest score from a [`StateCountTuner`]
    /// (the tracker's estimation error on a validation motion); ties go to fewer states.
    Validation {
        /// Lower bounds.
        min_states: StateCounts,
        /// Upper bounds.
        max_states: StateCounts,
    },
}

/// Settings of model training.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ModelSettings {
    /// HMM state count per feature (used when `tuning` is `given`): `states = 3` or
    /// `states = [3, 4, ...]`; default 3.
    pub states: StateCounts,
    /// EM settings shared by every feature, including the state assignment rule.
    pub hmm: HmmSettings,
    /// Seed of every random draw of training (each feature and state count gets a seed derived
    /// from it); default 0.
    pub seed: u64,
    /// How state counts are chosen, e.g. `[tuning] method = "bic", min_states = 2,
    /// max_states = 6`; default `given`.
    pub tuning: Tuning,
}

impl ModelSettings {
    /// Checks what can be checked without the data: HMM settings, non-zero counts, bounds in
    /// order (per-feature lists are checked against the number of features at training).
    pub fn check(&self) -> Result<(), ModelError> {
        self.hmm.check().map_err(|e| ModelError::Settings {
            field: "hmm",
            reason: e.to_string(),
        })?;
        let nonzero = |c: &StateCounts, field: &'static str| {
            let ok = match c {
                StateCounts::All(n) => *n > 0,
                StateCounts::PerFeature(v) => v.iter().all(|&n| n > 0),
            };
            if !ok {
                Err(ModelError::Settings {
                    field,
                    reason: "state counts must be at least 1".into(),
                })
            } else {
                Ok(())
            }
        };
        nonzero(&self.states, "states")?;
        if let Tuning::Bic {
            min_states,
            max_states,
        }
        | Tuning::Validation {
            min_states,
            max_states,
        } = &self.tuning
        {
            nonzero(min_states, "tuning.min_states")?;
            nonzero(max_states, "tuning.max_states")?;
            if let (StateCounts::All(lo), StateCounts::All(hi)) = (min_states, max_states) {
                if lo > hi {
                    return Err(ModelError::Settings {
                        field: "tuning",
                        reason: format!("min_states {lo} is above max_states {hi}"),
                    });
                }
            }
        }
        Ok(())
    }

    /// Inclusive state-count range of each of `n_features` features (one count when they are
    /// given); errors when a list has the wrong length, a count is 0 or a range is reversed.
    pub fn state_ranges(&self, n_features: usize) -> Result<Vec<(usize, usize)>, ModelError> {
        match &self.tuning {
            Tuning::Given => Ok(self
                .states
                .resolve(n_features, "states")?
                .into_iter()
                .map(|n| (n, n))
                .collect()),
            Tuning::Bic {
                min_states,
                max_states,
            }
            | Tuning::Validation {
                min_states,
                max_states,
            } => {
                let lo = min_states.resolve(n_features, "tuning.min_states")?;
                let hi = max_states.resolve(n_features, "tuning.max_states")?;
                lo.into_iter()
                    .zip(hi)
                    .enumerate()
                    .map(|(f, (lo, hi))| {
                        if lo > hi {
                            Err(ModelError::Settings {
                                field: "tuning",
                                reason: format!(
                                    "feature {f}: min_states {lo} is above max_states {hi}"
                                ),
                            })
                        } else {
                            Ok((lo, hi))
                        }
                    })
                    .collect()
            }
        }
    }
}

/// Error returned by a [`StateCountTuner`] (any error type, boxed).
pub type TunerError = Box<dyn std::error::Error + Send + Sync>;

/// Hook for tuning state counts by a score the model cannot compute itself, such as the
/// tracker's estimation error on a validation motion (§5.2).
pub trait StateCountTuner {
    /// Score of `candidate` (the model of feature number `feature`, trained with
    /// `candidate.requested_states()` states on the sample poses `sample_poses`); lower is
    /// better. An `Err` aborts training with [`ModelError::Tuner`].
    fn score(
        &mut self,
        feature: usize,
        candidate: &FeatureModel,
        sample_poses: &[[f64; 2]],
    ) -> Result<f64, TunerError>;
}

/// One feature of the model: its HMM, its frame Θᵢ (the kept HMM states) and its refining
/// ωᵢ onto the sample poses.
#[derive(Debug, Clone, PartialEq)]
pub struct FeatureModel {
    name: String,
    requested_states: usize,
    hmm: GaussianHmm,
    log_likelihood: f64,
    n_observations: usize,
    /// HMM state of every sample pose.
    states: Vec<usize>,
    /// HMM state index of every frame element, ascending.
    kept_states: Vec<usize>,
    removed_states: Vec<usize>,
    /// Samples whose value was missing (state by the nearest-pose rule).
    imputed: Vec<usize>,
    refining: Refining,
}

impl FeatureModel {
    /// Builds a feature model from an HMM already fitted on `column` (one value per sample
    /// pose; `None` or non-finite = missing): assigns every present value a state by `rule`,
    /// removes states that receive no sample, gives each missing sample the state of the
    /// nearest sample pose with a value, and builds the refining.
    ///
    /// `log_likelihood` is recorded as the fit's final log-likelihood; `requested_states` is the
    /// count asked of the fit (the HMM may have fewer states on degenerate data).
    pub fn from_hmm(
        name: &str,
        requested_states: usize,
        hmm: GaussianHmm,
        log_likelihood: f64,
        column: &[Option<f64>],
        sample_poses: &[[f64; 2]],
        rule: AssignmentRule,
    ) -> Result<Self, ModelError> {
        if column.len() != sample_poses.len() {
            return Err(ModelError::ColumnLength {
                feature: name.to_string(),
                expected: sample_poses.len(),
                got: column.len(),
            });
        }
        let (present, values) = present_values(column);
        if values.is_empty() {
            return Err(ModelError::NoValues {
                feature: name.to_string(),
            });
        }
        let assigned = hmm
            .assign(&values, rule)
            .map_err(|source| ModelError::Hmm {
                feature: name.to_string(),
                source,
            })?;
        let mut states = vec![usize::MAX; column.len()];
        for (&i, &s) in present.iter().zip(&assigned) {
            states[i] = s;
        }
        let mut imputed = Vec::new();
        for i in 0..column.len() {
            if states[i] == usize::MAX {
                let nearest = nearest_pose(sample_poses, &present, sample_poses[i]);
                states[i] = assigned[nearest];
                imputed.push(i);
            }
        }
        Self::from_parts(
            name.to_string(),
            requested_states,
            hmm,
            log_likelihood,
            values.len(),
            states,
            imputed,
        )
    }

    /// Assembles and checks a feature model from the HMM state of every sample.
    fn from_parts(
        name: String,
        requested_states: usize,
        hmm: GaussianHmm,
        log_likelihood: f64,
        n_observations: usize,
        states: Vec<usize>,
        imputed: Vec<usize>,
    ) -> Result<Self, ModelError> {
        let k = hmm.n_states();
        if let Some(&s) = states.iter().find(|&&s| s >= k) {
            return Err(ModelError::Corrupted(format!(
                "feature `{name}`: state {s} assigned to a sample, but the HMM has {k} states"
            )));
        }
        let mut used = vec![false; k];
        for &s in &states {
            used[s] = true;
        }
        let kept_states: Vec<usize> = (0..k).filter(|&s| used[s]).collect();
        let removed_states: Vec<usize> = (0..k).filter(|&s| !used[s]).collect();
        let mut frame_of = vec![usize::MAX; k];
        for (theta, &s) in kept_states.iter().enumerate() {
            frame_of[s] = theta;
        }
        let assignment: Vec<usize> = states.iter().map(|&s| frame_of[s]).collect();
        let refining =
            Refining::from_assignment(kept_states.len(), &assignment).map_err(|source| {
                ModelError::Refining {
                    feature: name.clone(),
                    source,
                }
            })?;
        Ok(Self {
            name,
            requested_states,
            hmm,
            log_likelihood,
            n_observations,
            states,
            kept_states,
            removed_states,
            imputed,
            refining,
        })
    }

    /// Feature name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// State count asked of the HMM fit.
    pub fn requested_states(&self) -> usize {
        self.requested_states
    }

    /// The feature's HMM (all its states, including removed ones).
    pub fn hmm(&self) -> &GaussianHmm {
        &self.hmm
    }

    /// Final log-likelihood of the HMM fit.
    pub fn log_likelihood(&self) -> f64 {
        self.log_likelihood
    }

    /// Number of values the HMM was fitted on (samples with a value).
    pub fn n_observations(&self) -> usize {
        self.n_observations
    }

    /// Bayesian information criterion of the HMM fit, −2 ln L + p ln N.
    pub fn bic(&self) -> f64 {
        self.hmm.bic(self.log_likelihood, self.n_observations)
    }

    /// Size of the frame Θᵢ (kept states).
    pub fn frame_size(&self) -> usize {
        self.kept_states.len()
    }

    /// HMM state index of each frame element θⱼ, ascending.
    pub fn kept_states(&self) -> &[usize] {
        &self.kept_states
    }

    /// HMM states removed because no sample was assigned to them.
    pub fn removed_states(&self) -> &[usize] {
        &self.removed_states
    }

    /// HMM state of every sample pose.
    pub fn hmm_states(&self) -> &[usize] {
        &self.states
    }

    /// Frame element θ of every sample pose (the refining as an assignment).
    pub fn assignment(&self) -> &[usize] {
        self.refining.assignment()
    }

    /// Sample poses whose value was missing, given the state of the nearest pose with a value.
    pub fn imputed(&self) -> &[usize] {
        &self.imputed
    }

    /// The refining ωᵢ from Θᵢ onto the sample poses.
    pub fn refining(&self) -> &Refining {
        &self.refining
    }

    /// Number of sample poses in each block ωᵢ({θⱼ}).
    pub fn block_sizes(&self) -> Vec<usize> {
        self.refining.blocks().iter().map(|b| b.count()).collect()
    }

    /// Likelihoods Γⱼ(y) of a value over the frame (kept states), scaled by a common factor so
    /// that the largest is 1: both measurement constructors (§3.6) are invariant to that factor,
    /// and the scaling keeps far outliers from underflowing to all zeros. `None` for a missing
    /// or non-finite value.
    pub fn likelihoods(&self, value: Option<f64>) -> Option<Vec<f64>> {
        let mut out = self.log_likelihoods(value)?;
        let max = out.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        for l in &mut out {
            *l = (*l - max).exp();
        }
        Some(out)
    }

    /// Log densities ln Γⱼ(y) of a value over the frame (kept states), unscaled. `None` for a
    /// missing or non-finite value.
    pub fn log_likelihoods(&self, value: Option<f64>) -> Option<Vec<f64>> {
        let y = value.filter(|y| y.is_finite())?;
        let mut all = vec![0.0; self.hmm.n_states()];
        // Cannot fail: y is finite and the buffer has the model's length.
        self.hmm.log_likelihoods(y, &mut all).ok()?;
        Some(self.kept_states.iter().map(|&s| all[s]).collect())
    }

    /// One-line summary for printing.
    pub fn summary(&self) -> FeatureSummary {
        FeatureSummary {
            name: self.name.clone(),
            requested_states: self.requested_states,
            states: self.frame_size(),
            removed_states: self.removed_states.clone(),
            log_likelihood: self.log_likelihood,
            bic: self.bic(),
            n_observations: self.n_observations,
            imputed: self.imputed.len(),
            block_sizes: self.block_sizes(),
        }
    }
}

/// Per-feature summary of a trained model, for printing.
#[derive(Debug, Clone, PartialEq)]
pub struct FeatureSummary {
    /// Feature name.
    pub name: String,
    /// State count asked of the HMM.
    pub requested_states: usize,
    /// Size of the frame (kept states).
    pub states: usize,
    /// HMM states removed for receiving no sample.
    pub removed_states: Vec<usize>,
    /// Final log-likelihood of the HMM fit.
    pub log_likelihood: f64,
    /// BIC of the HMM fit.
    pub bic: f64,
    /// Values the HMM was fitted on.
    pub n_observations: usize,
    /// Samples with a missing value (imputed by the nearest-pose rule).
    pub imputed: usize,
    /// Sample poses per frame element.
    pub block_sizes: Vec<usize>,
}

impl fmt::Display for FeatureSummary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{}: {} states (asked {}), log-likelihood {:.3}, BIC {:.3}, blocks {:?}",
            self.name,
            self.states,
            self.requested_states,
            self.log_likelihood,
            self.bic,
            self.block_sizes
        )?;
        if !self.removed_states.is_empty() {
            write!(f, ", removed states {:?}", self.removed_states)?;
        }
        if self.imputed > 0 {
            write!(f, ", {} missing values imputed", self.imputed)?;
        }
        Ok(())
    }
}

/// The evidential model: sample poses Q̃ and, per feature, its frame and refining onto Q̃.
#[derive(Debug, Clone, PartialEq)]
pub struct EvidentialModel {
    sample_poses: Vec<[f64; 2]>,
    features: Vec<FeatureModel>,
    conflict_threshold: Option<f64>,
    validation_errors: Option<Vec<f64>>,
    feature_config: Option<FeatureConfig>,
}

impl EvidentialModel {
    /// Trains the model from the sample poses and the feature matrix measured along the sample
    /// trajectory (`features[s][i]` = feature `i` at sample `s`, `None` when missing), with
    /// state counts given or tuned by BIC. [`Tuning::Validation`] needs
    /// [`EvidentialModel::train_with_tuner`].
    pub fn train(
        sample_poses: &[[f64; 2]],
        feature_names: &[String],
        features: &[Vec<Option<f64>>],
        settings: &ModelSettings,
    ) -> Result<Self, ModelError> {
        if matches!(settings.tuning, Tuning::Validation { .. }) {
            return Err(ModelError::TunerRequired);
        }
        Self::train_inner(sample_poses, feature_names, features, settings, None)
    }

    /// As [`EvidentialModel::train`], scoring candidate state counts with `tuner` when
    /// `settings.tuning` is [`Tuning::Validation`] (otherwise the tuner is not called).
    pub fn train_with_tuner(
        sample_poses: &[[f64; 2]],
        feature_names: &[String],
        features: &[Vec<Option<f64>>],
        settings: &ModelSettings,
        tuner: &mut dyn StateCountTuner,
    ) -> Result<Self, ModelError> {
        Self::train_inner(sample_poses, feature_names, features, settings, Some(tuner))
    }

    fn train_inner(
        sample_poses: &[[f64; 2]],
        feature_names: &[String],
        features: &[Vec<Option<f64>>],
        settings: &ModelSettings,
        mut tuner: Option<&mut dyn StateCountTuner>,
    ) -> Result<Self, ModelError> {
        settings.check()?;
        check_poses(sample_poses)?;
        check_names(feature_names)?;
        if features.len() != sample_poses.len() {
            return Err(ModelError::RowCount {
                rows: features.len(),
                poses: sample_poses.len(),
            });
        }
        if let Some((row, r)) = features
            .iter()
            .enumerate()
            .find(|(_, r)| r.len() != feature_names.len())
        {
            return Err(ModelError::RowLength {
                row,
                expected: feature_names.len(),
                got: r.len(),
            });
        }
        let ranges = settings.state_ranges(feature_names.len())?;
        let mut models = Vec::with_capacity(feature_names.len());
        for (f, (name, &(lo, hi))) in feature_names.iter().zip(&ranges).enumerate() {
            let column: Vec<Option<f64>> = features.iter().map(|row| row[f]).collect();
            let (_, values) = present_values(&column);
            if values.is_empty() {
                return Err(ModelError::NoValues {
                    feature: name.clone(),
                });
            }
            let mut best: Option<(f64, FeatureModel)> = None;
            for n in lo..=hi {
                let fit =
                    GaussianHmm::fit(&values, n, &settings.hmm, derive_seed(settings.seed, f, n))
                        .map_err(|source| ModelError::Hmm {
                        feature: name.clone(),
                        source,
                    })?;
                let candidate = FeatureModel::from_hmm(
                    name,
                    n,
                    fit.hmm,
                    fit.log_likelihood,
                    &column,
                    sample_poses,
                    settings.hmm.assignment,
                )?;
                let score = match (&settings.tuning, tuner.as_deref_mut()) {
                    (Tuning::Given, _) => 0.0,
                    (Tuning::Bic { .. }, _) => candidate.bic(),
                    (Tuning::Validation { .. }, Some(t)) => {
                        let s = t.score(f, &candidate, sample_poses).map_err(|source| {
                            ModelError::Tuner {
                                feature: name.clone(),
                                states: n,
                                source,
                            }
                        })?;
                        if !s.is_finite() {
                            return Err(ModelError::Tuner {
                                feature: name.clone(),
                                states: n,
                                source: format!("score {s} is not finite").into(),
                            });
                        }
                        s
                    }
                    (Tuning::Validation { .. }, None) => return Err(ModelError::TunerRequired),
                };
                if best.as_ref().is_none_or(|(b, _)| score < *b) {
                    best = Some((score, candidate));
                }
            }
            // `lo..=hi` is non-empty (checked), so a candidate exists.
            let (_, model) = best.ok_or(ModelError::Settings {
                field: "tuning",
                reason: "empty state-count range".into(),
            })?;
            models.push(model);
        }
        Ok(Self {
            sample_poses: sample_poses.to_vec(),
            features: models,
            conflict_threshold: None,
            validation_errors: None,
            feature_config: None,
        })
    }

    /// Assembles a model from feature models built on `sample_poses` (e.g. with
    /// [`FeatureModel::from_hmm`]). Errors on no poses or features, a non-finite pose, duplicate
    /// names, or a feature whose refining is not onto these poses.
    pub fn from_features(
        sample_poses: Vec<[f64; 2]>,
        features: Vec<FeatureModel>,
    ) -> Result<Self, ModelError> {
        check_poses(&sample_poses)?;
        let names: Vec<String> = features.iter().map(|f| f.name.clone()).collect();
        check_names(&names)?;
        if let Some(f) = features
            .iter()
            .find(|f| f.states.len() != sample_poses.len())
        {
            return Err(ModelError::ColumnLength {
                feature: f.name.clone(),
                expected: sample_poses.len(),
                got: f.states.len(),
            });
        }
        Ok(Self {
            sample_poses,
            features,
            conflict_threshold: None,
            validation_errors: None,
            feature_config: None,
        })
    }

    /// The sample poses Q̃, in trajectory order.
    pub fn sample_poses(&self) -> &[[f64; 2]] {
        &self.sample_poses
    }

    /// Number of features.
    pub fn n_features(&self) -> usize {
        self.features.len()
    }

    /// All feature models, in feature order.
    pub fn features(&self) -> &[FeatureModel] {
        &self.features
    }

    /// Feature names, in feature order.
    pub fn feature_names(&self) -> Vec<&str> {
        self.features.iter().map(|f| f.name()).collect()
    }

    /// Per-frame use by the tracker: for each feature, the likelihoods Γ over its frame (scaled
    /// so the largest is 1, see [`FeatureModel::likelihoods`]), or `None` when the value is
    /// missing or non-finite. Errors when `features` does not have one value per feature.
    pub fn likelihoods(
        &self,
        features: &[Option<f64>],
    ) -> Result<Vec<Option<Vec<f64>>>, ModelError> {
        if features.len() != self.features.len() {
            return Err(ModelError::InvalidInput {
                what: "feature vector",
                reason: format!(
                    "{} values for a model of {} features",
                    features.len(),
                    self.features.len()
                ),
            });
        }
        Ok(self
            .features
            .iter()
            .zip(features)
            .map(|(m, &y)| m.likelihoods(y))
            .collect())
    }

    /// Per-feature summaries, for printing.
    pub fn summary(&self) -> Vec<FeatureSummary> {
        self.features.iter().map(FeatureModel::summary).collect()
    }

    /// The learned conflict threshold, if any.
    pub fn conflict_threshold(&self) -> Option<f64> {
        self.conflict_threshold
    }

    /// Records a learned conflict threshold (finite and ≥ 0), or clears it.
    pub fn set_conflict_threshold(&mut self, threshold: Option<f64>) -> Result<(), ModelError> {
        if let Some(t) = threshold {
            if !(t.is_finite() && t >= 0.0) {
                return Err(ModelError::InvalidInput {
                    what: "conflict threshold",
                    reason: format!("{t} must be finite and >= 0"),
                });
            }
        }
        self.conflict_threshold = threshold;
        Ok(())
    }

    /// Per-feature validation errors, if recorded.
    pub fn validation_errors(&self) -> Option<&[f64]> {
        self.validation_errors.as_deref()
    }

    /// Records per-feature validation errors (one per feature, finite and ≥ 0), or clears them.
    pub fn set_validation_errors(&mut self, errors: Option<Vec<f64>>) -> Result<(), ModelError> {
        if let Some(e) = &errors {
            check_validation_errors(e, self.features.len())?;
        }
        self.validation_errors = errors;
        Ok(())
    }

    /// The feature configuration the model was trained with, when recorded: `track` extracts
    /// the same features with it.
    pub fn feature_config(&self) -> Option<&FeatureConfig> {
        self.feature_config.as_ref()
    }

    /// Records the feature configuration the model was trained with.
    pub fn set_feature_config(&mut self, config: Option<FeatureConfig>) {
        self.feature_config = config;
    }
}

fn check_validation_errors(e: &[f64], n_features: usize) -> Result<(), ModelError> {
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

fn check_poses(poses: &[[f64; 2]]) -> Result<(), ModelError> {
    if poses.is_empty() {
        return Err(ModelError::NoSamples);
    }
    if let Some(index) = poses
        .iter()
        .position(|p| !(p[0].is_finite() && p[1].is_finite()))
    {
        return Err(ModelError::NonFinitePose {
            index,
            pose: poses[index],
        });
    }
    Ok(())
}

fn check_names(names: &[String]) -> Result<(), ModelError> {
    if names.is_empty() {
        return Err(ModelError::NoFeatures);
    }
    let mut sorted: Vec<&String> = names.iter().collect();
    sorted.sort();
    if let Some(w) = sorted.windows(2).find(|w| w[0] == w[1]) {
        return Err(ModelError::DuplicateFeature(w[0].clone()));
    }
    Ok(())
}

/// Indices and values of the present (finite) entries of a column.
fn present_values(column: &[Option<f64>]) -> (Vec<usize>, Vec<f64>) {
    column
        .iter()
        .enumerate()
        .filter_map(|(i, v)| v.filter(|y| y.is_finite()).map(|y| (i, y)))
        .unzip()
}

/// Position in `present` of the sample pose nearest to `q` (ties to the lower index).
fn nearest_pose(poses: &[[f64; 2]], present: &[usize], q: [f64; 2]) -> usize {
    let mut best = 0;
    let mut best_d = f64::INFINITY;
    for (k, &i) in present.iter().enumerate() {
        let p = poses[i];
        let d = (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2);
        if d < best_d {
            best = k;
            best_d = d;
        }
    }
    best
}

/// A seed per (feature, state count), so that tuning and the given-count path draw the same
/// initialisations for the same count.
fn derive_seed(seed: u64, feature: usize, n_states: usize) -> u64 {
    // splitmix64 finaliser over the combined inputs.
    let mut z = seed
        ^ (feature as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (n_states as u64).wrapping_mul(0xD1B5_4A32_D192_ED03);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nearest_pose_prefers_lower_index_on_ties() {
        let poses = [[0.0, 0.0], [1.0, 0.0], [-1.0, 0.0], [5.0, 5.0]];
        assert_eq!(nearest_pose(&poses, &[1, 2, 3], [0.0, 0.0]), 0);
        assert_eq!(nearest_pose(&poses, &[1, 2, 3], [4.0, 4.0]), 2);
    }

    #[test]
    fn derived_seeds_differ_by_feature_and_count() {
        let a = derive_seed(1, 0, 3);
        assert_ne!(a, derive_seed(1, 1, 3));
        assert_ne!(a, derive_seed(1, 0, 4));
        assert_ne!(a, derive_seed(2, 0, 3));
        assert_eq!(a, derive_seed(1, 0, 3));
    }

    #[test]
    fn settings_check_and_ranges() {
        let mut s = ModelSettings::default();
        assert!(s.check().is_ok());
        s.states = StateCounts::All(0);
        assert!(matches!(s.check(), Err(ModelError::Settings { .. })));
        s.states = StateCounts::PerFeature(vec![2, 3]);
        assert!(s.check().is_ok());
        assert!(matches!(
            s.state_ranges(3),
            Err(ModelError::Settings { .. })
        ));
        assert_eq!(s.state_ranges(2).unwrap(), vec![(2, 2), (3, 3)]);
        s.tuning = Tuning::Bic {
            min_states: StateCounts::All(4),
            max_states: StateCounts::All(2),
        };
        assert!(matches!(s.check(), Err(ModelError::Settings { .. })));
        s.tuning = Tuning::Bic {
            min_states: StateCounts::All(1),
            max_states: StateCounts::PerFeature(vec![3, 0]),
        };
        assert!(s.check().is_err());
        s.tuning = Tuning::Bic {
            min_states: StateCounts::PerFeature(vec![1, 5]),
            max_states: StateCounts::All(4),
        };
        assert!(s.check().is_ok());
        assert!(matches!(
            s.state_ranges(2),
            Err(ModelError::Settings { .. })
        ));
    }
}
