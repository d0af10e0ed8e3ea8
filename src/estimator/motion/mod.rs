//! The motion model shared by the temporal methods: its settings (`[temporal]`), the
//! constant-velocity line through the last estimates ([`VelocityLine`]), the sample poses refined
//! onto a sub-grid ([`Refinement`]), and learning the carried belief's reliability α on the
//! validation motion. The temporal methods use it; none imports another.

mod refine;
mod velocity;

pub use refine::Refinement;
pub use velocity::VelocityLine;

use serde::{Deserialize, Serialize};

use super::{EstimatorError, PoseEstimator, TrainingSet};
use crate::planar::distance;
use crate::range::within;

/// The motion model and the reliability of the carried belief (`[temporal]` in scenarios).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TemporalSettings {
    /// The fastest the end effector moves (mm/s): the reach of one frame interval is
    /// `max_speed` × Δt. Default 80: twice the fastest test motion (a 40 mm/s circle; the rig
    /// follows 43 mm/s within micrometres), because the carried belief is sharper than the
    /// estimate's error and a tight reach makes the tracker lag (README, "Tracking over time").
    pub max_speed: f64,
    /// Reliability α ∈ [0, 1] of the carried belief; `None` learns it on the validation motion
    /// (the candidate with the lowest mean error, the largest among ties,
    /// [`RELIABILITY_CANDIDATES`]), or takes [`DEFAULT_RELIABILITY`] without one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reliability: Option<f64>,
    /// How many features the carried belief counts as in the largest-subset choice
    /// ([`crate::track::Tracker::track_with_past`]); `None`: half the features, so that a frame
    /// whose best coherent group holds fewer than half of its features is outweighed by the
    /// past. 1 counts it exactly as a feature.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub past_weight: Option<f64>,
    /// How many of the last estimates the velocity prediction is fitted through (a
    /// least-squares line); below 2 the estimates stay on the sample poses' weights.
    pub velocity_frames: usize,
    /// Spread σ (mm) of the velocity prediction's consonant belief on the refined sample poses
    /// ([`refine`]); `None`: half the sample poses' typical spacing.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub velocity_spread: Option<f64>,
}

/// The reliabilities tried when learning α.
pub const RELIABILITY_CANDIDATES: [f64; 7] = [0.5, 0.8, 0.9, 0.95, 0.98, 0.99, 1.0];

/// α when it is neither given nor learnable (no validation motion with timestamps).
pub const DEFAULT_RELIABILITY: f64 = 0.9;

/// Validation errors within this relative margin of the lowest are a tie.
const RELIABILITY_TIE: f64 = 1e-9;

impl Default for TemporalSettings {
    fn default() -> Self {
        Self {
            max_speed: 80.0,
            reliability: None,
            past_weight: None,
            velocity_frames: 3,
            velocity_spread: None,
        }
    }
}

impl TemporalSettings {
    /// How many features the past counts as with `features` features: `past_weight`, or half
    /// of them.
    pub fn past_weight_for(&self, features: usize) -> f64 {
        self.past_weight.unwrap_or(0.5 * features as f64)
    }

    /// Checks the ranges.
    ///
    /// # Errors
    /// [`EstimatorError::Training`] naming the field.
    pub fn check(&self) -> Result<(), EstimatorError> {
        if !(self.max_speed.is_finite() && self.max_speed > 0.0) {
            return Err(EstimatorError::Training(format!(
                "`temporal.max_speed` is {}: give the fastest speed of the end effector in mm/s \
                 (> 0)",
                self.max_speed
            )));
        }
        if let Some(alpha) = self.reliability {
            within(alpha, 0.0..=1.0)
                .map_err(|e| EstimatorError::Training(format!("`temporal.reliability`: {e}")))?;
        }
        if let Some(weight) = self.past_weight {
            if !(weight.is_finite() && weight >= 0.0) {
                return Err(EstimatorError::Training(format!(
                    "`temporal.past_weight` is {weight}: give how many features the past counts \
                     as (≥ 0)"
                )));
            }
        }
        if let Some(spread) = self.velocity_spread {
            if !(spread.is_finite() && spread > 0.0) {
                return Err(EstimatorError::Training(format!(
                    "`temporal.velocity_spread` is {spread}: give the spread of the velocity \
                     prediction in mm (> 0), or leave it out for half the sample spacing"
                )));
            }
        }
        Ok(())
    }
}

/// α as given, or learned on the validation motion: the candidate with the lowest
/// `error(α)`, the largest among ties. `None` when it is neither given nor learnable
/// The scenario checks every temporal method shares: the `[temporal]` section and, for the
/// trackers that weigh a frame's chosen group against the past, no splitting (`section` holds
/// their `selection`, `who` and `name` name the method in the message).
pub(crate) fn check_temporal(
    temporal: &TemporalSettings,
    splitting_refused: Option<(&crate::track::SelectionPolicy, &str, &str, &str)>,
) -> Result<(), String> {
    temporal.check().map_err(|e| format!("[temporal]: {e}"))?;
    match splitting_refused {
        Some((crate::track::SelectionPolicy::Splitting { .. }, section, who, name)) => {
            Err(format!(
                "[{section}]: {who} takes `selection` largest_subset or lowest_conflict, not \
             splitting: list the methods without \"{name}\" in `estimators`"
            ))
        }
        _ => Ok(()),
    }
}

/// (no validation motion with timestamps).
pub(crate) fn learned_reliability(
    settings: &TemporalSettings,
    data: &TrainingSet,
    mut error: impl FnMut(f64) -> Result<f64, EstimatorError>,
) -> Result<Option<f64>, EstimatorError> {
    if let Some(alpha) = settings.reliability {
        return Ok(Some(alpha));
    }
    if data.validation.is_none() || data.validation_times.is_none() {
        return Ok(None);
    }
    let errors = RELIABILITY_CANDIDATES
        .iter()
        .map(|&alpha| error(alpha))
        .collect::<Result<Vec<_>, _>>()?;
    let best = errors.iter().copied().fold(f64::INFINITY, f64::min);
    // Ties (a validation motion the past cannot improve on) go to the most reliable: the reach
    // is a hard bound when the speed limit holds.
    Ok(RELIABILITY_CANDIDATES
        .iter()
        .zip(&errors)
        .rev()
        .find(|(_, &e)| e <= best * (1.0 + RELIABILITY_TIE))
        .map(|(&alpha, _)| alpha))
}

/// Mean error of `estimator` over the validation motion, frames in order (frames without an
/// estimate count as the missing penalty); 0 without one.
pub(crate) fn motion_error(
    estimator: &dyn PoseEstimator,
    data: &TrainingSet,
) -> Result<f64, EstimatorError> {
    let (Some(validation), Some(times)) = (&data.validation, data.validation_times) else {
        return Ok(0.0);
    };
    let mut motion = estimator.start_motion();
    let mut total = 0.0;
    for ((&t, row), &q) in times.iter().zip(validation.rows).zip(validation.poses) {
        total += motion
            .next(t, row)?
            .pose
            .map_or(data.missing_penalty, |p| distance(p, q));
    }
    Ok(total / validation.rows.len().max(1) as f64)
}
