//! Planar geometry of poses (mm): distances, bounding boxes, the workspace rectangle and the
//! check every pose read is held to. A leaf: every room that measures or bounds poses uses it.

use serde::{Deserialize, Serialize};

/// Euclidean distance between two planar points.
pub fn distance(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

/// The lowest and highest x and y of the poses (±∞ inverted without poses).
pub fn bounding_box(poses: &[[f64; 2]]) -> ([f64; 2], [f64; 2]) {
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for p in poses {
        for k in 0..2 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    (lo, hi)
}

/// The diagonal of the poses' bounding box (0 without poses).
pub fn bounding_diagonal(poses: &[[f64; 2]]) -> f64 {
    let (lo, hi) = bounding_box(poses);
    if poses.is_empty() {
        0.0
    } else {
        (hi[0] - lo[0]).hypot(hi[1] - lo[1])
    }
}

/// An axis-aligned rectangle in mm (used for the robot's workspace).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Rect {
    /// Smallest x.
    pub x_min: f64,
    /// Largest x.
    pub x_max: f64,
    /// Smallest y.
    pub y_min: f64,
    /// Largest y.
    pub y_max: f64,
}

/// Pose coordinates beyond ±this (mm) are refused wherever poses are read, whether a workspace is
/// declared or not: no rig is 10 m across, and a pose of 1e300 mm only makes every error absurd.
pub const MAX_COORDINATE_MM: f64 = 1e4;

impl Rect {
    /// The rectangle's diagonal: the largest distance between two points inside it.
    pub fn diagonal(&self) -> f64 {
        (self.x_max - self.x_min).hypot(self.y_max - self.y_min)
    }

    /// Its area (mm²).
    pub fn area(&self) -> f64 {
        (self.x_max - self.x_min) * (self.y_max - self.y_min)
    }

    /// How far outside the rectangle a pose may lie and still count as in it: 5 % of its larger
    /// side (simulated poses settle within 0.0001 mm of the 19 mm workspace's edges).
    pub fn slack(&self) -> f64 {
        0.05 * (self.x_max - self.x_min).max(self.y_max - self.y_min)
    }

    /// Finite, within ±[`MAX_COORDINATE_MM`], with `x_min < x_max` and `y_min < y_max`.
    pub fn check(&self) -> Result<(), String> {
        let corners = [self.x_min, self.x_max, self.y_min, self.y_max];
        if !corners.iter().all(|v| v.abs() <= MAX_COORDINATE_MM)
            || self.x_min >= self.x_max
            || self.y_min >= self.y_max
        {
            return Err(format!(
                "workspace {self:?} must have finite bounds within ±{MAX_COORDINATE_MM} mm with \
                 x_min < x_max and y_min < y_max"
            ));
        }
        Ok(())
    }
}

/// Why the position `p` (mm) cannot be a pose: not finite, beyond ±[`MAX_COORDINATE_MM`], or
/// outside the declared `workspace` by more than its [`Rect::slack`].
pub fn check_position(p: [f64; 2], workspace: Option<&Rect>) -> Result<(), String> {
    if !p.iter().all(|v| v.abs() <= MAX_COORDINATE_MM) {
        return Err(format!(
            "position ({}, {}) mm is not finite or beyond ±{MAX_COORDINATE_MM} mm",
            p[0], p[1]
        ));
    }
    if let Some(w) = workspace {
        let slack = w.slack();
        if p[0] < w.x_min - slack
            || p[0] > w.x_max + slack
            || p[1] < w.y_min - slack
            || p[1] > w.y_max + slack
        {
            return Err(format!(
                "position ({}, {}) mm is outside the declared workspace x {}..{}, y {}..{} mm \
                 (by more than its slack of {slack:.3} mm)",
                p[0], p[1], w.x_min, w.x_max, w.y_min, w.y_max
            ));
        }
    }
    Ok(())
}
