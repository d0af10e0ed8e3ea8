//! Motions: sample trajectories (meshes, point lists) and timed test motions.
//!
//! Node motions ([`Plan::Nodes`]) are "drive to each node, settle, capture"; timed motions
//! ([`Plan::Timed`]) are "follow with velocity feed-forward, capture at the frame rate". All
//! positions are in the robot frame (mm) and must lie inside the workspace.

use std::f64::consts::{PI, TAU};

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::geometry::FiveBar;
use super::path::{PathKind, Plan, Target, TimedPath};
use super::SimError;

/// Most nodes or frames a motion may produce.
pub const MAX_TARGETS: usize = 1_000_000;

fn default_phase() -> f64 {
    PI / 2.0
}
fn default_amplitude() -> f64 {
    0.9
}
fn default_components() -> usize {
    4
}

/// A motion of the end-effector. Scenario files write it as a table with a `kind` field.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Motion {
    /// Regular mesh of spacing `spacing` (mm) over the workspace, centred, visited row by row
    /// (rows of constant y, bottom up) in serpentine order. 1 mm on 19 × 19 mm → 400 nodes.
    Mesh {
        /// Node spacing (mm).
        spacing: f64,
    },
    /// The mesh of spacing `spacing`, keeping every `every`-th node along each axis.
    SubsampledMesh {
        /// Base mesh spacing (mm).
        spacing: f64,
        /// Keep nodes whose column and row indices are multiples of this.
        every: usize,
    },
    /// Explicit list of nodes, visited in order.
    Points {
        /// Nodes `[x, y]` (mm).
        points: Vec<[f64; 2]>,
    },
    /// Lissajous figure `x = cx + a·hw·sin(2π fx t + φ)`, `y = cy + a·hh·sin(2π fy t)` with `hw`,
    /// `hh` the workspace half-sizes.
    Lissajous {
        /// Frequency along x (Hz).
        freq_x: f64,
        /// Frequency along y (Hz).
        freq_y: f64,
        /// Phase of x (rad), default π/2.
        #[serde(default = "default_phase")]
        phase: f64,
        /// Fraction of the workspace half-size used, in (0, 1], default 0.9.
        #[serde(default = "default_amplitude")]
        amplitude: f64,
        /// Duration (s).
        duration: f64,
        /// Frame rate (frames/s).
        fps: f64,
    },
    /// Circle at constant tangential speed, starting at angle 0.
    Circle {
        /// Centre (mm); default the workspace centre.
        #[serde(default)]
        centre: Option<[f64; 2]>,
        /// Radius (mm).
        radius: f64,
        /// Tangential speed (mm/s).
        speed: f64,
        /// Duration (s).
        duration: f64,
        /// Frame rate (frames/s).
        fps: f64,
    },
    /// Archimedean spiral out from the workspace centre: radius grows linearly to `max_radius`
    /// over `duration` while turning `turns` times.
    Spiral {
        /// Final radius (mm).
        max_radius: f64,
        /// Number of turns.
        turns: f64,
        /// Duration (s).
        duration: f64,
        /// Frame rate (frames/s).
        fps: f64,
    },
    /// Seeded smooth random path: per axis a sum of sinusoids with random amplitudes, phases and
    /// frequencies scaled so the typical speed is `speed`; it stays inside 90 % of the workspace.
    RandomPath {
        /// Seed of the path's random draws. Left out of a scenario, it derives from the master
        /// seed; a motion simulated without one is refused.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        seed: Option<u64>,
        /// Typical speed (mm/s).
        speed: f64,
        /// Duration (s).
        duration: f64,
        /// Frame rate (frames/s).
        fps: f64,
        /// Sinusoids per axis, default 4.
        #[serde(default = "default_components")]
        components: usize,
    },
}

fn positive(name: &str, v: f64) -> Result<(), SimError> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(SimError::Motion(format!(
            "{name} = {v} must be positive and finite"
        )))
    }
}

fn timing(duration: f64, fps: f64) -> Result<(), SimError> {
    positive("duration", duration)?;
    positive("fps", fps)?;
    let n = (duration * fps + 1e-9).floor();
    if n < 1.0 || n > MAX_TARGETS as f64 {
        return Err(SimError::Motion(format!(
            "duration × fps = {n} frames; must be between 1 and {MAX_TARGETS}"
        )));
    }
    Ok(())
}

