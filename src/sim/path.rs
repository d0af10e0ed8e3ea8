//! Timed paths: the validated trajectory a timed motion follows, and the targets it gives.

use std::f64::consts::TAU;

/// One target: time (s; for node motions the node index) and position (mm).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Target {
    /// Time (s) for timed motions, node index for node motions.
    pub t: f64,
    /// x (mm).
    pub x: f64,
    /// y (mm).
    pub y: f64,
}

/// What the robot does for a motion.
#[derive(Debug, Clone, PartialEq)]
pub enum Plan {
    /// Drive to each node, settle, capture.
    Nodes(Vec<[f64; 2]>),
    /// Follow a timed path, capturing at the frame rate.
    Timed(TimedPath),
}

/// The shape of a timed path, with its parameters resolved against the workspace.
#[derive(Debug, Clone, PartialEq)]
pub(super) enum PathKind {
    Lissajous {
        c: [f64; 2],
        amp: [f64; 2],
        freq: [f64; 2],
        phase: f64,
    },
    Circle {
        c: [f64; 2],
        radius: f64,
        omega: f64,
    },
    Spiral {
        c: [f64; 2],
        rate: f64,
        omega: f64,
    },
    Random {
        c: [f64; 2],
        // per axis: (amplitude, angular frequency, phase)
        terms: [Vec<(f64, f64, f64)>; 2],
    },
}

/// A timed, validated path.
#[derive(Debug, Clone, PartialEq)]
pub struct TimedPath {
    kind: PathKind,
    duration: f64,
    fps: f64,
}

impl TimedPath {
    /// A path of `kind` lasting `duration` s, captured at `fps` (both checked by the caller).
    pub(super) fn new(kind: PathKind, duration: f64, fps: f64) -> Self {
        TimedPath {
            kind,
            duration,
            fps,
        }
    }

    /// Position (mm) at time `t` (s).
    pub fn at(&self, t: f64) -> [f64; 2] {
        match &self.kind {
            PathKind::Lissajous {
                c,
                amp,
                freq,
                phase,
            } => [
                c[0] + amp[0] * (TAU * freq[0] * t + phase).sin(),
                c[1] + amp[1] * (TAU * freq[1] * t).sin(),
            ],
            PathKind::Circle { c, radius, omega } => {
                let a = omega * t;
                [c[0] + radius * a.cos(), c[1] + radius * a.sin()]
            }
            PathKind::Spiral { c, rate, omega } => {
                let r = rate * t;
                let a = omega * t;
                [c[0] + r * a.cos(), c[1] + r * a.sin()]
            }
            PathKind::Random { c, terms } => {
                let f = |k: usize| -> f64 {
                    terms[k]
                        .iter()
                        .map(|&(a, w, p)| a * (w * t + p).sin())
                        .sum()
                };
                [c[0] + f(0), c[1] + f(1)]
            }
        }
    }

    /// Duration (s).
    pub fn duration(&self) -> f64 {
        self.duration
    }

    /// Frame rate (frames/s).
    pub fn fps(&self) -> f64 {
        self.fps
    }

    /// Capture times `k / fps` for `k = 0 … ⌊duration·fps⌋ − 1`.
    pub fn frame_times(&self) -> Vec<f64> {
        let n = (self.duration * self.fps + 1e-9).floor() as usize;
        (0..n).map(|k| k as f64 / self.fps).collect()
    }
}
