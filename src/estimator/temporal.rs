//! The temporal evidential tracker (issue 17): the paper's tracker, with the belief of the last
//! frame carried to the next by a motion model and taking part in its conflict graph.
//!
//! - The motion model: a pose moves by v·Δt, v the velocity of the line through the last
//!   estimates ([`VelocityLine`]), then reaches every pose within `max_speed` × Δt in a frame
//!   interval Δt (the frames' own timestamps). The carried belief is consonant; moving it maps
//!   each focal set onto the poses it can reach, so its contour becomes the dilation
//!   π′(p) = max {π(q) : |q + v·Δt − p| ≤ max_speed·Δt}.
//! - Discounting by the reliability α (fixed, or learned on the validation motion): the carried
//!   contour is c = 1 − α + α·π′, so the past can never be in total conflict with a frame.
//! - The frame's features and the carried belief form one conflict graph
//!   ([`crate::track::Tracker::track_with_past`]), the past counting as `past_weight` features
//!   in the largest-subset choice: a frame that contradicts the past shows as conflict, and
//!   when the past is left out (`past_rejected`) it is dropped, not followed.
//! - What is carried on is the contour of the chosen combination (the consonant function with
//!   that contour), scaled to maximum 1.
//! - A frame without a usable feature gets the prediction: the estimate of π′ alone
//!   (`predicted`), and π′ is carried on, so the reach keeps growing until a frame is usable.
//!   A frame whose features are all outweighed by the past is flagged `predicted` too.
//! - Between the sample poses: on a frame the past joins (and on a prediction), the weights over
//!   the sample poses are combined with the line's predicted pose on the refined poses
//!   ([`Refinement`], spread `velocity_spread`, by default half the spacing widened to the RMS of
//!   the line's last misses), so the estimate can fall between samples. The uncertainty radius
//!   stays that of the sample weights.
//! - What is learned on the validation motion: α, and whether the line helps at all
//!   (`learn_velocity`; on coarse frames constant position wins).

use std::path::Path;
use std::sync::OnceLock;

use serde::{Deserialize, Serialize};

use super::motion::{
    learned_motion, motion_error, IncoherentFrames, PoseBuckets, Refinement, TemporalSettings,
    VelocityLine, DEFAULT_RELIABILITY,
};
use super::{
    EstimatorError, Evidential, EvidentialSettings, MotionTracker, PoseEstimate, PoseEstimator,
    TrainingSet,
};
use crate::features::FeatureConfig;
use crate::model::EvidentialModel;
use crate::model_file::{self, corrupted, Stamp};
use crate::planar::distance;
use crate::range::within;
use crate::track::{PoseRule, SelectionPolicy};

/// Most features the temporal evidential tracker takes: the carried belief is one more bit of
/// its group masks.
pub const MAX_TEMPORAL_FEATURES: usize = crate::track::MAX_FEATURES - 1;

/// Why `features` features are too many for the carried belief, if they are.
fn too_many_features(features: usize) -> Option<String> {
    (features > MAX_TEMPORAL_FEATURES).then(|| {
        format!(
            "{features} features, but the temporal evidential tracker takes at most \
             {MAX_TEMPORAL_FEATURES} (the carried belief is one more): use fewer features"
        )
    })
}

/// The temporal evidential tracker, fitted: the paper's tracker and the carried belief's
/// settings.
#[derive(Debug, Clone)]
pub struct TemporalEvidential {
    inner: Evidential,
    file: TemporalFile,
    /// The sample poses refined for the velocity prediction (`None` without two distinct
    /// poses: the estimates stay on the samples' weights), built on the first frame that needs
    /// it: it was half of loading a model file, and per-frame estimates never need it.
    refinement: OnceLock<Option<Refinement>>,
    /// The sample poses in buckets, for the dilation.
    buckets: PoseBuckets,
}

/// The model file: the settings, the reliability and velocity line used and the paper
/// tracker's own model file.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct TemporalFile {
    #[serde(flatten)]
    stamp: Stamp,
    settings: TemporalSettings,
    reliability: f64,
    reliability_learned: bool,
    /// The estimates the velocity line goes through (`settings.velocity_frames`, or 0 when
    /// the validation motion showed constant position lower).
    velocity_frames: usize,
    /// The RMS error (mm) of the paper's tracker alone on the validation motion (0 without
    /// one): the part of the line's misses that is the frames' own error, not the line's.
    frame_error: f64,
    /// The evidential model file's text.
    evidential_model: String,
}