/// Node coordinates of a centred mesh of spacing `e` over `[lo, hi]`.
fn axis(lo: f64, hi: f64, e: f64) -> Vec<f64> {
    let n = ((hi - lo) / e + 1e-9).floor() as usize + 1;
    let off = ((hi - lo) - (n - 1) as f64 * e) / 2.0;
    (0..n).map(|k| lo + off + k as f64 * e).collect()
}

fn serpentine(xs: &[f64], ys: &[f64]) -> Vec<[f64; 2]> {
    let mut out = Vec::with_capacity(xs.len() * ys.len());
    for (j, &y) in ys.iter().enumerate() {
        if j % 2 == 0 {
            out.extend(xs.iter().map(|&x| [x, y]));
        } else {
            out.extend(xs.iter().rev().map(|&x| [x, y]));
        }
    }
    out
}

impl Motion {
    /// Short name of the motion kind (as in scenario files).
    pub fn name(&self) -> &'static str {
        match self {
            Motion::Mesh { .. } => "mesh",
            Motion::SubsampledMesh { .. } => "subsampled_mesh",
            Motion::Points { .. } => "points",
            Motion::Lissajous { .. } => "lissajous",
            Motion::Circle { .. } => "circle",
            Motion::Spiral { .. } => "spiral",
            Motion::RandomPath { .. } => "random_path",
        }
    }

    /// The motion with `seed` filled in where it is a random path without its own seed.
    pub fn with_default_seed(&self, seed: u64) -> Motion {
        match self {
            Motion::RandomPath {
                seed: None,
                speed,
                duration,
                fps,
                components,
            } => Motion::RandomPath {
                seed: Some(seed),
                speed: *speed,
                duration: *duration,
                fps: *fps,
                components: *components,
            },
            other => other.clone(),
        }
    }

    /// Validates the motion against the five-bar's workspace and returns what the robot does.
    pub fn plan(&self, fb: &FiveBar) -> Result<Plan, SimError> {
        let w = fb.workspace();
        let c = fb.workspace_centre();
        let half = [(w.x_max - w.x_min) / 2.0, (w.y_max - w.y_min) / 2.0];
        let mesh = |spacing: f64, every: usize| -> Result<Plan, SimError> {
            positive("spacing", spacing)?;
            if every == 0 {
                return Err(SimError::Motion("every must be ≥ 1".into()));
            }
            let count =
                ((w.x_max - w.x_min) / spacing + 1.0) * ((w.y_max - w.y_min) / spacing + 1.0);
            if count > MAX_TARGETS as f64 {
                return Err(SimError::Motion(format!(
                    "spacing {spacing} mm gives ~{count:.0} nodes, more than {MAX_TARGETS}"
                )));
            }
            let pick = |v: Vec<f64>| -> Vec<f64> { v.into_iter().step_by(every).collect() };
            let xs = pick(axis(w.x_min, w.x_max, spacing));
            let ys = pick(axis(w.y_min, w.y_max, spacing));
            Ok(Plan::Nodes(serpentine(&xs, &ys)))
        };
        let plan = match self {
            Motion::Mesh { spacing } => mesh(*spacing, 1)?,
            Motion::SubsampledMesh { spacing, every } => mesh(*spacing, *every)?,
            Motion::Points { points } => {
                if points.is_empty() {
                    return Err(SimError::Motion("points: the list is empty".into()));
                }
                if points.len() > MAX_TARGETS {
                    return Err(SimError::Motion(format!(
                        "points: {} nodes, more than {MAX_TARGETS}",
                        points.len()
                    )));
                }
                for (k, p) in points.iter().enumerate() {
                    if !(p[0].is_finite() && p[1].is_finite() && fb.contains(p[0], p[1])) {
                        return Err(SimError::OutsideWorkspace(format!(
                            "points[{k}] = ({}, {}) mm is outside the workspace x ∈ [{}, {}], \
                             y ∈ [{}, {}]",
                            p[0], p[1], w.x_min, w.x_max, w.y_min, w.y_max
                        )));
                    }
                }
                Plan::Nodes(points.clone())
            }
            Motion::Lissajous {
                freq_x,
                freq_y,
                phase,
                amplitude,
                duration,
                fps,
            } => {
                positive("freq_x", *freq_x)?;
                positive("freq_y", *freq_y)?;
                if !phase.is_finite() {
                    return Err(SimError::Motion(format!("phase = {phase} must be finite")));
                }
                if !(*amplitude > 0.0 && *amplitude <= 1.0) {
                    return Err(SimError::Motion(format!(
                        "amplitude = {amplitude} must be in (0, 1] (a fraction of the workspace)"
                    )));
                }
                timing(*duration, *fps)?;
                Plan::Timed(TimedPath::new(
                    PathKind::Lissajous {
                        c,
                        amp: [amplitude * half[0], amplitude * half[1]],
                        freq: [*freq_x, *freq_y],
                        phase: *phase,
                    },
                    *duration,
                    *fps,
                ))
            }
            Motion::Circle {
                centre,
                radius,
                speed,
                duration,
                fps,
            } => {
                positive("radius", *radius)?;
                positive("speed", *speed)?;
                timing(*duration, *fps)?;
                Plan::Timed(TimedPath::new(
                    PathKind::Circle {
                        c: centre.unwrap_or(c),
                        radius: *radius,
                        omega: speed / radius,
                    },
                    *duration,
                    *fps,
                ))
            }
            Motion::Spiral {
                max_radius,
                turns,
                duration,
                fps,
            } => {
                positive("max_radius", *max_radius)?;
                positive("turns", *turns)?;
                timing(*duration, *fps)?;
                Plan::Timed(TimedPath::new(
                    PathKind::Spiral {
                        c,
                        rate: max_radius / duration,
                        omega: TAU * turns / duration,
                    },
                    *duration,
                    *fps,
                ))
            }
            Motion::RandomPath {
                seed,
                speed,
                duration,
                fps,
                components,
            } => {
                positive("speed", *speed)?;
                timing(*duration, *fps)?;
                if !(1..=64).contains(components) {
                    return Err(SimError::Motion(format!(
                        "components = {components} must be in 1..=64"
                    )));
                }
                let seed = seed.ok_or_else(|| {
                    SimError::Motion(
                        "random_path has no `seed`: give one (scenarios derive it from their master seed)"
                            .into(),
                    )
                })?;
                let mut rng = ChaCha8Rng::seed_from_u64(seed);
                let mut axis_terms = |h: f64| -> Vec<(f64, f64, f64)> {
                    let raw: Vec<(f64, f64, f64)> = (0..*components)
                        .map(|_| {
                            (
                                rng.random_range(0.5..1.0),
                                rng.random_range(0.5..1.5),
                                rng.random_range(0.0..TAU),
                            )
                        })
                        .collect();
                    let sum_a: f64 = raw.iter().map(|t| t.0).sum();
                    let reach = 0.9 * h;
                    raw.into_iter()
                        .map(|(a, u, p)| {
                            // ω chosen so a sinusoid of amplitude `reach` moves at ≈ `speed`
                            (reach * a / sum_a, u * speed / reach, p)
                        })
                        .collect()
                };
                let tx = axis_terms(half[0]);
                let ty = axis_terms(half[1]);
                Plan::Timed(TimedPath::new(
                    PathKind::Random { c, terms: [tx, ty] },
                    *duration,
                    *fps,
                ))
            }
        };
        if let Plan::Timed(path) = &plan {
            // Check the whole path at 1 ms resolution (capped), not only the frames.
            let n = ((path.duration() / 1e-3).ceil() as usize).clamp(1, MAX_TARGETS);
            for k in 0..=n {
                let t = path.duration() * k as f64 / n as f64;
                let p = path.at(t);
                if !fb.contains(p[0], p[1]) {
                    return Err(SimError::OutsideWorkspace(format!(
                        "{} motion leaves the workspace at t = {t:.3} s: ({:.3}, {:.3}) mm; \
                         shrink it or move its centre",
                        self.name(),
                        p[0],
                        p[1]
                    )));
                }
            }
        }
        Ok(plan)
    }

    /// The sequence of targets: nodes (with their index as `t`) or the path at the frame times.
    pub fn targets(&self, fb: &FiveBar) -> Result<Vec<Target>, SimError> {
        Ok(match self.plan(fb)? {
            Plan::Nodes(nodes) => nodes
                .iter()
                .enumerate()
                .map(|(k, p)| Target {
                    t: k as f64,
                    x: p[0],
                    y: p[1],
                })
                .collect(),
            Plan::Timed(path) => path
                .frame_times()
                .into_iter()
                .map(|t| {
                    let p = path.at(t);
                    Target {
                        t,
                        x: p[0],
                        y: p[1],
                    }
                })
                .collect(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::Geometry;

    fn fb() -> FiveBar {
        Geometry::default().check().unwrap()
    }

    #[test]
    fn unit_mesh_has_400_serpentine_nodes() {
        let t = Motion::Mesh { spacing: 1.0 }.targets(&fb()).unwrap();
        assert_eq!(t.len(), 400);
        assert_eq!((t[0].x, t[0].y), (-9.5, 38.0));
        assert_eq!((t[19].x, t[19].y), (9.5, 38.0));
        assert_eq!((t[20].x, t[20].y), (9.5, 39.0));
        for w in t.windows(2) {
            let d = (w[1].x - w[0].x).hypot(w[1].y - w[0].y);
            assert!((d - 1.0).abs() < 1e-9, "serpentine steps are one spacing");
        }
    }

    #[test]
    fn subsampled_mesh_keeps_every_kth() {
        let t = Motion::SubsampledMesh {
            spacing: 1.0,
            every: 2,
        }
        .targets(&fb())
        .unwrap();
        assert_eq!(t.len(), 100);
        assert!(t.iter().all(|p| ((p.x + 9.5) / 2.0).fract() == 0.0));
    }

    #[test]
    fn timed_motions_stay_inside() {
        let fb = fb();
        let motions = [
            Motion::Lissajous {
                freq_x: 0.3,
                freq_y: 0.2,
                phase: 1.0,
                amplitude: 1.0,
                duration: 10.0,
                fps: 40.0,
            },
            Motion::Circle {
                centre: None,
                radius: 8.0,
                speed: 20.0,
                duration: 5.0,
                fps: 30.0,
            },
            Motion::Spiral {
                max_radius: 9.0,
                turns: 3.0,
                duration: 6.0,
                fps: 25.0,
            },
            Motion::RandomPath {
                seed: Some(7),
                speed: 30.0,
                duration: 10.0,
                fps: 40.0,
                components: 4,
            },
        ];
        for m in motions {
            let t = m.targets(&fb).unwrap();
            assert!(!t.is_empty());
            assert!(t.iter().all(|p| fb.contains(p.x, p.y)), "{}", m.name());
        }
    }

    #[test]
    fn random_path_is_seeded() {
        let m = |seed| Motion::RandomPath {
            seed: Some(seed),
            speed: 20.0,
            duration: 2.0,
            fps: 10.0,
            components: 3,
        };
        let a = m(1).targets(&fb()).unwrap();
        let b = m(1).targets(&fb()).unwrap();
        let c = m(2).targets(&fb()).unwrap();
        assert_eq!(a, b);
        assert_ne!(a, c);
    }

    #[test]
    fn outside_motions_are_errors() {
        let fb = fb();
        let circle = Motion::Circle {
            centre: None,
            radius: 12.0,
            speed: 10.0,
            duration: 5.0,
            fps: 10.0,
        };
        assert!(matches!(
            circle.plan(&fb),
            Err(SimError::OutsideWorkspace(_))
        ));
        let pts = Motion::Points {
            points: vec![[0.0, 40.0], [0.0, 70.0]],
        };
        let e = pts.plan(&fb).unwrap_err().to_string();
        assert!(e.contains("points[1]"), "{e}");
        assert!(Motion::Mesh { spacing: 0.0 }.plan(&fb).is_err());
        assert!(Motion::Mesh { spacing: f64::NAN }.plan(&fb).is_err());
    }

    #[test]
    fn serde_is_tagged_and_strict() {
        let m: Motion = toml::from_str("kind = \"mesh\"\nspacing = 2.0\n").unwrap();
        assert_eq!(m, Motion::Mesh { spacing: 2.0 });
        assert!(toml::from_str::<Motion>("kind = \"mesh\"\nspacing = 2.0\nspcing = 1\n").is_err());
        let c: Motion = toml::from_str(
            "kind = \"circle\"\nradius = 5.0\nspeed = 10.0\nduration = 1.0\nfps = 30.0\n",
        )
        .unwrap();
        assert!(matches!(c, Motion::Circle { centre: None, .. }));
        let back: Motion = serde_json::from_str(&serde_json::to_string(&c).unwrap()).unwrap();
        assert_eq!(back, c);
    }
}
