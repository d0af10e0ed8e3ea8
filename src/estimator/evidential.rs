//! The paper's evidential tracker behind the seam: fitting trains one HMM per feature (state
//! counts given or tuned), measures each feature's own error on the validation motion (the
//! fallback's ranking) and learns the conflict threshold there (§4.3), and returns a complete
//! [`EvidentialModel`] with its [`Tracker`].

use std::path::Path;

use super::{EstimateFlags, EstimatorError, PoseEstimate, PoseEstimator, TrainingSet};
use crate::features::FeatureConfig;
use crate::model::{
    EvidentialModel, FeatureFrames, FeatureModel, ModelParts, ModelSettings, StateCountTuner,
    TunerError, Tuning,
};
use crate::model_file::Provenance;
use crate::planar::distance;
use crate::track::{
    FrameEstimate, GroupError, SelectionPolicy, ThresholdRule, TrackError, TrackSettings,
    TrackedFeature, Tracker, TrackerModel,
};

/// The splitting policy measures every group's validation error (2ⁿ groups): features at most.
pub const MAX_FEATURES_GROUP_ERRORS: usize = 10;

/// How the evidential tracker is trained and run.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct EvidentialSettings {
    /// HMM state counts and EM (its `seed` is the training seed, used as is).
    pub model: ModelSettings,
    /// Constructor, selection, estimator and the conflict threshold (unless learned).
    pub track: TrackSettings,
    /// Learn the conflict threshold on the validation motion (§4.3).
    pub learn_threshold: bool,
    /// How it is learned.
    pub threshold_rule: ThresholdRule,
}

/// The evidential tracker of the paper, fitted: its complete model and the tracker built on it.
#[derive(Debug, Clone)]
pub struct Evidential {
    model: EvidentialModel,
    tracker: Tracker,
    names: Vec<String>,
    /// The variance per axis of the poses a sample pose stands for (mm²), added to the
    /// covariance it states ([`super::motion::cell_variance`]).
    cell_variance: f64,
}