impl TemporalEvidential {
    /// Version of the model file format this build writes and reads. 4: the evidential
    /// model's version 3 (its covariance adds the sample poses' cells).
    pub const FORMAT_VERSION: u32 = 4;
    /// The `method` of its model files.
    pub const METHOD: &'static str = "evidential_temporal";

    /// Fits the paper's tracker on `data`, then learns on the validation motion α (when it is
    /// not given) and whether the velocity line helps (`learn_velocity`).
    ///
    /// # Errors
    /// Invalid settings (the splitting policy is refused); the evidential tracker's errors.
    pub fn fit(
        evidential: &EvidentialSettings,
        settings: &TemporalSettings,
        data: &TrainingSet,
    ) -> Result<Self, EstimatorError> {
        settings.check()?;
        if let SelectionPolicy::Splitting { .. } = evidential.track.selection {
            return Err(EstimatorError::Training(
                "the temporal evidential tracker takes `track.selection` largest_subset or \
                 lowest_conflict, not splitting (its alternatives are not weighed against the past)"
                    .into(),
            ));
        }
        if let Some(why) = too_many_features(data.feature_names.len()) {
            return Err(EstimatorError::Training(why));
        }
        let inner = Evidential::fit(evidential, data)?;
        let alpha = settings.reliability.unwrap_or(DEFAULT_RELIABILITY);
        let mut fitted = Self::new(inner, settings.clone(), alpha)?;
        if let Some(v) = &data.validation {
            let mut total = 0.0;
            for (row, truth) in v.rows.iter().zip(v.poses) {
                let pose = fitted.inner.estimate(row)?.pose;
                total += pose
                    .map_or(data.missing_penalty, |p| distance(p, *truth))
                    .powi(2);
            }
            fitted.file.frame_error = (total / v.rows.len().max(1) as f64).sqrt();
        }
        let learned = learned_motion(settings, data, |alpha, frames| {
            fitted.file.reliability = alpha;
            fitted.file.velocity_frames = frames;
            motion_error(&fitted, data)
        })?;
        fitted.file.reliability = alpha;
        fitted.file.velocity_frames = settings.velocity_frames;
        if let Some(choice) = learned {
            fitted.file.reliability = choice.reliability;
            fitted.file.reliability_learned = settings.reliability.is_none();
            fitted.file.velocity_frames = choice.velocity_frames;
        }
        Ok(fitted)
    }

    fn new(
        inner: Evidential,
        settings: TemporalSettings,
        reliability: f64,
    ) -> Result<Self, EstimatorError> {
        let file = TemporalFile {
            stamp: Stamp::new(Self::METHOD, Self::FORMAT_VERSION),
            velocity_frames: settings.velocity_frames,
            frame_error: 0.0,
            settings,
            reliability,
            reliability_learned: false,
            evidential_model: inner.to_json()?,
        };
        Ok(Self::assemble(inner, file))
    }

    fn assemble(inner: Evidential, file: TemporalFile) -> Self {
        let buckets = PoseBuckets::new(inner.tracker().model().poses());
        Self {
            inner,
            file,
            refinement: OnceLock::new(),
            buckets,
        }
    }

    /// The refined sample poses, built on first use.
    fn refinement(&self) -> Option<&Refinement> {
        self.refinement
            .get_or_init(|| Refinement::new(self.inner.tracker().model().poses()))
            .as_ref()
    }

    /// The settings it was fitted with.
    pub fn settings(&self) -> &TemporalSettings {
        &self.file.settings
    }

    /// The reliability α of the carried belief, and whether it was learned.
    pub fn reliability(&self) -> (f64, bool) {
        (self.file.reliability, self.file.reliability_learned)
    }

    /// The estimates the velocity line goes through (0: constant position, as the validation
    /// motion chose when `learn_velocity`).
    pub fn velocity_frames(&self) -> usize {
        self.file.velocity_frames
    }

    /// The paper's tracker inside.
    pub fn evidential(&self) -> &Evidential {
        &self.inner
    }

