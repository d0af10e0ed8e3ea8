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
mod path;
mod robot;

pub use camera::{Camera, CameraSettings, NoiseSettings, Part, Primitive, Scene};
pub use geometry::{FiveBar, Geometry, MAX_CONDITION, MIN_SINGULAR_MARGIN_DEG};
pub use motion::{Motion, MAX_TARGETS};
pub use path::{Plan, Target, TimedPath};
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
    simulate_on(settings, motion, seed, 1, progress)
}

/// [`simulate`] on up to `threads` threads: with two or more, the frames are rendered on a
/// second thread while the physics steps on to the next pose. The renderer takes the frames in
/// order from the one noise stream, so the dataset is byte-identical whatever `threads`.
pub fn simulate_on(
    settings: &SimSettings,
    motion: &Motion,
    seed: u64,
    threads: usize,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<Dataset, SimError> {
    let rig = settings.check()?;
    let plan = motion.plan(&rig.five_bar)?;
    let total = match &plan {
        Plan::Nodes(nodes) => nodes.len(),
        Plan::Timed(path) => path.frame_times().len(),
    };
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut render = |shot: Shot| -> Result<Frame, SimError> {
        Ok(Frame {
            file: String::new(),
            t: shot.t,
            image: rig.camera.render(&shot.scene, &rig.noise, &mut rng)?,
            truth: Some(shot.truth),
        })
    };
    let mut frames = Vec::with_capacity(total);
    if threads <= 1 {
        drive(&rig, &plan, &mut |shot| {
            frames.push(render(shot)?);
            progress(frames.len(), total);
            Ok(())
        })?;
    } else {
        frames = pipelined(&rig, &plan, &mut render, &mut |done| progress(done, total))?;
    }
    for (k, frame) in frames.iter_mut().enumerate() {
        frame.file = frame_file_name(k);
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

/// What the physics hands the camera: one frame's scene, time and ground truth.
struct Shot {
    scene: Scene,
    t: f64,
    truth: crate::dataset::Truth,
}

/// Steps the robot through `plan`, handing each frame's [`Shot`] to `shot` in order.
fn drive(
    rig: &Rig,
    plan: &Plan,
    shot: &mut dyn FnMut(Shot) -> Result<(), SimError>,
) -> Result<(), SimError> {
    let take = |robot: &Robot, t: f64| Shot {
        scene: robot.scene(),
        t,
        truth: robot.truth(),
    };
    match plan {
        Plan::Nodes(nodes) => {
            let mut robot = Robot::new_at(&rig.five_bar, &rig.robot, nodes[0][0], nodes[0][1])?;
            for p in nodes {
                robot.drive_to(p[0], p[1])?;
                shot(take(&robot, robot.time()))?;
            }
        }
        Plan::Timed(path) => {
            let p0 = path.at(0.0);
            let mut robot = Robot::new_at(&rig.five_bar, &rig.robot, p0[0], p0[1])?;
            let at = |t: f64| path.at(t);
            for t in path.frame_times() {
                robot.follow(&at, t)?;
                shot(take(&robot, t))?;
            }
        }
    }
    Ok(())
}

/// The physics on this thread, the camera on another; `done(n)` after the n-th frame is
/// rendered. Fails as the sequential loop would: with the error of the earlier frame (the
/// physics of frame k comes after the rendering of frame k − 1).
fn pipelined(
    rig: &Rig,
    plan: &Plan,
    render: &mut (dyn FnMut(Shot) -> Result<Frame, SimError> + Send),
    done: &mut dyn FnMut(usize),
) -> Result<Vec<Frame>, SimError> {
    let (shots, shot_rx) = std::sync::mpsc::channel::<Shot>();
    let (rendered, rendered_rx) = std::sync::mpsc::channel::<usize>();
    std::thread::scope(|scope| {
        let camera = scope.spawn(move || {
            let mut frames = Vec::new();
            for shot in shot_rx {
                match render(shot) {
                    Ok(frame) => frames.push(frame),
                    // Frame `frames.len()` failed: dropping the receiver stops the physics.
                    Err(e) => return (frames, Some(e)),
                }
                let _ = rendered.send(frames.len());
            }
            (frames, None)
        });
        let physics = drive(rig, plan, &mut |shot| {
            for n in rendered_rx.try_iter() {
                done(n);
            }
            shots
                .send(shot)
                .map_err(|_| SimError::Physics("the renderer stopped (its error follows)".into()))
        });
        drop(shots);
        for n in rendered_rx.iter() {
            done(n);
        }
        let (frames, render_error) = camera
            .join()
            .unwrap_or_else(|panic| std::panic::resume_unwind(panic));
        // The renderer fails only on a frame the physics made, so its error comes first.
        match render_error {
            Some(e) => Err(e),
            None => physics.map(|()| frames),
        }
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

#[cfg(test)]
mod tests {
    use super::*;

    /// Frames, times and truths, byte for byte, and progress counting 1, 2, …, total.
    fn check_threads_agree(motion: &Motion, seed: u64) {
        let settings = SimSettings::default();
        let one = simulate(&settings, motion, seed, &mut |_, _| {}).unwrap();
        for threads in [2, 3] {
            let mut calls = Vec::new();
            let many = simulate_on(&settings, motion, seed, threads, &mut |done, total| {
                calls.push((done, total))
            })
            .unwrap();
            assert_eq!(many, one, "{threads} threads");
            let total = one.len();
            let expected: Vec<_> = (1..=total).map(|n| (n, total)).collect();
            assert_eq!(calls, expected, "{threads} threads");
        }
    }

    #[test]
    fn rendering_beside_the_physics_gives_the_same_dataset() {
        let nodes = Motion::SubsampledMesh {
            spacing: 1.0,
            every: 25,
        };
        check_threads_agree(&nodes, 4);
        let timed = Motion::Circle {
            centre: None,
            radius: 4.0,
            speed: 20.0,
            duration: 0.5,
            fps: 20.0,
        };
        check_threads_agree(&timed, 5);
    }

    #[test]
    fn a_physics_error_stops_the_pipeline_with_that_error() {
        // Three settled steps needed within one: the robot never settles.
        let mut settings = SimSettings::default();
        settings.robot.settle_steps = 3;
        settings.robot.max_settle_steps = 1;
        let motion = Motion::SubsampledMesh {
            spacing: 1.0,
            every: 100,
        };
        let one = simulate(&settings, &motion, 1, &mut |_, _| {}).map(|d| d.len());
        let two = simulate_on(&settings, &motion, 1, 2, &mut |_, _| {}).map(|d| d.len());
        assert_eq!(format!("{one:?}"), format!("{two:?}"));
        assert!(one.is_err());
    }
}