impl Evidential {
    /// Trains on `data`: HMMs and refinings on the sample trajectory, then, when `data` has a
    /// validation motion, each feature's validation error and (if asked) the conflict threshold.
    ///
    /// # Errors
    /// [`EstimatorError::Training`] for a validation-only setting without a validation motion;
    /// model and tracker errors otherwise.
    pub fn fit(settings: &EvidentialSettings, data: &TrainingSet) -> Result<Self, EstimatorError> {
        let sample = data.sample;
        let frames = match (&settings.model.tuning, &data.validation) {
            (Tuning::Validation { .. }, Some(validation)) => {
                let mut tuner = ValidationTuner {
                    rows: validation.rows,
                    truth: validation.poses,
                    settings: &settings.track,
                    penalty: data.missing_penalty,
                };
                FeatureFrames::train_with_tuner(
                    sample.poses,
                    data.feature_names,
                    sample.rows,
                    &settings.model,
                    &mut tuner,
                )?
            }
            (Tuning::Validation { .. }, None) => {
                return Err(EstimatorError::Training(
                    "tuning state counts by validation error needs a validation motion".into(),
                ))
            }
            _ => FeatureFrames::train(
                sample.poses,
                data.feature_names,
                sample.rows,
                &settings.model,
            )?,
        };
        if settings.learn_threshold && data.validation.is_none() {
            return Err(EstimatorError::Training(
                "learning the conflict threshold needs a validation motion".into(),
            ));
        }

        let mut track = settings.track.clone();
        let mut validation_errors = None;
        let mut group_errors = Vec::new();
        let mut threshold_learned = false;
        if let Some(validation) = &data.validation {
            // One tracker combining every compatible feature, with no fallback ranking yet.
            let open = TrackSettings {
                conflict_threshold: crate::evidence::ConflictLevel::Infinite,
                selection: SelectionPolicy::LargestSubset,
                // Each feature alone, as measured: the errors the learned reliabilities read.
                combine: crate::track::Combine::Selected,
                rule: crate::evidence::Rule::Dempster,
                discount: crate::track::Discount::None,
                ..settings.track.clone()
            };
            let tracker = build_tracker(&frames, None, &[], &open)?;
            let group_error = |mask: crate::track::GroupMask| -> Result<f64, EstimatorError> {
                let rows: Vec<Vec<Option<f64>>> = (validation.rows.iter())
                    .map(|row| {
                        (0..row.len())
                            .map(|j| row[j].filter(|_| mask >> j & 1 == 1))
                            .collect()
                    })
                    .collect();
                let estimates = track_rows(&frames, &tracker, &rows)?;
                Ok(validation_error(
                    &estimates,
                    validation.poses,
                    data.missing_penalty,
                ))
            };
            let n = frames.n_features();
            validation_errors = Some(
                (0..n)
                    .map(|i| group_error(1 << i))
                    .collect::<Result<_, _>>()?,
            );
            if let SelectionPolicy::Splitting { min_size } = settings.track.selection {
                if n > MAX_FEATURES_GROUP_ERRORS {
                    return Err(EstimatorError::Training(format!(
                        "the splitting policy learns a reliability for every group of features, \
                         which takes at most {MAX_FEATURES_GROUP_ERRORS} features (this model has {n}): \
                         use fewer features or another selection policy"
                    )));
                }
                for mask in 1..1u64 << n {
                    if mask.count_ones() as usize >= min_size {
                        group_errors.push(GroupError {
                            features: (0..n).filter(|j| mask >> j & 1 == 1).collect(),
                            error: group_error(mask)?,
                        });
                    }
                }
            }
            if settings.learn_threshold {
                // The level of the group combined with no threshold, and its error.
                let estimates = track_rows(&frames, &tracker, validation.rows)?;
                let (levels, errors): (Vec<f64>, Vec<f64>) = estimates
                    .iter()
                    .zip(validation.poses)
                    .filter_map(|(e, t)| Some((e.conflict_level?, distance(e.estimate?, *t))))
                    .unzip();
                track.conflict_threshold =
                    settings.threshold_rule.check()?.learn(&levels, &errors)?;
                threshold_learned = true;
            }
        }
        let model = EvidentialModel::new(ModelParts {
            frames,
            feature_config: data.feature_config.cloned(),
            track,
            threshold_learned,
            validation_errors,
            group_errors,
            provenance: data.provenance.clone(),
        })?;
        Self::from_model(model)
    }

    /// The same fitted tracker recording `provenance` (its fit does not depend on it).
    pub(crate) fn reprovenanced(&self, provenance: &Provenance) -> Self {
        let mut copy = self.clone();
        copy.model = self.model.with_provenance(provenance.clone());
        copy
    }

    /// The estimator of a complete model (builds its tracker).
    ///
    /// # Errors
    /// Tracker errors (e.g. more features than the tracker accepts).
    pub fn from_model(model: EvidentialModel) -> Result<Self, EstimatorError> {
        let tracker = build_tracker(
            model.frames(),
            model.validation_errors(),
            model.group_errors(),
            model.track_settings(),
        )?;
        let names = model
            .feature_names()
            .iter()
            .map(|n| n.to_string())
            .collect();
        let cell_variance = super::motion::cell_variance(tracker.model().poses());
        Ok(Self {
            model,
            tracker,
            names,
            cell_variance,
        })
    }

    /// Reads a model file (see [`EvidentialModel::load`]).
    ///
    /// # Errors
    /// As [`EvidentialModel::load`] and [`Evidential::from_model`].
    pub fn load(path: &Path) -> Result<Self, EstimatorError> {
        Self::from_model(EvidentialModel::load(path)?)
    }

    /// The complete model.
    pub fn model(&self) -> &EvidentialModel {
        &self.model
    }

    /// The tracker built on it.
    pub fn tracker(&self) -> &Tracker {
        &self.tracker
    }

