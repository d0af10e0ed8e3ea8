//! Five-bar geometry: settings, validation and closed-form kinematics.
//!
//! Frame: the robot's own frame, in millimetres. The base pivots sit at `(∓b, 0)`, `y` points from
//! the base towards the workspace. Joint angles are measured from the `+x` axis, counter-clockwise:
//! `θ1` is the left proximal link (pivot at `−b`), `θ2` the right one. "Elbows out": the left
//! elbow lies left of the line from its pivot to the end-effector, the right elbow right of it.

use serde::{Deserialize, Serialize};

use super::SimError;
use crate::planar::Rect;

/// Largest Jacobian condition number accepted anywhere in the workspace.
pub const MAX_CONDITION: f64 = 10.0;
/// Smallest angle (degrees) accepted between a proximal and a distal link, and between the two
/// distal links, and the same distance from a straight angle: closer is near-singular.
pub const MIN_SINGULAR_MARGIN_DEG: f64 = 15.0;

/// Raw five-bar geometry (mm). Validate with [`Geometry::check`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Geometry {
    /// Half the distance between the two base pivots (pivots at `(−b, 0)` and `(b, 0)`).
    pub base_half_span: f64,
    /// Length of each proximal (motor-driven) link.
    pub proximal: f64,
    /// Length of each distal link.
    pub distal: f64,
    /// Radius of the link capsules.
    pub link_radius: f64,
    /// Radius of the end-effector disc.
    pub end_effector_radius: f64,
    /// The rectangle the end-effector must be able to reach everywhere.
    pub workspace: Rect,
}

impl Default for Geometry {
    fn default() -> Self {
        Geometry {
            base_half_span: 10.0,
            proximal: 30.0,
            distal: 50.0,
            link_radius: 0.8,
            end_effector_radius: 1.5,
            workspace: Rect {
                x_min: -9.5,
                x_max: 9.5,
                y_min: 38.0,
                y_max: 57.0,
            },
        }
    }
}

/// Which arm a kinematic quantity belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Arm {
    Left,
    Right,
}

impl Geometry {
    /// Validates the geometry: positive finite sizes, a proper workspace rectangle, every point of
    /// it reachable with elbows out and away from serial and parallel singularities.
    pub fn check(&self) -> Result<FiveBar, SimError> {
        let fields = [
            ("base_half_span", self.base_half_span),
            ("proximal", self.proximal),
            ("distal", self.distal),
            ("link_radius", self.link_radius),
            ("end_effector_radius", self.end_effector_radius),
        ];
        for (name, v) in fields {
            if !(v.is_finite() && v > 0.0) {
                return Err(SimError::Settings(format!(
                    "geometry.{name} = {v} must be a positive finite length in mm"
                )));
            }
        }
        let w = &self.workspace;
        if ![w.x_min, w.x_max, w.y_min, w.y_max]
            .iter()
            .all(|v| v.is_finite())
            || w.x_min >= w.x_max
            || w.y_min >= w.y_max
        {
            return Err(SimError::Settings(format!(
                "geometry.workspace {w:?} must be finite with x_min < x_max and y_min < y_max"
            )));
        }
        if w.y_min <= 0.0 {
            return Err(SimError::Settings(format!(
                "geometry.workspace.y_min = {} must be > 0: the workspace lies above the base \
                 pivots (y > 0)",
                w.y_min
            )));
        }
        let fb = FiveBar { g: self.clone() };
        let corners = [
            ("bottom-left", w.x_min, w.y_min),
            ("bottom-right", w.x_max, w.y_min),
            ("top-left", w.x_min, w.y_max),
            ("top-right", w.x_max, w.y_max),
        ];
        for (name, x, y) in corners {
            if let Err(why) = fb.pose_quality(x, y) {
                return Err(SimError::Workspace(format!(
                    "workspace corner {name} ({x}, {y}) mm: {why}; shrink the workspace or \
                     change the link lengths"
                )));
            }
        }
        // Corners are not enough in general: scan the whole rectangle.
        let n = 40;
        for j in 0..=n {
            for i in 0..=n {
                let x = w.x_min + (w.x_max - w.x_min) * i as f64 / n as f64;
                let y = w.y_min + (w.y_max - w.y_min) * j as f64 / n as f64;
                if let Err(why) = fb.pose_quality(x, y) {
                    return Err(SimError::Workspace(format!(
                        "workspace point ({x:.3}, {y:.3}) mm: {why}; shrink the workspace or \
                         change the link lengths"
                    )));
                }
            }
        }
        Ok(fb)
    }
}

