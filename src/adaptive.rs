//! The adaptive sample trajectory (paper §3.1): refine a set of sample poses until no feature
//! changes too fast between neighbouring samples (the paper's condition 2), within a budget.
//!
//! This room is a pure algorithm. It knows neither the simulator nor the feature extractor: the
//! harness passes a `measure` closure that renders the new poses and extracts their features.
//!
//! **Neighbours.** Two samples `a`, `b` are neighbours when `|a − b| ≤ r` and no other sample lies
//! strictly inside the circle with diameter `ab` (closer to the midpoint than `|a − b| / 2`, the
//! Gabriel condition), so a pair split by an added midpoint stops being a pair. The radius `r` is
//! [`NEIGHBOUR_FACTOR`] × the median nearest-neighbour distance of the *initial* samples
//! ([`neighbour_radius`]) and stays fixed while samples are added: on a regular mesh of spacing ε
//! it is 1.01 ε, which links the four axis neighbours and not the diagonals.
//!
//! **Condition 2.** A pair violates it when, for some feature `k`, both values are present and
//! `|f_k(a) − f_k(b)| > threshold · range_k`, with `range_k` the feature's max − min over the
//! current samples. Missing values (`None`) never count as changes; a feature whose range is zero
//! (or at rounding level, ≤ 1e-12 × its largest magnitude) never violates.
//!
//! **A round** adds the midpoints of the violating pairs, worst first (largest normalised change;
//! ties by lower first index, then lower second index), skipping any midpoint closer than
//! `min_spacing` to an existing or already chosen sample (or coinciding with one), until the budget
//! is full; then `measure` is called once with all new points and they are appended in that order.

use crate::range::within;
use serde::{Deserialize, Serialize};

/// The neighbour radius is this factor times the median nearest-neighbour distance of the initial
/// samples; the 1 % margin absorbs rounding on a regular mesh.
pub const NEIGHBOUR_FACTOR: f64 = 1.01;

/// Relative slack of the Gabriel test, so a sample lying on the diameter circle (up to rounding)
/// does not break a pair.
const GABRIEL_SLACK: f64 = 1e-9;

/// A feature whose range is at most this times its largest magnitude counts as constant.
const RANGE_EPS: f64 = 1e-12;

/// Everything that can go wrong refining a sample trajectory.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum AdaptiveError {
    /// A setting is out of range.
    #[error("invalid adaptive-sampling setting: {0}")]
    Settings(String),
    /// Poses, feature rows or the rows returned by `measure` do not fit together.
    #[error("mismatched lengths: {0}")]
    LengthMismatch(String),
    /// The initial samples cannot define neighbours.
    #[error("unusable initial samples: {0}")]
    Initial(String),
    /// A NaN or infinite pose or feature value.
    #[error("non-finite input: {0}")]
    NotFinite(String),
    /// The `measure` callback failed.
    #[error("measuring {points} new poses in round {round} failed: {message}")]
    Measure {
        /// The round (1-based) whose new poses were being measured.
        round: usize,
        /// How many poses were passed to `measure`.
        points: usize,
        /// The callback's own message.
        message: String,
    },
}

/// Settings of the refinement loop.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AdaptiveSettings {
    /// Largest allowed change of any feature between neighbouring samples, as a fraction of that
    /// feature's range over the current samples; in (0, 1] (1 never triggers).
    pub threshold: f64,
    /// Budget: the total sample count (initial + added) never exceeds this; at least 2 and at least
    /// the initial count.
    pub max_samples: usize,
    /// Largest number of refinement rounds (calls to `measure`); 0 only evaluates the condition.
    pub max_rounds: usize,
    /// Never add a point closer than this (mm) to an existing sample; ≥ 0.
    pub min_spacing: f64,
}

impl Default for AdaptiveSettings {
    /// A 20 % threshold, a budget of 1600 samples (4× the paper's 400-node mesh), 8 rounds and
    /// 0.1 mm minimum spacing.
    fn default() -> Self {
        Self {
            threshold: 0.2,
            max_samples: 1600,
            max_rounds: 8,
            min_spacing: 0.1,
        }
    }
}