    /// Reads a model file's text.
    ///
    /// # Errors
    /// [`EstimatorError::File`] naming what is wrong.
    pub fn from_json(text: &str) -> Result<Self, EstimatorError> {
        let file: TemporalFile = model_file::parse(text, Self::METHOD, Self::FORMAT_VERSION)?;
        file.settings
            .check()
            .map_err(|e| corrupted(format!("settings: {e}")))?;
        within(file.reliability, 0.0..=1.0).map_err(|e| corrupted(format!("reliability: {e}")))?;
        within(file.frame_error, 0.0..=1e5).map_err(|e| corrupted(format!("frame_error: {e}")))?;
        if ![0, file.settings.velocity_frames].contains(&file.velocity_frames) {
            return Err(corrupted(format!(
                "velocity_frames: {} is neither the settings' {} nor 0",
                file.velocity_frames, file.settings.velocity_frames
            ))
            .into());
        }
        let model = EvidentialModel::from_json(&file.evidential_model)
            .map_err(|e| corrupted(format!("evidential_model: {e}")))?;
        let inner = Evidential::from_model(model)?;
        if let Some(why) = too_many_features(inner.feature_names().len()) {
            return Err(corrupted(format!("evidential_model: {why}")).into());
        }
        if let SelectionPolicy::Splitting { .. } = inner.model().track_settings().selection {
            return Err(corrupted(
                "evidential_model: the splitting policy is not taken with the past",
            )
            .into());
        }
        Ok(Self::assemble(inner, file))
    }

    /// Reads a model file.
    ///
    /// # Errors
    /// As [`TemporalEvidential::from_json`], naming the path.
    pub fn load(path: &Path) -> Result<Self, EstimatorError> {
        Ok(model_file::load(path, Self::from_json)?)
    }
}

impl PoseEstimator for TemporalEvidential {
    fn method(&self) -> &'static str {
        Self::METHOD
    }

    fn feature_names(&self) -> &[String] {
        self.inner.feature_names()
    }

    fn feature_config(&self) -> Option<&FeatureConfig> {
        self.inner.feature_config()
    }

    /// A frame alone has no past: the paper tracker's estimate.
    fn estimate(&self, features: &[Option<f64>]) -> Result<PoseEstimate, EstimatorError> {
        self.inner.estimate(features)
    }

    fn to_json(&self) -> Result<String, EstimatorError> {
        Ok(model_file::to_text(&self.file)?)
    }

    fn start_motion(&self) -> Box<dyn MotionTracker + '_> {
        Box::new(EvidentialMotion {
            estimator: self,
            past: None,
            line: VelocityLine::new(self.file.velocity_frames),
            misses: Vec::new(),
        })
    }

    fn with_provenance(
        &self,
        provenance: &crate::model_file::Provenance,
    ) -> Option<Box<dyn PoseEstimator>> {
        let inner = self.inner.reprovenanced(provenance);
        let mut file = self.file.clone();
        file.evidential_model = inner.to_json().ok()?;
        Some(Box::new(Self {
            inner,
            file,
            refinement: self.refinement.clone(),
            buckets: self.buckets.clone(),
        }))
    }
}

/// One motion under the temporal evidential tracker.
struct EvidentialMotion<'a> {
    estimator: &'a TemporalEvidential,
    past: Option<Carried>,
    /// The line through the last estimates of frames whose own features outweighed the past.
    line: VelocityLine,
    /// The squared distances between the line's last predictions and those frames' estimates
    /// on the sample weights, at most [`MISS_FRAMES`], oldest first.
    misses: Vec<f64>,
}

/// The belief carried from the last frame.
struct Carried {
    /// The frame's time.
    time: f64,
    /// Its contour over the sample poses (max 1, before moving).
    contour: Vec<f64>,
    /// Whether it comes from a frame whose usable features together were beyond the threshold.
    doubtful: bool,
}

/// How many of the line's last misses set its spread.
const MISS_FRAMES: usize = 5;