/// A validated five-bar: closed-form kinematics and workspace queries.
#[derive(Debug, Clone, PartialEq)]
pub struct FiveBar {
    g: Geometry,
}

/// Angle between two vectors, in degrees in [0, 180].
fn angle_deg(a: [f64; 2], b: [f64; 2]) -> f64 {
    let cross = a[0] * b[1] - a[1] * b[0];
    let dot = a[0] * b[0] + a[1] * b[1];
    cross.abs().atan2(dot).to_degrees()
}

impl FiveBar {
    /// The geometry this five-bar was validated from.
    pub fn geometry(&self) -> &Geometry {
        &self.g
    }

    /// The workspace rectangle (mm, robot frame).
    pub fn workspace(&self) -> Rect {
        self.g.workspace
    }

    /// Centre of the workspace rectangle.
    pub fn workspace_centre(&self) -> [f64; 2] {
        let w = &self.g.workspace;
        [(w.x_min + w.x_max) / 2.0, (w.y_min + w.y_max) / 2.0]
    }

    /// Whether `(x, y)` lies in the workspace (boundary included, 1e-9 mm slack).
    pub fn contains(&self, x: f64, y: f64) -> bool {
        let w = &self.g.workspace;
        let e = 1e-9;
        x >= w.x_min - e && x <= w.x_max + e && y >= w.y_min - e && y <= w.y_max + e
    }

    /// The base pivots `[left, right]`.
    pub fn pivots(&self) -> [[f64; 2]; 2] {
        let b = self.g.base_half_span;
        [[-b, 0.0], [b, 0.0]]
    }

    /// The elbows `[left, right]` for joint angles `θ`.
    pub fn elbows(&self, theta: [f64; 2]) -> [[f64; 2]; 2] {
        let [a1, a2] = self.pivots();
        let l = self.g.proximal;
        [
            [a1[0] + l * theta[0].cos(), a1[1] + l * theta[0].sin()],
            [a2[0] + l * theta[1].cos(), a2[1] + l * theta[1].sin()],
        ]
    }

    fn arm_angle(&self, arm: Arm, x: f64, y: f64) -> Result<f64, String> {
        let a = match arm {
            Arm::Left => self.pivots()[0],
            Arm::Right => self.pivots()[1],
        };
        let (dx, dy) = (x - a[0], y - a[1]);
        let d = dx.hypot(dy);
        let (l1, l2) = (self.g.proximal, self.g.distal);
        let c = (l1 * l1 + d * d - l2 * l2) / (2.0 * l1 * d);
        if !c.is_finite() || !(-1.0..=1.0).contains(&c) {
            return Err(format!(
                "{} arm cannot reach it: distance {d:.3} mm from its pivot is outside [{:.3}, {:.3}]",
                match arm {
                    Arm::Left => "left",
                    Arm::Right => "right",
                },
                (l1 - l2).abs(),
                l1 + l2
            ));
        }
        let alpha = c.acos();
        let base = dy.atan2(dx);
        Ok(match arm {
            Arm::Left => base + alpha,
            Arm::Right => base - alpha,
        })
    }

    /// Inverse kinematics (elbows out): joint angles `[θ1, θ2]` (rad) putting the end-effector at
    /// `(x, y)`. Works outside the workspace too as long as both arms reach; errors otherwise.
    pub fn inverse(&self, x: f64, y: f64) -> Result<[f64; 2], SimError> {
        if !(x.is_finite() && y.is_finite()) {
            return Err(SimError::NotFinite(format!("pose ({x}, {y})")));
        }
        let t1 = self
            .arm_angle(Arm::Left, x, y)
            .map_err(|e| SimError::Unreachable(format!("({x}, {y}) mm: {e}")))?;
        let t2 = self
            .arm_angle(Arm::Right, x, y)
            .map_err(|e| SimError::Unreachable(format!("({x}, {y}) mm: {e}")))?;
        Ok([t1, t2])
    }