    /// The same model run with other tracker settings.
    ///
    /// # Errors
    /// Invalid settings.
    pub fn with_track_settings(&self, track: TrackSettings) -> Result<Self, EstimatorError> {
        Self::from_model(self.model.with_track_settings(track)?)
    }

    /// The tracker's full output for one frame of feature values: the estimate plus the relative
    /// plausibility of every sample pose and the splitting policy's alternatives.
    ///
    /// # Errors
    /// [`EstimatorError::FeatureCount`] when `features` does not have one value per feature.
    pub fn track(&self, features: &[Option<f64>]) -> Result<FrameEstimate, EstimatorError> {
        if features.len() != self.names.len() {
            return Err(EstimatorError::FeatureCount {
                expected: self.names.len(),
                found: features.len(),
            });
        }
        Ok(self
            .tracker
            .track(&self.model.frames().likelihoods(features)?)?)
    }
}

impl PoseEstimator for Evidential {
    fn method(&self) -> &'static str {
        crate::model::METHOD
    }

    fn feature_names(&self) -> &[String] {
        &self.names
    }

    fn feature_config(&self) -> Option<&FeatureConfig> {
        self.model.feature_config()
    }

    fn estimate(&self, features: &[Option<f64>]) -> Result<PoseEstimate, EstimatorError> {
        Ok(self.pose_estimate(self.track(features)?))
    }

    fn to_json(&self) -> Result<String, EstimatorError> {
        Ok(self.model.to_json()?)
    }

    fn with_provenance(&self, provenance: &Provenance) -> Option<Box<dyn PoseEstimator>> {
        Some(Box::new(self.reprovenanced(provenance)))
    }
}

impl Evidential {
    /// The seam's view of one frame of the tracker. Its covariance is the weights' spread over
    /// the sample poses plus the variance of the poses each one stands for (Sheppard's
    /// correction for grouping): a belief on one sample pose still leaves its whole cell, which
    /// the spread alone, zero there, would not say.
    pub(super) fn pose_estimate(&self, frame: FrameEstimate) -> PoseEstimate {
        let mut estimate = pose_estimate(frame);
        if let Some(c) = &mut estimate.covariance {
            c[0][0] += self.cell_variance;
            c[1][1] += self.cell_variance;
        }
        estimate
    }
}

/// The seam's view of one frame of the tracker, its covariance the weights' spread alone.
fn pose_estimate(frame: FrameEstimate) -> PoseEstimate {
    let capped = frame.flags.alternatives_capped;
    PoseEstimate {
        pose: frame.estimate,
        uncertainty_radius: frame.uncertainty.map(|u| u.radius),
        group: Some(frame.group),
        conflict_level: frame.conflict_level,
        detection_score: frame.full_conflict_level,
        region: None,
        covariance: frame.uncertainty.map(|u| u.covariance),
        flags: EstimateFlags {
            missing: frame.flags.missing().collect(),
            excluded: frame.flags.excluded,
            fallback: frame.flags.fallback,
            combination_failed: frame.flags.combination_failed,
            alternatives_capped: capped.then_some(frame.alternatives_found),
            ..EstimateFlags::default()
        },
    }
}

/// The tracker's view of trained frames, with these settings, fallback ranking and group
/// reliabilities.
fn build_tracker(
    frames: &FeatureFrames,
    validation_errors: Option<&[f64]>,
    group_errors: &[GroupError],
    settings: &TrackSettings,
) -> Result<Tracker, EstimatorError> {
    let features = frames
        .features()
        .iter()
        .enumerate()
        .map(|(i, f)| TrackedFeature {
            refining: f.refining().clone(),
            validation_error: validation_errors.map(|v| v[i]),
        })
        .collect();
    let min_size = settings.selection.min_size();
    if min_size > frames.n_features() {
        return Err(TrackError::InvalidSetting {
            field: "selection.min_size",
            reason: format!(
                "{min_size} is more than the model's {} features: no group could ever be chosen",
                frames.n_features()
            ),
        }
        .into());
    }
    let model = TrackerModel::new(frames.sample_poses().to_vec(), features)?
        .with_group_errors(group_errors)?;
    Ok(Tracker::new(model, settings.clone().check()?)?)
}

