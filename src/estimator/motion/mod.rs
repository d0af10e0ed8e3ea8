//! The motion model shared by the temporal methods: its settings (`[temporal]`), the
//! constant-velocity line through the last estimates ([`VelocityLine`]), the sample poses refined
//! onto a sub-grid ([`Refinement`]), and learning the carried belief's reliability α on the
//! validation motion. The temporal methods use it; none imports another.

mod dilate;
mod refine;
mod velocity;

pub use dilate::PoseBuckets;

pub use refine::{cell_variance, Refinement};
pub(crate) use refine::{MAX_POINTS as REFINE_MAX_POINTS, SUBDIVISIONS as REFINE_SUBDIVISIONS};
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
    /// estimate's error and a tight reach makes the tracker lag (docs/results.md, "Tracking over time").
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
    /// `evidential_temporal` only: with a timed validation motion, keep the velocity line only
    /// when it lowers the validation error below constant position's (each with its own α).
    /// On coarse frames (2 mm mesh, 4 states) the line, fed the estimates it pulled, drifts.
    #[serde(skip_serializing_if = "is_true")]
    pub learn_velocity: bool,
    /// Spread σ (mm) of the velocity prediction's consonant belief on the refined sample poses
    /// (`refine`); `None`: half the sample poses' typical spacing, widened by
    /// `evidential_temporal` to the RMS of the line's last five misses.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub velocity_spread: Option<f64>,
    /// `evidential_temporal` and `continuous_temporal`: what becomes of a frame whose usable
    /// features together are beyond the conflict threshold (a bright box or glare corrupts every
    /// global feature), as the past of the next frame.
    pub incoherent_frames: IncoherentFrames,
}

/// What the temporal trackers carry from a frame whose usable features together are beyond the
/// conflict threshold (`temporal.incoherent_frames`).
///
/// Carried as any other, such a frame's pose (mm off under a bright box) joins the next clean
/// frame with all but one of its features, the past counting as half of them, and pulls it off.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum IncoherentFrames {
    /// Carried as any other frame (before the twenty-first session).
    Carried,
    /// Carried, but a next frame whose usable features all agree keeps them all: the past joins
    /// it only beside every one of them.
    #[default]
    Outweighed,
    /// Not carried: the past and the velocity line stay as the last frame within the threshold
    /// left them, the reach growing with the time since (costs bursts of struck frames their
    /// chain).
    Skipped,
}

/// The reliabilities tried when learning α.
pub const RELIABILITY_CANDIDATES: [f64; 7] = [0.5, 0.8, 0.9, 0.95, 0.98, 0.99, 1.0];

/// α when it is neither given nor learnable (no validation motion with timestamps).
pub const DEFAULT_RELIABILITY: f64 = 0.9;

/// Validation errors within this relative margin of the lowest are a tie.
const RELIABILITY_TIE: f64 = 1e-9;

/// The share by which the velocity line must lower the validation error to be kept. On
/// `time.toml`'s validation path (seeds 1–5) it lowers it by 11–15 % with 24 states and raises it
/// by 7–37 % on coarse frames (2 mm mesh, 4 states); a gain below 5 % is noise on 100 frames (an
/// earlier spread rule kept the line on one coarse seed for 4 %, and its Lissajous error rose 17 %).
pub const LINE_GAIN: f64 = 0.05;

