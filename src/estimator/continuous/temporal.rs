//! The continuous tracker over time (issue 17): the carried belief of
//! [`crate::estimator::TemporalEvidential`] in the continuous tracker's terms.
//!
//! - The carried belief is consonant: a flat top of radius `max_speed` × Δt around the last
//!   estimate moved by the velocity of the line through the last estimates
//!   ([`crate::estimator::TemporalSettings::velocity_frames`]), falling off as a Gaussian of
//!   the last fit's broadest spread (1/√ of the smallest eigenvalue of its curvature),
//!   discounted by α: its χ² term is −2 ln c(q)
//!   ([`super::frame::PastTerm`]), one more term of a group's χ² and bit `features` of its mask.
//! - The frame's own choice (the paper's selection on its features) competes with the past plus
//!   the largest group of features it can be combined with below the threshold, the past counting
//!   as `past_weight` features, as in the discrete tracker.
//! - A frame without a usable feature, or one the past outweighs entirely, gets the prediction
//!   (`predicted`): the carried belief's centre, with the reach growing until a frame is usable.

use std::path::Path;

use serde::{Deserialize, Serialize};

use super::frame::{members, Frame, PastTerm};
use super::Continuous;
use crate::estimator::inputs::frame_values;
use crate::estimator::motion::{
    learned_reliability, motion_error, IncoherentFrames, VelocityLine, DEFAULT_RELIABILITY,
};
use crate::estimator::{
    ContinuousSettings, EstimatorError, MotionTracker, PlausibilityRegion, PoseEstimate,
    PoseEstimator, TemporalSettings, TrainingSet,
};
use crate::features::FeatureConfig;
use crate::model_file::{self, corrupted, Stamp};
use crate::range::within;
use crate::track::{group_beside_past_with, past_outweighs, GroupMask};

/// Most features the continuous tracker over time takes: the carried belief is one more bit.
pub const MAX_CONTINUOUS_TEMPORAL_FEATURES: usize = super::MAX_CONTINUOUS_FEATURES - 1;

/// Why `features` features are too many for the carried belief, if they are.
pub(super) fn too_many_features(features: usize) -> Option<String> {
    (features > MAX_CONTINUOUS_TEMPORAL_FEATURES).then(|| {
        format!(
            "{features} features, but the continuous tracker over time takes at most \
             {MAX_CONTINUOUS_TEMPORAL_FEATURES} (the carried belief is one more): use fewer \
             features"
        )
    })
}

/// The continuous tracker over time, fitted.
#[derive(Debug, Clone)]
pub struct ContinuousTemporal {
    inner: Continuous,
    file: ContinuousTemporalFile,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct ContinuousTemporalFile {
    #[serde(flatten)]
    stamp: Stamp,
    settings: TemporalSettings,
    reliability: f64,
    reliability_learned: bool,
    /// The continuous tracker's model file text.
    continuous_model: String,
}

impl ContinuousTemporal {
    /// Version of the model file format this build writes and reads.
    pub const FORMAT_VERSION: u32 = 2;
    /// The `method` of its model files.
    pub const METHOD: &'static str = "continuous_temporal";

    /// Fits the continuous tracker on `data`, then learns α on the validation motion when it is
    /// not given.
    ///
    /// # Errors
    /// Invalid settings; the continuous tracker's fitting errors.
    pub fn fit(
        continuous: &ContinuousSettings,
        settings: &TemporalSettings,
        data: &TrainingSet,
    ) -> Result<Self, EstimatorError> {
        settings.check()?;
        if let crate::track::SelectionPolicy::Splitting { .. } = continuous.selection {
            return Err(EstimatorError::Training(
                "the continuous tracker over time takes `continuous.selection` largest_subset or \
                 lowest_conflict, not splitting"
                    .into(),
            ));
        }
        if let Some(why) = too_many_features(data.feature_names.len()) {
            return Err(EstimatorError::Training(why));
        }
        let inner = Continuous::fit(continuous, data)?;
        let mut fitted = Self {
            file: ContinuousTemporalFile {
                stamp: Stamp::new(Self::METHOD, Self::FORMAT_VERSION),
                settings: settings.clone(),
                reliability: DEFAULT_RELIABILITY,
                reliability_learned: false,
                continuous_model: inner.to_json()?,
            },
            inner,
        };
        let learned = learned_reliability(settings, data, |alpha| {
            fitted.file.reliability = alpha;
            motion_error(&fitted, data)
        })?;
        if let Some(alpha) = learned {
            fitted.file.reliability = alpha;
            fitted.file.reliability_learned = settings.reliability.is_none();
        }
        Ok(fitted)
    }

    /// The reliability α of the carried belief, and whether it was learned.
    pub fn reliability(&self) -> (f64, bool) {
        (self.file.reliability, self.file.reliability_learned)
    }

