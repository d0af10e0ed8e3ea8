//! Datasets: grey-level frames with optional ground-truth poses, in memory and on disk.
//!
//! This is the seam between the world and the tracker: the simulator writes datasets, and a user
//! with a real camera can bring one instead. On disk a dataset is a folder holding
//!
//! - `manifest.json` — format version, camera geometry, units, seed, scenario and source;
//! - `poses.csv` — header `file,t,x,y` or `file,t,x,y,theta1,theta2`, one row per frame in order:
//!   the frame's path relative to the folder, its time (s), the end-effector position (mm) and,
//!   optionally, the joint angles (rad). `x, y` may be left empty when the truth is unknown, and
//!   the angles when they are (a real object has none);
//! - the frames themselves, `frames/NNNNN.png` by default (8-bit grey; colour PNGs are converted).
//!
//! Coordinates: positions are in the robot's own frame (mm), the frame of
//! [`crate::sim::Geometry`]: `y` points from the base pivots towards the workspace, which is
//! `x ∈ [−9.5, 9.5]`, `y ∈ [38, 57]` by default. Image pixel `(i, j)` (column, row, rows going
//! down) has its centre at world `x = cx + (i − (W − 1)/2)·s`, `y = cy − (j − (H − 1)/2)·s`
//! (see [`CameraGeometry`]).

mod check;
mod files;
mod init;

pub use check::{check_folder, CheckReport};
pub use init::{init_folder, png_files, InitOptions};

use std::path::{Component, Path, PathBuf};

use image::GrayImage;
use serde::{Deserialize, Serialize};

pub use crate::planar::{check_position, Rect, MAX_COORDINATE_MM};

/// Joint angles beyond ±this (rad) are refused: a five-bar's motors turn less than a turn.
pub const MAX_ANGLE_RAD: f64 = 2.0 * std::f64::consts::PI;

/// The on-disk format version this build writes and reads.
pub const FORMAT_VERSION: u32 = 1;
/// Manifest file name inside a dataset folder.
pub const MANIFEST_FILE: &str = "manifest.json";
/// Pose table file name inside a dataset folder.
pub const POSES_FILE: &str = "poses.csv";

/// Everything that can go wrong reading or writing a dataset.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum DatasetError {
    /// A file could not be read or written.
    #[error("{}: cannot access it (check the path and permissions)", path.display())]
    Io {
        /// The file or folder.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// The manifest is missing, malformed or of another format version.
    #[error("{path}: {message}")]
    Manifest {
        /// The manifest file.
        path: PathBuf,
        /// What is wrong and how to fix it.
        message: String,
    },
    /// A row of `poses.csv` is malformed.
    #[error("{path} line {line}: {message}")]
    Row {
        /// The pose table.
        path: PathBuf,
        /// 1-based line number in the file.
        line: u64,
        /// What is wrong and how to fix it.
        message: String,
    },
    /// A frame listed in `poses.csv` is missing or unreadable.
    #[error("{path} (listed on line {line} of {POSES_FILE}): {message}")]
    Frame {
        /// The frame file.
        path: PathBuf,
        /// The line of `poses.csv` listing it.
        line: u64,
        /// What is wrong and how to fix it.
        message: String,
    },
    /// A folder of frames cannot become a dataset as it is (`init_folder`).
    #[error("{}: {message}", path.display())]
    Folder {
        /// The folder or file concerned.
        path: PathBuf,
        /// What is wrong and how to fix it.
        message: String,
    },
    /// The in-memory dataset is inconsistent and cannot be written.
    #[error("invalid dataset: {0}")]
    Invalid(String),
}

impl Truth {
    /// Why this cannot be a pose of the rig: a position that [`check_position`] refuses, or a
    /// joint angle beyond ±[`MAX_ANGLE_RAD`].
    pub fn check(&self, workspace: Option<&Rect>) -> Result<(), String> {
        check_position([self.x, self.y], workspace)?;
        match self.angles {
            Some([a, b]) if !(a.abs() <= MAX_ANGLE_RAD && b.abs() <= MAX_ANGLE_RAD) => {
                Err(format!("joint angles ({a}, {b}) rad must be within ±2π"))
            }
            _ => Ok(()),
        }
    }
}

/// Which way round the scene is drawn: the features' own type, so a manifest's polarity is the
/// one feature extraction takes.
pub use crate::features::Polarity;