impl EvidentialMotion<'_> {
    /// The velocity prediction's spread: as set, or half the sample spacing widened to what the
    /// line's last misses hold beyond the frames' own error (mean square minus the validation
    /// one): on a tight fast circle the line lags by more than half a spacing, and a tighter
    /// belief pulls the estimate off the path.
    fn spread(&self, refinement: &Refinement) -> f64 {
        let file = &self.estimator.file;
        (file.settings.velocity_spread)
            .unwrap_or_else(|| line_spread(refinement.spacing(), &self.misses, file.frame_error))
    }

    /// Whether a frame with this level of conflict among all its usable features is beyond
    /// the conflict threshold (or has no level).
    fn incoherent(&self, full_conflict_level: Option<f64>) -> bool {
        let threshold = self.estimator.inner.tracker().settings().conflict_threshold;
        !full_conflict_level.is_some_and(|level| threshold.admits(level))
    }

    /// Keeps how far the line's prediction at `time` lay from `measured`, a frame's estimate
    /// on the sample weights.
    fn remember_miss(&mut self, time: f64, measured: Option<[f64; 2]>) {
        if let (Some(p), Some(m)) = (self.line.predict(time), measured) {
            self.misses
                .push((p[0] - m[0]).powi(2) + (p[1] - m[1]).powi(2));
            if self.misses.len() > MISS_FRAMES {
                self.misses.remove(0);
            }
        }
    }

    /// The estimate of `weights` over the sample poses refined with the velocity prediction
    /// at `time`; `None` when there is no prediction (fewer than two estimates since the last
    /// restart) or no refinement.
    fn refined(&self, time: f64, weights: &[f64]) -> Option<[f64; 2]> {
        let predicted = self.line.predict(time)?;
        let refinement = self.estimator.refinement()?;
        let spread = self.spread(refinement);
        let map = self.estimator.inner.tracker().settings().estimator == PoseRule::Map;
        refinement.estimate(weights, predicted, spread, map)
    }
}

impl MotionTracker for EvidentialMotion<'_> {
    fn next(
        &mut self,
        time: f64,
        features: &[Option<f64>],
    ) -> Result<PoseEstimate, EstimatorError> {
        let inner = &self.estimator.inner;
        let tracker = inner.tracker();
        let policy = self.estimator.file.settings.incoherent_frames;
        let Some(past) = self.past.take() else {
            let frame = inner.track(features)?;
            let incoherent = self.incoherent(frame.full_conflict_level);
            if incoherent && policy == IncoherentFrames::Skipped {
                return Ok(inner.pose_estimate(frame));
            }
            self.past = scaled_to_max(&frame.plausibility).map(|contour| Carried {
                time,
                contour,
                doubtful: incoherent,
            });
            let own = frame.group.len();
            let estimate = inner.pose_estimate(frame);
            let weight = self.estimator.file.settings.past_weight_for(features.len());
            self.line.feed(time, estimate.pose, own, weight, false);
            return Ok(estimate);
        };
        let interval = (time - past.time).max(0.0);
        let reach = self.estimator.file.settings.max_speed * interval;
        let shift = self.line.shift(interval);
        let moved = self.estimator.buckets.dilate(&past.contour, reach, shift);
        let alpha = self.estimator.file.reliability;
        let carried: Vec<f64> = moved.iter().map(|&m| 1.0 - alpha + alpha * m).collect();
        let likelihoods = inner.model().frames().likelihoods(features)?;
        let settings = &self.estimator.file.settings;
        let weight = settings.past_weight_for(likelihoods.len());
        let doubtful = past.doubtful && policy == IncoherentFrames::Outweighed;
        let outcome = tracker.track_with_past(&likelihoods, &carried, weight, doubtful)?;
        let mut estimate = inner.pose_estimate(outcome.frame.clone());
        if outcome.frame.estimate.is_some() {
            estimate.flags.past_rejected = !outcome.past_joined;
            // The past outweighed every feature: the estimate is the prediction.
            estimate.flags.predicted = outcome.past_joined && outcome.frame.group.is_empty();
            if outcome.past_joined {
                if let Some(pose) = self.refined(time, &outcome.frame.plausibility) {
                    estimate.pose = Some(pose);
                }
            }
            let incoherent = self.incoherent(outcome.frame.full_conflict_level);
            if incoherent && policy == IncoherentFrames::Skipped {
                self.past = Some(past);
                return Ok(estimate);
            }
            let own = outcome.frame.group.len();
            // Only frames that would feed the line measure its miss.
            if own as f64 > weight {
                self.remember_miss(time, outcome.frame.estimate);
            }
            self.line
                .feed(time, estimate.pose, own, weight, outcome.past_joined);
            // Nothing to carry (not expected with an estimate): keep the moved past.
            self.past = Some(match scaled_to_max(&outcome.frame.plausibility) {
                Some(contour) => Carried {
                    time,
                    contour,
                    doubtful: incoherent,
                },
                None => Carried {
                    time,
                    contour: moved,
                    doubtful: past.doubtful,
                },
            });
            return Ok(estimate);
        }
        // No usable measurement: the prediction.
        let total: f64 = moved.iter().sum();
        let weights: Vec<f64> = moved.iter().map(|m| m / total).collect();
        if let Some((pose, uncertainty)) = tracker.estimate_with_weights(&weights) {
            estimate.pose = Some(self.refined(time, &weights).unwrap_or(pose));
            estimate.uncertainty_radius = Some(uncertainty.radius);
            estimate.covariance = Some(uncertainty.covariance);
            estimate.flags.predicted = true;
            estimate.flags.combination_failed = false;
        }
        self.past = Some(Carried {
            time,
            contour: moved,
            doubtful: past.doubtful,
        });
        Ok(estimate)
    }
}

