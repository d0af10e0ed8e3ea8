//! Training: one Gaussian HMM per feature on the sample trajectory, state counts given or tuned
//! (§5.2), giving each feature its frame of discernment and its refining onto the sample poses.

use super::feature::{present_values, FeatureSummary};
use super::{FeatureModel, ModelError, ModelSettings, Tuning};
use crate::hmm::GaussianHmm;

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

/// The features' frames of discernment and their refinings onto the sample poses Q̃: what
/// training learns from the sample trajectory.
#[derive(Debug, Clone, PartialEq)]
pub struct FeatureFrames {
    pub(super) sample_poses: Vec<[f64; 2]>,
    pub(super) features: Vec<FeatureModel>,
}

impl FeatureFrames {
    /// Trains the model from the sample poses and the feature matrix measured along the sample
    /// trajectory (`features[s][i]` = feature `i` at sample `s`, `None` when missing), with
    /// state counts given or tuned by BIC. [`Tuning::Validation`] needs
    /// [`FeatureFrames::train_with_tuner`].
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

    /// As [`FeatureFrames::train`], scoring candidate state counts with `tuner` when
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
                // Kept in the process: evidential and evidential_temporal train these same fits.
                let fit = GaussianHmm::fit_shared(
                    &values,
                    n,
                    &settings.hmm,
                    crate::seed::for_fit(settings.seed, f, n),
                )
                .map_err(|source| ModelError::Hmm {
                    feature: name.clone(),
                    source,
                })?;
                let mut candidate = FeatureModel::from_hmm(
                    name,
                    n,
                    fit.hmm,
                    fit.log_likelihood,
                    &column,
                    sample_poses,
                    settings.hmm.assignment,
                )?;
                candidate.em_converged = Some(fit.converged);
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
        let names: Vec<String> = features.iter().map(|f| f.name().to_string()).collect();
        check_names(&names)?;
        if let Some(f) = features
            .iter()
            .find(|f| f.hmm_states().len() != sample_poses.len())
        {
            return Err(ModelError::ColumnLength {
                feature: f.name().to_string(),
                expected: sample_poses.len(),
                got: f.hmm_states().len(),
            });
        }
        Ok(Self {
            sample_poses,
            features,
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
}

pub(super) fn check_poses(poses: &[[f64; 2]]) -> Result<(), ModelError> {
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

pub(super) fn check_names(names: &[String]) -> Result<(), ModelError> {
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