impl Default for TemporalSettings {
    fn default() -> Self {
        Self {
            max_speed: 80.0,
            reliability: None,
            past_weight: None,
            velocity_frames: 3,
            learn_velocity: true,
            velocity_spread: None,
            incoherent_frames: IncoherentFrames::default(),
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

/// α as given, or learned on the validation motion: the candidate with the lowest
/// `error(α)`, the largest among ties. `None` when it is neither given nor learnable
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

/// What the temporal evidential tracker learns on the validation motion: α and whether the
/// velocity line is used.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct LearnedMotion {
    /// The reliability α of the carried belief.
    pub reliability: f64,
    /// The estimates the velocity line goes through (0: constant position).
    pub velocity_frames: usize,
}

/// α and the velocity line as given, or learned on the validation motion: every pair of an α
/// candidate ([`learned_reliability`]'s) and a line (`velocity_frames`, and 0 when
/// `learn_velocity`), the lowest `error(α, frames)`; the line is kept only when it is lower
/// than every constant-position pair by [`LINE_GAIN`] (it must help), and among ties the
/// largest α. `None` when nothing is learnable (no validation motion with timestamps).
pub(crate) fn learned_motion(
    settings: &TemporalSettings,
    data: &TrainingSet,
    mut error: impl FnMut(f64, usize) -> Result<f64, EstimatorError>,
) -> Result<Option<LearnedMotion>, EstimatorError> {
    if data.validation.is_none() || data.validation_times.is_none() {
        return Ok(None);
    }
    let alphas: Vec<f64> = match settings.reliability {
        Some(alpha) => vec![alpha],
        None => RELIABILITY_CANDIDATES.to_vec(),
    };
    let mut lines = vec![settings.velocity_frames];
    if settings.learn_velocity && settings.velocity_frames >= 2 {
        lines.insert(0, 0);
    }
    let mut best: Option<(f64, LearnedMotion)> = None;
    // Constant position first: the line replaces it only when clearly lower.
    for &velocity_frames in &lines {
        let errors = (alphas.iter())
            .map(|&alpha| error(alpha, velocity_frames))
            .collect::<Result<Vec<_>, _>>()?;
        let lowest = errors.iter().copied().fold(f64::INFINITY, f64::min);
        let Some(reliability) = (alphas.iter().zip(&errors).rev())
            .find(|(_, &e)| e <= lowest * (1.0 + RELIABILITY_TIE))
            .map(|(&alpha, _)| alpha)
        else {
            continue;
        };
        if best.is_none_or(|(b, _)| lowest < b * (1.0 - LINE_GAIN)) {
            let choice = LearnedMotion {
                reliability,
                velocity_frames,
            };
            best = Some((lowest, choice));
        }
    }
    Ok(best.map(|(_, choice)| choice))
}

fn is_true(value: &bool) -> bool {
    *value
}

/// Mean error of `estimator` over the validation motion, frames in order (frames without an
/// estimate count as the missing penalty); 0 without one.
pub(crate) fn motion_error(
    estimator: &dyn PoseEstimator,
    data: &TrainingSet,
) -> Result<f64, EstimatorError> {
    Ok(motion_error_within(estimator, data, f64::INFINITY)?.unwrap_or(f64::INFINITY))
}

/// [`motion_error`], or `None` as soon as the frames so far put the mean above `bound`: the
/// terms are non-negative and rounding is monotone, so the whole motion's mean would be above
/// it too. A search for the lowest error stops a candidate there (the same choice, fewer passes).
pub(crate) fn motion_error_within(
    estimator: &dyn PoseEstimator,
    data: &TrainingSet,
    bound: f64,
) -> Result<Option<f64>, EstimatorError> {
    let (Some(validation), Some(times)) = (&data.validation, data.validation_times) else {
        return Ok(Some(0.0));
    };
    let frames = validation.rows.len().max(1) as f64;
    let mut motion = estimator.start_motion();
    let mut total = 0.0;
    for ((&t, row), &q) in times.iter().zip(validation.rows).zip(validation.poses) {
        total += motion
            .next(t, row)?
            .pose
            .map_or(data.missing_penalty, |p| distance(p, q));
        if total / frames > bound {
            return Ok(None);
        }
    }
    Ok(Some(total / frames))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimator::Labelled;

    /// `learned_motion` over a made-up validation error.
    fn learn(
        settings: &TemporalSettings,
        error: impl Fn(f64, usize) -> f64,
    ) -> Option<LearnedMotion> {
        let names = ["f".to_string()];
        let (poses, rows) = (
            [[0.0, 40.0], [1.0, 40.0]],
            [vec![Some(0.0)], vec![Some(1.0)]],
        );
        let labelled = Labelled {
            poses: &poses,
            rows: &rows,
        };
        let mut data = TrainingSet::new(&names, labelled);
        data.validation = Some(labelled);
        data.validation_times = Some(&[0.0, 0.1]);
        learned_motion(settings, &data, |a, f| Ok(error(a, f))).unwrap()
    }

    #[test]
    fn a_bounded_error_is_the_full_one_or_stops_above_its_bound() {
        // The centre answers (0, 45) every frame: errors 5, 0, 5, 10 over four frames.
        let names = ["f".to_string()];
        let poses = [[0.0, 40.0], [0.0, 45.0], [0.0, 50.0], [0.0, 55.0]];
        let rows = vec![vec![Some(0.0)]; 4];
        let labelled = Labelled {
            poses: &[[0.0, 35.0], [0.0, 55.0]],
            rows: &rows[..2],
        };
        let mut data = TrainingSet::new(&names, labelled);
        data.validation = Some(Labelled {
            poses: &poses,
            rows: &rows,
        });
        data.validation_times = Some(&[0.0, 0.1, 0.2, 0.3]);
        let centre = crate::estimator::Centre::fit(&Default::default(), &data).unwrap();
        let full = motion_error(&centre, &data).unwrap();
        assert_eq!(full, 5.0);
        for bound in [5.0, 7.0, f64::INFINITY] {
            let within = motion_error_within(&centre, &data, bound).unwrap();
            assert_eq!(within.map(f64::to_bits), Some(full.to_bits()), "{bound}");
        }
        // The running mean (1.25, 1.25, 2.5, 5) passes 4.99 at the last frame, 0 at the first.
        assert_eq!(motion_error_within(&centre, &data, 4.99).unwrap(), None);
        assert_eq!(motion_error_within(&centre, &data, 0.0).unwrap(), None);
    }

    #[test]
    fn the_velocity_line_is_kept_only_when_it_helps_on_validation() {
        let settings = TemporalSettings::default();
        let choice = |reliability, velocity_frames| {
            Some(LearnedMotion {
                reliability,
                velocity_frames,
            })
        };
        // The line lowers the error: kept, with its own best α.
        let helps = |a: f64, f: usize| if f == 3 { 1.0 + (a - 0.9).abs() } else { 2.0 };
        assert_eq!(learn(&settings, helps), choice(0.9, 3));
        // The line raises it, ties, or gains less than `LINE_GAIN`: constant position, the
        // largest α among its ties.
        let small = |_: f64, f: usize| if f == 3 { 0.97 } else { 1.0 };
        assert_eq!(learn(&settings, small), choice(1.0, 0));
        let hurts = |a: f64, f: usize| {
            if f == 3 {
                3.0
            } else {
                2.0 - (a >= 0.95) as u8 as f64
            }
        };
        assert_eq!(learn(&settings, hurts), choice(1.0, 0));
        assert_eq!(learn(&settings, |_, _| 1.0), choice(1.0, 0));
        // Not learned: the line as set, α learned alone; a given α is kept.
        let fixed = TemporalSettings {
            learn_velocity: false,
            reliability: Some(0.8),
            ..settings.clone()
        };
        assert_eq!(learn(&fixed, hurts), choice(0.8, 3));
        // Without a timed validation motion nothing is learned.
        let (names, rows) = (["f".to_string()], [vec![Some(0.0)]]);
        let data = TrainingSet::new(
            &names,
            Labelled {
                poses: &[[0.0, 40.0]],
                rows: &rows,
            },
        );
        assert_eq!(
            learned_motion(&settings, &data, |_, _| Ok(0.0)).unwrap(),
            None
        );
    }
}