impl AdaptiveSettings {
    /// Checks that every setting is in range.
    pub fn check(&self) -> Result<(), AdaptiveError> {
        if !(self.threshold.is_finite() && self.threshold > 0.0 && self.threshold <= 1.0) {
            return Err(AdaptiveError::Settings(format!(
                "threshold = {} must be in (0, 1] (a fraction of each feature's range)",
                self.threshold
            )));
        }
        within(self.max_samples, 2..=100_000)
            .map_err(|e| AdaptiveError::Settings(format!("max_samples = {e}")))?;
        if !(self.min_spacing.is_finite() && self.min_spacing >= 0.0) {
            return Err(AdaptiveError::Settings(format!(
                "min_spacing = {} mm must be ≥ 0 and finite",
                self.min_spacing
            )));
        }
        Ok(())
    }
}

/// Why the refinement loop stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[non_exhaustive]
pub enum StopReason {
    /// No neighbouring pair violates the condition.
    Converged,
    /// Violations remain but the sample budget is full.
    BudgetSpent,
    /// Violations remain after `max_rounds` rounds.
    MaxRounds,
    /// Violations remain but every candidate midpoint is closer than `min_spacing` to a sample.
    SpacingLimit,
}

/// A neighbouring pair that violates the condition, by its worst feature.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Violation {
    /// Index of the first sample (the lower one).
    pub a: usize,
    /// Index of the second sample (`a < b`).
    pub b: usize,
    /// The feature with the largest normalised change.
    pub feature: usize,
    /// That change as a fraction of the feature's range (> threshold).
    pub change: f64,
}

/// The refined sample trajectory and how it was obtained.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AdaptiveOutcome {
    /// All sample poses: the initial ones first, then the additions in the order they were made.
    pub poses: Vec<[f64; 2]>,
    /// One feature row per pose, in the same order.
    pub features: Vec<Vec<Option<f64>>>,
    /// How many of `poses` are initial.
    pub initial_count: usize,
    /// Samples added in each round (one entry per call to `measure`).
    pub added_per_round: Vec<usize>,
    /// Violating pairs found before each round and at the end (`added_per_round.len() + 1`).
    pub violations_per_round: Vec<usize>,
    /// The neighbour radius used (mm), from the initial samples.
    pub neighbour_radius: f64,
    /// The pairs still violating the condition at the end, worst first.
    pub remaining: Vec<Violation>,
    /// Why the loop stopped.
    pub stop: StopReason,
}

impl AdaptiveOutcome {
    /// The added poses, in order.
    pub fn added(&self) -> &[[f64; 2]] {
        &self.poses[self.initial_count.min(self.poses.len())..]
    }

    /// The poses added in round `round` (0-based), or an empty slice past the last round.
    pub fn added_in_round(&self, round: usize) -> &[[f64; 2]] {
        if round >= self.added_per_round.len() {
            return &[];
        }
        let start = self.initial_count + self.added_per_round[..round].iter().sum::<usize>();
        let end = start + self.added_per_round[round];
        self.poses.get(start..end).unwrap_or(&[])
    }

    /// How many neighbouring pairs still violate the condition.
    pub fn remaining_violations(&self) -> usize {
        self.remaining.len()
    }
}

fn dist(p: [f64; 2], q: [f64; 2]) -> f64 {
    (p[0] - q[0]).hypot(p[1] - q[1])
}

/// The neighbour radius of a sample set: [`NEIGHBOUR_FACTOR`] × the median nearest-neighbour
/// distance (the mean of the two middle values for an even count). Needs at least two finite
/// poses, and a positive median (not mostly coincident poses).
pub fn neighbour_radius(poses: &[[f64; 2]]) -> Result<f64, AdaptiveError> {
    check_poses(poses, "pose")?;
    if poses.len() < 2 {
        return Err(AdaptiveError::Initial(format!(
            "{} sample(s) given; need at least 2 to define neighbours",
            poses.len()
        )));
    }
    let mut nearest: Vec<f64> = poses
        .iter()
        .enumerate()
        .map(|(i, &p)| {
            poses
                .iter()
                .enumerate()
                .filter(|&(j, _)| j != i)
                .map(|(_, &q)| dist(p, q))
                .fold(f64::INFINITY, f64::min)
        })
        .collect();
    nearest.sort_by(f64::total_cmp);
    let n = nearest.len();
    let median = if n % 2 == 1 {
        nearest[n / 2]
    } else {
        0.5 * (nearest[n / 2 - 1] + nearest[n / 2])
    };
    if !(median > 0.0 && median.is_finite()) {
        return Err(AdaptiveError::Initial(format!(
            "median nearest-neighbour distance is {median}: most initial poses coincide; \
             give distinct poses"
        )));
    }
    Ok(NEIGHBOUR_FACTOR * median)
}