    /// Forward kinematics: end-effector `[x, y]` for joint angles `[θ1, θ2]`, in the assembly mode
    /// with the end-effector on the far side of the elbows from the base (the working mode).
    pub fn forward(&self, theta: [f64; 2]) -> Result<[f64; 2], SimError> {
        if !(theta[0].is_finite() && theta[1].is_finite()) {
            return Err(SimError::NotFinite(format!("joint angles {theta:?}")));
        }
        let [b1, b2] = self.elbows(theta);
        let (dx, dy) = (b2[0] - b1[0], b2[1] - b1[1]);
        let d = dx.hypot(dy);
        let l2 = self.g.distal;
        let h2 = l2 * l2 - d * d / 4.0;
        if d == 0.0 || h2 < 0.0 {
            return Err(SimError::Unreachable(format!(
                "joint angles {theta:?} rad: elbows {d:.3} mm apart, the distal links \
                 ({l2} mm) cannot close the loop"
            )));
        }
        let h = h2.sqrt();
        let m = [(b1[0] + b2[0]) / 2.0, (b1[1] + b2[1]) / 2.0];
        // Left-hand normal of b1 -> b2: away from the base when b1 is left of b2.
        Ok([m[0] - h * dy / d, m[1] + h * dx / d])
    }

    /// Jacobian `∂(x, y)/∂(θ1, θ2)` at `(x, y)` (mm/rad, row-major).
    pub fn jacobian(&self, x: f64, y: f64) -> Result<[[f64; 2]; 2], SimError> {
        let theta = self.inverse(x, y)?;
        let [b1, b2] = self.elbows(theta);
        let l = self.g.proximal;
        // |P − B_i|² = L2²  ⇒  (P − B_i)·dP = (P − B_i)·∂B_i/∂θ_i dθ_i.
        let u1 = [x - b1[0], y - b1[1]];
        let u2 = [x - b2[0], y - b2[1]];
        let q1 = u1[0] * (-l * theta[0].sin()) + u1[1] * (l * theta[0].cos());
        let q2 = u2[0] * (-l * theta[1].sin()) + u2[1] * (l * theta[1].cos());
        let det = u1[0] * u2[1] - u1[1] * u2[0];
        if det == 0.0 {
            return Err(SimError::Unreachable(format!(
                "({x}, {y}) mm is a parallel singularity (distal links collinear)"
            )));
        }
        // inverse of [[u1x, u1y], [u2x, u2y]] times diag(q1, q2)
        Ok([
            [u2[1] * q1 / det, -u1[1] * q2 / det],
            [-u2[0] * q1 / det, u1[0] * q2 / det],
        ])
    }

    /// Condition number (ratio of singular values) of the Jacobian at `(x, y)`.
    pub fn condition(&self, x: f64, y: f64) -> Result<f64, SimError> {
        let j = self.jacobian(x, y)?;
        let (a, b, c, d) = (j[0][0], j[0][1], j[1][0], j[1][1]);
        let s = a * a + b * b + c * c + d * d;
        let det = (a * d - b * c).abs();
        let disc = ((s * s - 4.0 * det * det).max(0.0)).sqrt();
        let smax = ((s + disc) / 2.0).sqrt();
        let smin2 = (s - disc) / 2.0;
        if smin2 <= 0.0 {
            return Ok(f64::INFINITY);
        }
        Ok(smax / smin2.sqrt())
    }