    /// Reads a model file's text.
    ///
    /// # Errors
    /// [`EstimatorError::File`] naming what is wrong.
    pub fn from_json(text: &str) -> Result<Self, EstimatorError> {
        let file: ContinuousTemporalFile =
            model_file::parse(text, Self::METHOD, Self::FORMAT_VERSION)?;
        file.settings
            .check()
            .map_err(|e| corrupted(format!("settings: {e}")))?;
        within(file.reliability, 0.0..=1.0).map_err(|e| corrupted(format!("reliability: {e}")))?;
        let inner = Continuous::from_json(&file.continuous_model).map_err(|e| match e {
            e @ (EstimatorError::Model(_) | EstimatorError::File(_)) => {
                corrupted(format!("continuous_model: {e}")).into()
            }
            other => other,
        })?;
        if let Some(why) = too_many_features(inner.feature_names().len()) {
            return Err(corrupted(why).into());
        }
        Ok(Self { inner, file })
    }

    /// Reads a model file.
    ///
    /// # Errors
    /// As [`ContinuousTemporal::from_json`], naming the path.
    pub fn load(path: &Path) -> Result<Self, EstimatorError> {
        Ok(model_file::load(path, Self::from_json)?)
    }
}

impl PoseEstimator for ContinuousTemporal {
    fn method(&self) -> &'static str {
        Self::METHOD
    }

    fn feature_names(&self) -> &[String] {
        self.inner.feature_names()
    }

    fn feature_config(&self) -> Option<&FeatureConfig> {
        self.inner.feature_config()
    }

    /// A frame alone has no past: the continuous tracker's estimate.
    fn estimate(&self, features: &[Option<f64>]) -> Result<PoseEstimate, EstimatorError> {
        self.inner.estimate(features)
    }

    fn to_json(&self) -> Result<String, EstimatorError> {
        Ok(model_file::to_text(&self.file)?)
    }

    fn start_motion(&self) -> Box<dyn MotionTracker + '_> {
        Box::new(ContinuousMotion {
            estimator: self,
            past: None,
            line: VelocityLine::new(self.file.settings.velocity_frames),
        })
    }

    fn with_provenance(
        &self,
        provenance: &crate::model_file::Provenance,
    ) -> Option<Box<dyn PoseEstimator>> {
        let inner = self.inner.reprovenanced(provenance);
        let mut file = self.file.clone();
        file.continuous_model = inner.to_json().ok()?;
        Some(Box::new(Self { inner, file }))
    }
}

/// The last measured frame: its time, estimate and the spread of its belief (mm).
#[derive(Debug, Clone, Copy)]
struct Last {
    /// Its usable features together were beyond the conflict threshold.
    incoherent: bool,
    time: f64,
    pose: [f64; 2],
    scale: f64,
}

struct ContinuousMotion<'a> {
    estimator: &'a ContinuousTemporal,
    past: Option<Last>,
    /// The line through the last estimates of frames whose own features outweighed the past.
    line: VelocityLine,
}

impl ContinuousMotion<'_> {
    /// Whether a frame of this detection score (the level of all its usable features) is
    /// beyond the conflict threshold (or has no score).
    fn incoherent(&self, detection_score: Option<f64>) -> bool {
        let threshold = self.estimator.inner.threshold();
        !detection_score.is_some_and(|score| threshold.admits(score))
    }

    /// `temporal.incoherent_frames`.
    fn policy(&self) -> IncoherentFrames {
        self.estimator.file.settings.incoherent_frames
    }
}

/// 1/√ of the smallest eigenvalue of a curvature (mm), kept within [1 µm, 19 mm].
fn broadest_spread(curvature: [[f64; 2]; 2]) -> f64 {
    let [[a, b], [_, c]] = curvature;
    let smallest = 0.5 * (a + c - ((a - c) * (a - c) + 4.0 * b * b).sqrt());
    let spread = 1.0 / smallest.max(0.0).sqrt();
    if spread.is_finite() {
        spread.clamp(1e-3, 19.0)
    } else {
        19.0
    }
}