/// A top-down orthographic camera: image size and where it looks.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraGeometry {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Pixel size in mm.
    pub mm_per_px: f64,
    /// World point (mm) at the image centre, `[x, y]`.
    pub centre: [f64; 2],
    /// Foreground/background polarity.
    #[serde(default)]
    pub polarity: Polarity,
}

impl CameraGeometry {
    /// Continuous pixel coordinates `(i, j)` of world point `(x, y)`; pixel centres are integers.
    pub fn world_to_pixel(&self, x: f64, y: f64) -> [f64; 2] {
        [
            (x - self.centre[0]) / self.mm_per_px + (self.width as f64 - 1.0) / 2.0,
            (self.centre[1] - y) / self.mm_per_px + (self.height as f64 - 1.0) / 2.0,
        ]
    }

    /// World point (mm) of continuous pixel coordinates `(i, j)`.
    pub fn pixel_to_world(&self, i: f64, j: f64) -> [f64; 2] {
        [
            self.centre[0] + (i - (self.width as f64 - 1.0) / 2.0) * self.mm_per_px,
            self.centre[1] - (j - (self.height as f64 - 1.0) / 2.0) * self.mm_per_px,
        ]
    }

    fn check(&self) -> Result<(), String> {
        if self.width == 0 || self.height == 0 {
            return Err(format!(
                "camera size {}×{} must be non-zero",
                self.width, self.height
            ));
        }
        if !(self.mm_per_px.is_finite() && self.mm_per_px > 0.0) {
            return Err(format!(
                "camera mm_per_px = {} must be positive and finite",
                self.mm_per_px
            ));
        }
        if !(self.centre[0].is_finite() && self.centre[1].is_finite()) {
            return Err(format!("camera centre {:?} must be finite", self.centre));
        }
        Ok(())
    }
}

/// Units of the numbers in `poses.csv`; written for humans, checked on read.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Units {
    /// Length unit of x, y: always `"mm"`.
    pub length: String,
    /// Angle unit of θ1, θ2: always `"rad"`.
    pub angle: String,
    /// Time unit of t: always `"s"`.
    pub time: String,
}

impl Default for Units {
    fn default() -> Self {
        Units {
            length: "mm".into(),
            angle: "rad".into(),
            time: "s".into(),
        }
    }
}

/// What a dataset is: camera, units, provenance.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    /// On-disk format version; must equal [`FORMAT_VERSION`].
    pub format_version: u32,
    /// Camera geometry of every frame.
    pub camera: CameraGeometry,
    /// Units of `poses.csv`.
    #[serde(default)]
    pub units: Units,
    /// The robot's workspace (mm), when known.
    #[serde(default)]
    pub workspace: Option<Rect>,
    /// Seed of the noise/motion draws, for simulated datasets.
    #[serde(default)]
    pub seed: Option<u64>,
    /// Scenario or motion name.
    #[serde(default)]
    pub scenario: String,
    /// Free-form provenance (simulator settings, rig description…).
    #[serde(default)]
    pub source: String,
    /// Number of frames, checked against `poses.csv`.
    pub frame_count: usize,
}

/// Ground truth of one frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Truth {
    /// End-effector x (mm).
    pub x: f64,
    /// End-effector y (mm).
    pub y: f64,
    /// The motor angles `[θ1, θ2]` (rad, left then right) when known: the simulated five-bar
    /// has them, a real object has none. Nothing downstream needs them (every method estimates
    /// the position `x, y`); they are kept for checks of the kinematics.
    pub angles: Option<[f64; 2]>,
}

/// One frame: image, time, and ground truth if known.
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    /// Path of the PNG relative to the dataset folder, e.g. `frames/00000.png`.
    pub file: String,
    /// Time (s).
    pub t: f64,
    /// The grey-level image.
    pub image: GrayImage,
    /// Ground-truth pose, when known.
    pub truth: Option<Truth>,
}

/// A dataset in memory.
#[derive(Debug, Clone, PartialEq)]
pub struct Dataset {
    /// What the dataset is.
    pub manifest: Manifest,
    /// The frames, in time order.
    pub frames: Vec<Frame>,
}

/// The default relative path of frame `index`.
pub fn frame_file_name(index: usize) -> String {
    format!("frames/{index:05}.png")
}