/// Tracks feature rows; returns the per-frame estimates.
fn track_rows(
    frames: &FeatureFrames,
    tracker: &Tracker,
    rows: &[Vec<Option<f64>>],
) -> Result<Vec<FrameEstimate>, EstimatorError> {
    rows.iter()
        .map(|row| Ok(tracker.track(&frames.likelihoods(row)?)?))
        .collect()
}

/// Mean distance of the estimates to the truth, a frame without an estimate counting as
/// `penalty` (the workspace diagonal), so a feature that rarely gives an estimate ranks low and
/// the score stays finite.
fn validation_error(estimates: &[FrameEstimate], truth: &[[f64; 2]], penalty: f64) -> f64 {
    let total: f64 = estimates
        .iter()
        .zip(truth)
        .map(|(e, t)| e.estimate.map_or(penalty, |p| distance(p, *t)))
        .sum();
    total / truth.len().max(1) as f64
}

/// Scores candidate state counts by the tracking error of the candidate feature alone on the
/// validation motion (§5.2, "learned from the measured estimation error as nᵢ increases").
struct ValidationTuner<'a> {
    rows: &'a [Vec<Option<f64>>],
    truth: &'a [[f64; 2]],
    settings: &'a TrackSettings,
    penalty: f64,
}

impl StateCountTuner for ValidationTuner<'_> {
    fn score(
        &mut self,
        feature: usize,
        candidate: &FeatureModel,
        sample_poses: &[[f64; 2]],
    ) -> Result<f64, TunerError> {
        let tracker_model = TrackerModel::new(
            sample_poses.to_vec(),
            vec![TrackedFeature {
                refining: candidate.refining().clone(),
                validation_error: None,
            }],
        )?;
        let tracker = Tracker::new(tracker_model, self.settings.clone().check()?)?;
        let estimates = self
            .rows
            .iter()
            .map(|row| tracker.track(&[candidate.likelihoods(row[feature])]))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(validation_error(&estimates, self.truth, self.penalty))
    }
}

/// The scenario checks of the evidential tracker: what only it limits (its groups are bit masks,
/// its state counts are listed per feature, splitting learns a reliability per group).
pub(crate) fn check_settings(
    settings: &super::EstimatorSettings,
    context: &super::SettingsContext,
) -> Result<(), String> {
    check_discrete_frames(settings, context)?;
    let n = context.feature_names.len();
    if let crate::track::SelectionPolicy::Splitting { .. } = settings.evidential.track.selection {
        if context.has_validation && n > MAX_FEATURES_GROUP_ERRORS {
            return Err(format!(
                "[track]: the splitting policy learns a reliability for every group of \
                 features, which takes at most {MAX_FEATURES_GROUP_ERRORS} features (there are {n}): \
                 use fewer features or another selection policy"
            ));
        }
    }
    Ok(())
}

/// What every tracker on the HMM frames needs: at most [`crate::track::MAX_FEATURES`] features,
/// groups no larger than the features, a state count for every feature.
pub(crate) fn check_discrete_frames(
    settings: &super::EstimatorSettings,
    context: &super::SettingsContext,
) -> Result<(), String> {
    let names = &context.feature_names;
    let max = crate::track::MAX_FEATURES;
    if names.len() > max {
        return Err(format!(
            "[features]: {} features, but the tracker takes at most {max}: use fewer \
             size-function lines or drop the barycentre",
            names.len()
        ));
    }
    let min_size = settings.evidential.track.selection.min_size();
    if min_size > names.len() {
        return Err(format!(
            "[track]: selection `min_size = {min_size}` is more than the {} features: no group \
             could ever be chosen",
            names.len()
        ));
    }
    let ranges = settings
        .evidential
        .model
        .state_ranges(names.len())
        .map_err(|e| format!("[model]: {e} (the features are {})", names.join(", ")))?;
    check_rule_cost(&settings.evidential.track, &ranges)
}