/// All neighbouring pairs `(a, b)`, `a < b`, sorted: within `radius` and with no other sample
/// strictly inside their diameter circle. O(n²) in the sample count.
pub fn neighbour_pairs(poses: &[[f64; 2]], radius: f64) -> Vec<(usize, usize)> {
    let n = poses.len();
    let mut near: Vec<Vec<usize>> = vec![Vec::new(); n];
    for i in 0..n {
        for j in i + 1..n {
            if dist(poses[i], poses[j]) <= radius {
                near[i].push(j);
                near[j].push(i);
            }
        }
    }
    let mut pairs = Vec::new();
    for i in 0..n {
        for &j in near[i].iter().filter(|&&j| j > i) {
            let (p, q) = (poses[i], poses[j]);
            let half = 0.5 * dist(p, q);
            let mid = [0.5 * (p[0] + q[0]), 0.5 * (p[1] + q[1])];
            // A sample inside the diameter circle is closer than |p − q| ≤ radius to p,
            // so it is among p's near samples.
            let blocked = near[i]
                .iter()
                .any(|&k| k != j && dist(poses[k], mid) < half * (1.0 - GABRIEL_SLACK));
            if !blocked {
                pairs.push((i, j));
            }
        }
    }
    pairs
}

/// The neighbouring pairs (by [`neighbour_pairs`]) that violate condition 2, worst first (ties by
/// lower `a`, then lower `b`). Feature ranges are taken over all rows given.
pub fn violations(
    poses: &[[f64; 2]],
    features: &[Vec<Option<f64>>],
    radius: f64,
    threshold: f64,
) -> Vec<Violation> {
    let width = features.iter().map(Vec::len).max().unwrap_or(0);
    let ranges: Vec<f64> = (0..width)
        .map(|k| {
            let (lo, hi) = features
                .iter()
                .filter_map(|row| row.get(k).copied().flatten())
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
                    (lo.min(v), hi.max(v))
                });
            // a range at rounding level is a constant feature, not a tiny scale to amplify
            if hi - lo > RANGE_EPS * lo.abs().max(hi.abs()) {
                hi - lo
            } else {
                0.0
            }
        })
        .collect();
    let mut out: Vec<Violation> = neighbour_pairs(poses, radius)
        .into_iter()
        .filter_map(|(a, b)| {
            let (ra, rb) = (features.get(a)?, features.get(b)?);
            let mut worst: Option<(usize, f64)> = None;
            for (k, &range) in ranges.iter().enumerate() {
                if range <= 0.0 {
                    continue;
                }
                if let (Some(Some(x)), Some(Some(y))) = (ra.get(k), rb.get(k)) {
                    let change = (x - y).abs() / range;
                    if change > threshold && worst.is_none_or(|(_, w)| change > w) {
                        worst = Some((k, change));
                    }
                }
            }
            worst.map(|(feature, change)| Violation {
                a,
                b,
                feature,
                change,
            })
        })
        .collect();
    out.sort_by(|x, y| {
        y.change
            .total_cmp(&x.change)
            .then(x.a.cmp(&y.a))
            .then(x.b.cmp(&y.b))
    });
    out
}

fn check_poses(poses: &[[f64; 2]], what: &str) -> Result<(), AdaptiveError> {
    match poses
        .iter()
        .position(|p| !(p[0].is_finite() && p[1].is_finite()))
    {
        Some(i) => Err(AdaptiveError::NotFinite(format!(
            "{what} {i} is {:?}; give finite coordinates in mm",
            poses[i]
        ))),
        None => Ok(()),
    }
}

fn check_rows(
    rows: &[Vec<Option<f64>>],
    width: usize,
    what: &str,
    offset: usize,
) -> Result<(), AdaptiveError> {
    for (i, row) in rows.iter().enumerate() {
        if row.len() != width {
            return Err(AdaptiveError::LengthMismatch(format!(
                "{what}: feature row of sample {} has {} values, expected {width} \
                 (every row needs one entry per feature; use None for a missing value)",
                offset + i,
                row.len()
            )));
        }
        if let Some(k) = row.iter().position(|v| v.is_some_and(|v| !v.is_finite())) {
            return Err(AdaptiveError::NotFinite(format!(
                "{what}: feature {k} of sample {} is {:?}; use None for a missing value",
                offset + i,
                row[k]
            )));
        }
    }
    Ok(())
}