    /// Why `(x, y)` is a bad pose (unreachable or near a singularity), if it is.
    fn pose_quality(&self, x: f64, y: f64) -> Result<(), String> {
        let t1 = self.arm_angle(Arm::Left, x, y)?;
        let t2 = self.arm_angle(Arm::Right, x, y)?;
        let [b1, b2] = self.elbows([t1, t2]);
        let [a1, a2] = self.pivots();
        let m = MIN_SINGULAR_MARGIN_DEG;
        for (name, a, b) in [("left", a1, b1), ("right", a2, b2)] {
            let elbow = angle_deg([b[0] - a[0], b[1] - a[1]], [x - b[0], y - b[1]]);
            if elbow < m || elbow > 180.0 - m {
                return Err(format!(
                    "{name} arm near a serial singularity (proximal/distal angle {elbow:.1}°, \
                     must stay {m}° away from 0° and 180°)"
                ));
            }
        }
        let distal = angle_deg([x - b1[0], y - b1[1]], [x - b2[0], y - b2[1]]);
        if distal < m || distal > 180.0 - m {
            return Err(format!(
                "near a parallel singularity (distal links {distal:.1}° apart, must stay {m}° \
                 away from 0° and 180°)"
            ));
        }
        let cond = self.condition(x, y).map_err(|e| e.to_string())?;
        if cond > MAX_CONDITION {
            return Err(format!(
                "Jacobian condition number {cond:.2} exceeds {MAX_CONDITION}"
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn default_geometry_is_valid_and_well_conditioned() {
        let fb = Geometry::default().check().unwrap();
        let w = fb.workspace();
        let mut worst: f64 = 0.0;
        for j in 0..=19 {
            for i in 0..=19 {
                let x = w.x_min + i as f64;
                let y = w.y_min + j as f64;
                worst = worst.max(fb.condition(x, y).unwrap());
            }
        }
        assert!(worst < 1.5, "worst condition {worst}");
    }

    #[test]
    fn unreachable_corner_is_named() {
        let mut g = Geometry::default();
        g.workspace.y_max = 90.0;
        let e = g.check().unwrap_err().to_string();
        assert!(e.contains("top-left"), "{e}");
        assert!(e.contains("cannot reach"), "{e}");
    }

    #[test]
    fn near_singular_workspace_is_rejected() {
        let mut g = Geometry::default();
        // ~79.8 mm from a pivot: the arms are almost stretched (80 mm).
        g.workspace.y_min = 78.8;
        g.workspace.y_max = 79.2;
        g.workspace.x_min = -0.2;
        g.workspace.x_max = 0.2;
        let e = g.check().unwrap_err().to_string();
        assert!(e.contains("serial singularity"), "{e}");
        assert!(e.contains("corner"), "{e}");
    }

    #[test]
    fn bad_numbers_are_rejected() {
        let g = Geometry {
            distal: f64::NAN,
            ..Geometry::default()
        };
        assert!(matches!(g.check(), Err(SimError::Settings(_))));
        let mut g = Geometry::default();
        g.workspace.x_min = 20.0;
        assert!(matches!(g.check(), Err(SimError::Settings(_))));
    }

    #[test]
    fn elbows_point_out() {
        let fb = Geometry::default().check().unwrap();
        let [t1, t2] = fb.inverse(0.0, 47.5).unwrap();
        let [b1, b2] = fb.elbows([t1, t2]);
        assert!(b1[0] < -10.0 && b2[0] > 10.0, "{b1:?} {b2:?}");
    }

    #[test]
    fn nan_pose_is_an_error() {
        let fb = Geometry::default().check().unwrap();
        assert!(fb.inverse(f64::NAN, 40.0).is_err());
        assert!(fb.forward([f64::INFINITY, 0.0]).is_err());
        assert!(fb.inverse(0.0, 200.0).is_err());
    }

    proptest! {
        #[test]
        fn ik_fk_round_trip(u in 0.0f64..=1.0, v in 0.0f64..=1.0) {
            let fb = Geometry::default().check().unwrap();
            let w = fb.workspace();
            let x = w.x_min + u * (w.x_max - w.x_min);
            let y = w.y_min + v * (w.y_max - w.y_min);
            let th = fb.inverse(x, y).unwrap();
            let p = fb.forward(th).unwrap();
            prop_assert!((p[0] - x).abs() < 1e-10 && (p[1] - y).abs() < 1e-10);
        }

        #[test]
        fn jacobian_matches_finite_differences(u in 0.0f64..=1.0, v in 0.0f64..=1.0) {
            let fb = Geometry::default().check().unwrap();
            let w = fb.workspace();
            let x = w.x_min + u * (w.x_max - w.x_min);
            let y = w.y_min + v * (w.y_max - w.y_min);
            let j = fb.jacobian(x, y).unwrap();
            let th = fb.inverse(x, y).unwrap();
            let h = 1e-6;
            for k in 0..2 {
                let mut tp = th;
                tp[k] += h;
                let mut tm = th;
                tm[k] -= h;
                let pp = fb.forward(tp).unwrap();
                let pm = fb.forward(tm).unwrap();
                for r in 0..2 {
                    let fd = (pp[r] - pm[r]) / (2.0 * h);
                    prop_assert!((fd - j[r][k]).abs() < 1e-5 * (1.0 + fd.abs()),
                        "J[{}][{}] = {} vs fd {}", r, k, j[r][k], fd);
                }
            }
        }
    }
}