/// Checks that a frame path is relative and stays inside the dataset folder.
fn safe_relative(file: &str) -> Result<&Path, String> {
    let p = Path::new(file);
    if file.is_empty() {
        return Err("empty frame path".into());
    }
    if p.components().any(|c| !matches!(c, Component::Normal(_))) {
        return Err(format!(
            "frame path {file:?} must be relative to the dataset folder, without `..`"
        ));
    }
    Ok(p)
}

impl Dataset {
    /// Number of frames.
    pub fn len(&self) -> usize {
        self.frames.len()
    }

    /// Whether there are no frames.
    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }

    /// Ground-truth end-effector positions `[x, y]` of every frame, or `None` if any frame has no
    /// truth.
    pub fn truth_positions(&self) -> Option<Vec<[f64; 2]>> {
        self.frames
            .iter()
            .map(|f| f.truth.map(|t| [t.x, t.y]))
            .collect()
    }

    /// The diagonal of the declared workspace, or of the poses' bounding box without one (0
    /// without truth): the largest error an estimate inside it can have.
    pub fn workspace_diagonal(&self) -> f64 {
        match &self.manifest.workspace {
            Some(w) => w.diagonal(),
            None => crate::planar::bounding_diagonal(&self.truth_positions().unwrap_or_default()),
        }
    }

    /// Ground truth of every frame, or `None` if any frame has no truth.
    pub fn truths(&self) -> Option<Vec<Truth>> {
        self.frames.iter().map(|f| f.truth).collect()
    }

    /// The images, in order.
    pub fn images(&self) -> impl Iterator<Item = &GrayImage> {
        self.frames.iter().map(|f| &f.image)
    }

    /// Checks internal consistency: frame count, image sizes, safe unique paths, finite values.
    pub fn validate(&self) -> Result<(), DatasetError> {
        let m = &self.manifest;
        if m.format_version != FORMAT_VERSION {
            return Err(DatasetError::Invalid(format!(
                "format_version {} (this build writes {FORMAT_VERSION})",
                m.format_version
            )));
        }
        m.camera.check().map_err(DatasetError::Invalid)?;
        if m.frame_count != self.frames.len() {
            return Err(DatasetError::Invalid(format!(
                "manifest says {} frames, dataset holds {}",
                m.frame_count,
                self.frames.len()
            )));
        }
        let mut seen = std::collections::HashSet::new();
        for (k, f) in self.frames.iter().enumerate() {
            safe_relative(&f.file).map_err(|e| DatasetError::Invalid(format!("frame {k}: {e}")))?;
            if f.file.contains(',') || f.file.contains('"') || f.file.contains('\n') {
                return Err(DatasetError::Invalid(format!(
                    "frame {k}: path {:?} must not contain commas, quotes or newlines",
                    f.file
                )));
            }
            if !seen.insert(f.file.as_str()) {
                return Err(DatasetError::Invalid(format!(
                    "frame {k}: path {:?} used twice",
                    f.file
                )));
            }
            if f.image.width() != m.camera.width || f.image.height() != m.camera.height {
                return Err(DatasetError::Invalid(format!(
                    "frame {k}: image is {}×{}, camera is {}×{}",
                    f.image.width(),
                    f.image.height(),
                    m.camera.width,
                    m.camera.height
                )));
            }
            if !f.t.is_finite() {
                return Err(DatasetError::Invalid(format!("frame {k}: time {}", f.t)));
            }
            if let Some(t) = f.truth {
                t.check(m.workspace.as_ref())
                    .map_err(|e| DatasetError::Invalid(format!("frame {k}: {e}")))?;
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pixel_world_round_trip() {
        let c = CameraGeometry {
            width: 170,
            height: 120,
            mm_per_px: 0.2,
            centre: [0.0, 47.5],
            polarity: Polarity::BrightOnDark,
        };
        let p = c.world_to_pixel(0.0, 47.5);
        assert_eq!(p, [84.5, 59.5]);
        let q = c.pixel_to_world(10.0, 3.0);
        let r = c.world_to_pixel(q[0], q[1]);
        assert!((r[0] - 10.0).abs() < 1e-12 && (r[1] - 3.0).abs() < 1e-12);
        // rows go down: larger y is a smaller row index
        assert!(c.world_to_pixel(0.0, 50.0)[1] < p[1]);
    }

    #[test]
    fn unsafe_paths_are_rejected() {
        assert!(safe_relative("../x.png").is_err());
        assert!(safe_relative("/abs.png").is_err());
        assert!(safe_relative("").is_err());
        assert!(safe_relative("frames/00001.png").is_ok());
    }
}