/// Chooses the midpoints to add, worst pair first, respecting spacing and `room`.
fn choose(poses: &[[f64; 2]], found: &[Violation], min_spacing: f64, room: usize) -> Vec<[f64; 2]> {
    let mut new: Vec<[f64; 2]> = Vec::new();
    for v in found {
        if new.len() >= room {
            break;
        }
        let (p, q) = (poses[v.a], poses[v.b]);
        let mid = [0.5 * (p[0] + q[0]), 0.5 * (p[1] + q[1])];
        let admissible = poses.iter().chain(new.iter()).all(|&s| {
            let d = dist(s, mid);
            d > 0.0 && d >= min_spacing
        });
        if admissible {
            new.push(mid);
        }
    }
    new
}

/// Refines `initial` (with its feature rows `initial_features`, one per pose, one entry per
/// feature) until no neighbouring pair violates condition 2, the budget is spent, `max_rounds`
/// rounds have run, or no admissible midpoint is left (see the module docs).
///
/// `measure` receives all new poses of a round at once and must return one feature row per pose,
/// in order, with the same feature count; its error message is carried in
/// [`AdaptiveError::Measure`]. Deterministic: same inputs and measurements → same outcome.
pub fn refine<F>(
    initial: Vec<[f64; 2]>,
    initial_features: Vec<Vec<Option<f64>>>,
    settings: &AdaptiveSettings,
    mut measure: F,
) -> Result<AdaptiveOutcome, AdaptiveError>
where
    F: FnMut(&[[f64; 2]]) -> Result<Vec<Vec<Option<f64>>>, String>,
{
    settings.check()?;
    if initial.len() != initial_features.len() {
        return Err(AdaptiveError::LengthMismatch(format!(
            "{} initial poses but {} feature rows; give one row per pose",
            initial.len(),
            initial_features.len()
        )));
    }
    if initial.len() > settings.max_samples {
        return Err(AdaptiveError::Settings(format!(
            "max_samples = {} is below the {} initial samples; raise the budget",
            settings.max_samples,
            initial.len()
        )));
    }
    let radius = neighbour_radius(&initial)?;
    let width = initial_features.first().map_or(0, Vec::len);
    if width == 0 {
        return Err(AdaptiveError::LengthMismatch(
            "the feature rows are empty; give at least one feature per sample".into(),
        ));
    }
    check_rows(&initial_features, width, "initial features", 0)?;

    let initial_count = initial.len();
    let mut poses = initial;
    let mut features = initial_features;
    let mut added_per_round = Vec::new();
    let mut violations_per_round = Vec::new();
    let stop = loop {
        let found = violations(&poses, &features, radius, settings.threshold);
        violations_per_round.push(found.len());
        if found.is_empty() {
            break (StopReason::Converged, found);
        }
        if added_per_round.len() >= settings.max_rounds {
            break (StopReason::MaxRounds, found);
        }
        let room = settings.max_samples.saturating_sub(poses.len());
        if room == 0 {
            break (StopReason::BudgetSpent, found);
        }
        let new = choose(&poses, &found, settings.min_spacing, room);
        if new.is_empty() {
            break (StopReason::SpacingLimit, found);
        }
        let round = added_per_round.len() + 1;
        let rows = measure(&new).map_err(|message| AdaptiveError::Measure {
            round,
            points: new.len(),
            message,
        })?;
        if rows.len() != new.len() {
            return Err(AdaptiveError::LengthMismatch(format!(
                "measure returned {} feature rows for {} new poses in round {round}; \
                 return one row per pose",
                rows.len(),
                new.len()
            )));
        }
        check_rows(&rows, width, "measured features", poses.len())?;
        added_per_round.push(new.len());
        poses.extend(new);
        features.extend(rows);
    };
    let (stop, remaining) = stop;
    Ok(AdaptiveOutcome {
        poses,
        features,
        initial_count,
        added_per_round,
        violations_per_round,
        neighbour_radius: radius,
        remaining,
        stop,
    })
}

#[cfg(test)]
#[path = "adaptive_tests.rs"]
mod tests;