impl MotionTracker for ContinuousMotion<'_> {
    fn next(
        &mut self,
        time: f64,
        features: &[Option<f64>],
    ) -> Result<PoseEstimate, EstimatorError> {
        let model = &self.estimator.inner;
        let Some(last) = self.past else {
            let estimate = model.estimate(features)?;
            let incoherent = self.incoherent(estimate.detection_score);
            let carried = !(incoherent && self.policy() == IncoherentFrames::Skipped);
            if let Some(pose) = estimate.pose.filter(|_| carried) {
                let mut frame = Frame::new(
                    model,
                    model.usable(frame_values(features, model.file.header.feature_names.len())?.0),
                );
                let group = estimate
                    .group
                    .iter()
                    .flatten()
                    .fold(0, |m: GroupMask, &i| m | 1 << i);
                let scale = broadest_spread(frame.fit(group).curvature);
                self.past = Some(Last {
                    incoherent,
                    time,
                    pose,
                    scale,
                });
                let own = estimate.group.as_ref().map_or(0, Vec::len);
                let weight = self.estimator.file.settings.past_weight_for(features.len());
                self.line.feed(time, Some(pose), own, weight, false);
            }
            return Ok(estimate);
        };
        let settings = &self.estimator.file.settings;
        let (values, missing) = frame_values(features, model.file.header.feature_names.len())?;
        let shift = self.line.shift(time - last.time);
        let past = PastTerm {
            centre: [last.pose[0] + shift[0], last.pose[1] + shift[1]],
            reach: settings.max_speed * (time - last.time).max(0.0),
            scale: last.scale,
            reliability: self.estimator.file.reliability,
        };
        let mut frame = Frame::new(model, model.usable(values)).with_past(past);
        let usable = frame.usable_mask;
        let predicted = |missing: Vec<usize>, excluded: Vec<usize>| PoseEstimate {
            pose: Some(past.centre),
            uncertainty_radius: Some(past.reach + last.scale),
            group: Some(Vec::new()),
            conflict_level: None,
            detection_score: None,
            region: None,
            covariance: Some({
                let r = past.reach + last.scale;
                [[r * r, 0.0], [0.0, r * r]]
            }),
            flags: crate::estimator::EstimateFlags {
                missing,
                excluded,
                predicted: true,
                ..Default::default()
            },
        };
        if usable == 0 {
            return Ok(predicted(missing, Vec::new()));
        }
        let alone = frame.select();
        let past_bit = frame.past_bit();
        let features = model.file.header.feature_names.len();
        // Sub-groups of the frame's own choice proven within the threshold beside the past.
        let proven = if alone.fallback {
            0
        } else {
            frame.within_beside_past(alone.chosen)
        };
        let (with_past, _) = group_beside_past_with(
            &mut frame,
            usable,
            features,
            model.file.settings.selection,
            model.threshold(),
            |_, mask| mask & !proven == 0,
        );
        let weight = settings.past_weight_for(features);
        let frame_choice = alone.chosen.map(|(_, group)| (group, alone.fallback));
        // A past from an incoherent frame may not outweigh a feature of a coherent frame (all
        // its usable features chosen, and within the threshold together: `combine = "all"`
        // chooses them all whatever their level).
        let detection_score = frame.grid_level(usable, f64::INFINITY).value;
        let incoherent = self.incoherent(Some(detection_score));
        let coherent = !incoherent
            && !alone.fallback
            && alone.chosen.is_some_and(|(_, group)| group == usable);
        let doubtful = last.incoherent && self.policy() == IncoherentFrames::Outweighed;
        let past_joins = !(doubtful && coherent && with_past != usable)
            && past_outweighs(frame_choice, with_past, weight);
        let (group, level) = match (past_joins, alone.chosen) {
            (true, _) => {
                if with_past == 0 {
                    return Ok(predicted(missing, members(usable).collect()));
                }
                let group = with_past | past_bit;
                (group, frame.grid_level(group, f64::INFINITY).value)
            }
            (false, Some((level, group))) => (group, level),
            (false, None) => return Ok(predicted(missing, Vec::new())),
        };
        let fit = frame.fit(group);
        let terms = group.count_ones();
        let region = (terms >= 2)
            .then(|| {
                PlausibilityRegion::from_curvature(
                    fit.pose,
                    fit.curvature,
                    model.file.region_chi2,
                    model.region_level(),
                )
            })
            .flatten();
        let features_only = group & !past_bit;
        // Combined with the past, the belief is no broader than the carried one (a group of
        // one feature and the past's flat top has no curvature across the feature's curve).
        let spread = broadest_spread(fit.curvature);
        let scale = if past_joins {
            spread.min(past.scale + past.reach)
        } else {
            spread
        };
        if !(incoherent && self.policy() == IncoherentFrames::Skipped) {
            self.past = Some(Last {
                incoherent,
                time,
                pose: fit.pose,
                scale,
            });
            let own = features_only.count_ones() as usize;
            self.line
                .feed(time, Some(fit.pose), own, weight, past_joins);
        }
        Ok(PoseEstimate {
            pose: Some(fit.pose),
            uncertainty_radius: region.as_ref().map(|r| r.semi_major),
            group: Some(members(features_only).collect()),
            conflict_level: Some(level),
            detection_score: Some(detection_score),
            region,
            covariance: crate::estimator::laplace_covariance(fit.curvature),
            flags: crate::estimator::EstimateFlags {
                missing,
                excluded: members(usable & !features_only).collect(),
                fallback: !past_joins && alone.fallback,
                past_rejected: !past_joins,
                ..Default::default()
            },
        })
    }
}
