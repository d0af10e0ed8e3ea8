//! The simulated rig: a five-bar robot in rapier2d, its motions, and a software camera.
//!
//! This room produces [`Dataset`]s; nothing downstream depends on it. Conventions:
//!
//! - **Coordinates**: the robot's own frame in mm ([`Geometry`]): base pivots at `(∓10, 0)`, `y`
//!   towards the workspace `x ∈ [−9.5, 9.5]`, `y ∈ [38, 57]`. Poses in datasets, `render --x --y`
//!   and motions all use it. Joint angles `θ1` (left), `θ2` (right) in rad from `+x`, CCW.
//! - **Images**: bright robot (grey 220) on a dark background (grey 30) by default, plus mild
//!   Gaussian noise (σ = 2). Pixel `(i, j)` (column, row; rows go down) has its centre at
//!   [`crate::dataset::CameraGeometry::pixel_to_world`]`(i, j)`.
//! - **Ground truth** is read from the simulated bodies after stepping, never from the command.

mod camera;
mod geometry;
mod motion;
mod robot;

pub use camera::{Camera, CameraSettings, NoiseSettings, Part, Primitive, Scene};
pub use geometry::{FiveBar, Geometry, MAX_CONDITION, MIN_SINGULAR_MARGIN_DEG};
pub use motion::{Motion, Plan, Target, TimedPath, MAX_TARGETS};
pub use robot::{Robot, RobotSettings};

use image::GrayImage;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::dataset::{frame_file_name, Dataset, Frame, Manifest, Units, FORMAT_VERSION};

/// Everything that can go wrong in the simulated rig.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SimError {
    /// A setting is out of range.
    #[error("invalid simulator setting: {0}")]
    Settings(String),
    /// The workspace is not fully reachable or passes near a singularity.
    #[error("unusable workspace: {0}")]
    Workspace(String),
    /// A pose cannot be reached by the arms.
    #[error("unreachable pose {0}")]
    Unreachable(String),
    /// A pose lies outside the workspace.
    #[error("pose outside the workspace: {0}")]
    OutsideWorkspace(String),
    /// A NaN or infinite input.
    #[error("non-finite input: {0}; give finite numbers")]
    NotFinite(String),
    /// A motion's parameters are invalid.
    #[error("invalid motion: {0}")]
    Motion(String),
    /// The robot did not settle.
    #[error("robot did not settle: {0}")]
    NotSettled(String),
    /// The physics diverged.
    #[error("physics failure: {0}")]
    Physics(String),
}

/// All settings of the simulated rig.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct SimSettings {
    /// Five-bar geometry and workspace.
    pub geometry: Geometry,
    /// Physics and motors.
    pub robot: RobotSettings,
    /// Camera.
    pub camera: CameraSettings,
    /// Image noise.
    pub noise: NoiseSettings,
}

/// Validated simulator settings.
#[derive(Debug, Clone, PartialEq)]
pub struct Rig {
    /// The validated five-bar.
    pub five_bar: FiveBar,
    /// Physics and motors (checked).
    pub robot: RobotSettings,
    /// The validated camera.
    pub camera: Camera,
    /// Image noise (checked).
    pub noise: NoiseSettings,
}

impl SimSettings {
    /// Validates every part.
    pub fn check(&self) -> Result<Rig, SimError> {
        let five_bar = self.geometry.check()?;
        self.robot.check()?;
        self.noise.check()?;
        let camera = self.camera.check(five_bar.workspace_centre())?;
        Ok(Rig {
            five_bar,
            robot: self.robot.clone(),
            camera,
            noise: self.noise.clone(),
        })
    }
}

/// Runs `motion` on the simulated rig and captures a frame at every node (after settling) or at
/// every frame time (while following). Noise is drawn from `seed`; same inputs → byte-identical
/// frames. `progress(done, total)` is called after each frame.
pub fn simulate(
    settings: &SimSettings,
    motion: &Motion,
    seed: u64,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<Dataset, SimError> {
    let rig = settings.check()?;
    let plan = motion.plan(&rig.five_bar)?;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut frames = Vec::new();
    let mut capture = |robot: &Robot, t: f64, frames: &mut Vec<Frame>| -> Result<(), SimError> {
        let image = rig.camera.render(&robot.scene(), &rig.noise, &mut rng)?;
        frames.push(Frame {
            file: frame_file_name(frames.len()),
            t,
            image,
            truth: Some(robot.truth()),
        });
        Ok(())
    };
    match plan {
        Plan::Nodes(nodes) => {
            let total = nodes.len();
            frames.reserve(total);
            let mut robot = Robot::new_at(&rig.five_bar, &rig.robot, nodes[0][0], nodes[0][1])?;
            for (k, p) in nodes.iter().enumerate() {
                robot.drive_to(p[0], p[1])?;
                capture(&robot, robot.time(), &mut frames)?;
                progress(k + 1, total);
            }
        }
        Plan::Timed(path) => {
            let times = path.frame_times();
            let total = times.len();
            frames.reserve(total);
            let p0 = path.at(0.0);
            let mut robot = Robot::new_at(&rig.five_bar, &rig.robot, p0[0], p0[1])?;
            let at = |t: f64| path.at(t);
            for (k, &t) in times.iter().enumerate() {
                robot.follow(&at, t)?;
                capture(&robot, t, &mut frames)?;
                progress(k + 1, total);
            }
        }
    }
    let source =
        serde_json::json!({ "generator": "evitrack sim", "motion": motion, "settings": settings });
    Ok(Dataset {
        manifest: Manifest {
            format_version: FORMAT_VERSION,
            camera: rig.camera.geometry,
            units: Units::default(),
            workspace: Some(rig.five_bar.workspace()),
            seed: Some(seed),
            scenario: motion.name().to_string(),
            source: source.to_string(),
            frame_count: frames.len(),
        },
        frames,
    })
}

/// Drives the robot from the workspace centre to `(x, y)` (mm, robot frame), lets it settle and
/// renders one frame with noise drawn from `seed`.
pub fn render_pose(
    settings: &SimSettings,
    x: f64,
    y: f64,
    seed: u64,
) -> Result<GrayImage, SimError> {
    let rig = settings.check()?;
    let mut robot = Robot::new(&rig.five_bar, &rig.robot)?;
    robot.drive_to(x, y)?;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rig.camera.render(&robot.scene(), &rig.noise, &mut rng)
}