/// Dubois and Prade's rule and PCR6 enumerate every tuple of focal sets: refused before a run
/// when the largest state counts could give more than [`crate::track::MAX_RULE_TUPLES`].
fn check_rule_cost(track: &TrackSettings, ranges: &[(usize, usize)]) -> Result<(), String> {
    use crate::evidence::Rule;
    if !matches!(track.rule, Rule::DuboisPrade | Rule::Pcr6) {
        return Ok(());
    }
    let max = crate::track::MAX_RULE_TUPLES;
    let fits = ranges.iter().try_fold(1u64, |t, &(_, hi)| {
        t.checked_mul(hi as u64 + 1).filter(|&t| t <= max)
    });
    match fits {
        Some(_) => Ok(()),
        None => Err(format!(
            "[track]: the evidential trackers (`evidential`, `evidential_temporal`) cannot take \
             rule `{}` here: it enumerates every tuple of focal sets, and {} features with these \
             state counts give more than {max} a frame; use fewer states or another rule",
            track.rule.name(),
            ranges.len()
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::track::FrameFlags;

    fn frame(estimate: Option<[f64; 2]>) -> FrameEstimate {
        FrameEstimate {
            estimate,
            group: vec![0],
            conflict_level: Some(0.0),
            full_conflict_level: Some(0.0),
            uncertainty: None,
            plausibility: Vec::new(),
            alternatives: Vec::new(),
            alternatives_found: 0,
            flags: FrameFlags::default(),
        }
    }

    #[test]
    fn a_capped_frame_says_how_many_alternatives_it_found() {
        let mut capped = frame(Some([0.0, 41.0]));
        capped.alternatives_found = 1648;
        let words = |f: FrameEstimate| pose_estimate(f).flag_words(&[]);
        assert_eq!(words(capped.clone()), "");
        capped.flags.alternatives_capped = true;
        assert_eq!(words(capped), "alternatives_capped:1648");
    }

    #[test]
    fn a_belief_on_sample_poses_states_their_cells_variance_too() {
        use rand::SeedableRng;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(4);
        // The 1 mm mesh: each sample pose stands for a 1 mm square, variance 1/12 mm² per axis.
        let samples = crate::estimator::test_maps::MeshSamples::new(20, 4, 0.01, &mut rng);
        let mut settings = EvidentialSettings::default();
        settings.model.states = crate::model::StateCounts::All(12);
        let fitted = Evidential::fit(&settings, &samples.training()).unwrap();
        for row in samples.rows.iter().step_by(37) {
            let frame = fitted.track(row).unwrap();
            let spread = frame.uncertainty.unwrap().covariance;
            let stated = fitted.estimate(row).unwrap().covariance.unwrap();
            for axis in 0..2 {
                let added = stated[axis][axis] - spread[axis][axis];
                assert!((added - 1.0 / 12.0).abs() < 1e-12, "{added}");
            }
            assert_eq!(stated[0][1], spread[0][1]);
        }
    }

    #[test]
    fn frames_without_estimate_count_as_the_penalty() {
        let truth = [[0.0, 40.0], [1.0, 40.0], [2.0, 40.0]];
        let estimates = [
            frame(Some([0.0, 41.0])),
            frame(None),
            frame(Some([2.0, 43.0])),
        ];
        // (1 + 10 + 3) / 3: the missing frame weighs as much as the penalty, not nothing.
        let score = validation_error(&estimates, &truth, 10.0);
        assert!((score - 14.0 / 3.0).abs() < 1e-12);
        let none = [frame(None), frame(None)];
        assert_eq!(validation_error(&none, &truth[..2], 10.0), 10.0);
    }
}