/// Half the sample `spacing`, or the RMS of the line's squared `misses` beyond the frames' own
/// error `frame_error` when that is wider.
fn line_spread(spacing: f64, misses: &[f64], frame_error: f64) -> f64 {
    let mean = misses.iter().sum::<f64>() / misses.len().max(1) as f64;
    (0.5 * spacing).max((mean - frame_error * frame_error).max(0.0).sqrt())
}

/// The contour scaled to maximum 1; `None` when it has no positive finite maximum.
fn scaled_to_max(contour: &[f64]) -> Option<Vec<f64>> {
    let max = contour.iter().copied().fold(0.0f64, f64::max);
    (max > 0.0 && max.is_finite()).then(|| contour.iter().map(|c| c / max).collect())
}

/// The scenario checks of the temporal evidential tracker: the `[temporal]` section, no
/// splitting, and the HMM frames' limits.
pub(crate) fn check_settings(
    settings: &super::EstimatorSettings,
    context: &super::SettingsContext,
) -> Result<(), String> {
    super::motion::check_temporal(
        &settings.temporal,
        Some((
            &settings.evidential.track.selection,
            "track",
            "the temporal evidential tracker",
            TemporalEvidential::METHOD,
        )),
    )?;
    if let Some(why) = too_many_features(context.feature_names.len()) {
        return Err(format!("[features]: {why}"));
    }
    super::evidential::check_discrete_frames(settings, context)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_carried_belief_leaves_room_for_63_features() {
        assert_eq!(too_many_features(63), None);
        let why = too_many_features(64).unwrap();
        assert!(why.contains("at most 63"), "{why}");
    }

    #[test]
    fn the_line_widens_only_by_what_it_misses_beyond_the_frames_own_error() {
        // No miss yet, or misses no larger than the frames' own error: half the spacing.
        assert_eq!(line_spread(1.0, &[], 0.5), 0.5);
        assert_eq!(line_spread(1.0, &[0.25, 0.36], 0.6), 0.5);
        // Misses of 1 mm (mean square 1) with frames 0.6 mm off: the line's own 0.8 mm.
        assert!((line_spread(1.0, &[1.0, 1.0], 0.6) - 0.8).abs() < 1e-12);
        assert!((line_spread(1.0, &[2.0, 0.0], 0.6) - 0.8).abs() < 1e-12);
    }

    #[test]
    fn settings_are_checked() {
        let bad = |s: TemporalSettings| s.check().unwrap_err().to_string();
        assert!(bad(TemporalSettings {
            max_speed: 0.0,
            ..TemporalSettings::default()
        })
        .contains("temporal.max_speed"));
        assert!(bad(TemporalSettings {
            reliability: Some(1.5),
            ..TemporalSettings::default()
        })
        .contains("temporal.reliability"));
        assert!(bad(TemporalSettings {
            velocity_spread: Some(0.0),
            ..TemporalSettings::default()
        })
        .contains("temporal.velocity_spread"));
        assert!(TemporalSettings::default().check().is_ok());
    }
}
