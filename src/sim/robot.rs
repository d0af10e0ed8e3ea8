//! The five-bar as a rapier2d world: links, loop-closing joints, two position motors.
//!
//! Bodies are placed exactly at the initial pose. The left proximal body is rotated by `θ1 − π`
//! and its link extends along its local `−x`, so both motor angles stay far from the ±π wrap of
//! the joint angle. Ground truth is read from the simulated bodies, never from the command.

use crate::range::within;
use rapier2d::prelude::*;
use serde::{Deserialize, Serialize};

use super::camera::{Part, Primitive, Scene};
use super::geometry::FiveBar;
use super::SimError;
use crate::dataset::Truth;
use std::f64::consts::PI;

/// Physics and motor settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RobotSettings {
    /// Physics time step (s).
    pub dt: f64,
    /// Solver iterations per step.
    pub solver_iterations: usize,
    /// Motor position gain (acceleration-based): overdamped, `stiffness / damping` ≈ 1/time
    /// constant.
    pub stiffness: f64,
    /// Motor damping (acceleration-based).
    pub damping: f64,
    /// Settled when the end-effector is this close to the command (mm)…
    pub settle_tolerance: f64,
    /// …for this many consecutive steps.
    pub settle_steps: usize,
    /// Give up settling after this many steps.
    pub max_settle_steps: usize,
}

impl Default for RobotSettings {
    fn default() -> Self {
        RobotSettings {
            dt: 1e-3,
            solver_iterations: 4,
            stiffness: 1e7,
            damping: 1e5,
            settle_tolerance: 1e-4,
            settle_steps: 3,
            max_settle_steps: 5000,
        }
    }
}

impl RobotSettings {
    /// Checks the settings are usable.
    pub fn check(&self) -> Result<(), SimError> {
        // The time step also sets the cost: ≥ 1e-5 s keeps a frame's settling to ≤ 10⁵ steps.
        let ranges = [
            ("robot.dt", self.dt, 1e-5..=0.01, " s (1e-3 is the default)"),
            ("robot.stiffness", self.stiffness, 1e-3..=1e12, ""),
            ("robot.damping", self.damping, 1e-3..=1e12, ""),
            (
                "robot.settle_tolerance",
                self.settle_tolerance,
                1e-9..=1.0,
                " mm",
            ),
        ];
        for (name, value, range, unit) in ranges {
            within(value, range).map_err(|e| SimError::Settings(format!("{name} = {e}{unit}")))?;
        }
        let counts = [
            ("robot.solver_iterations", self.solver_iterations, 1..=100),
            ("robot.settle_steps", self.settle_steps, 1..=1000),
            ("robot.max_settle_steps", self.max_settle_steps, 1..=100_000),
        ];
        for (name, value, range) in counts {
            within(value, range).map_err(|e| SimError::Settings(format!("{name} = {e}")))?;
        }
        Ok(())
    }
}

/// The simulated five-bar.
pub struct Robot {
    fb: FiveBar,
    settings: RobotSettings,
    world: PhysicsWorld,
    prox: [RigidBodyHandle; 2],
    dist: [RigidBodyHandle; 2],
    ee: RigidBodyHandle,
    motors: [ImpulseJointHandle; 2],
    steps: u64,
}

fn v2(p: [f64; 2]) -> Vector {
    Vector::new(p[0] as f32, p[1] as f32)
}

/// Joint-space motor target for each arm (left is offset by π, see module docs).
fn motor_angles(theta: [f64; 2]) -> [f64; 2] {
    [theta[0] - PI, theta[1]]
}

impl Robot {
    /// Builds the world with the end-effector resting at the workspace centre.
    pub fn new(fb: &FiveBar, settings: &RobotSettings) -> Result<Robot, SimError> {
        let c = fb.workspace_centre();
        Robot::new_at(fb, settings, c[0], c[1])
    }

    /// Builds the world with the end-effector resting exactly at `(x, y)` (mm, in the workspace).
    pub fn new_at(
        fb: &FiveBar,
        settings: &RobotSettings,
        x: f64,
        y: f64,
    ) -> Result<Robot, SimError> {
        settings.check()?;
        check_inside(fb, x, y)?;
        let g = fb.geometry();
        let theta = fb.inverse(x, y)?;
        let [a1, a2] = fb.pivots();
        let [b1, b2] = fb.elbows(theta);
        let p = [x, y];
        let (l1, l2) = (g.proximal as f32, g.distal as f32);
        let r = g.link_radius as f32;

        let mut world = PhysicsWorld {
            gravity: Vector::ZERO,
            ..PhysicsWorld::default()
        };
        world.integration_parameters.dt = settings.dt as f32;
        world.integration_parameters.num_solver_iterations = settings.solver_iterations;

        let none = InteractionGroups::none();
        let link = |a: Vector, b: Vector| {
            ColliderBuilder::capsule_from_endpoints(a, b, r).collision_groups(none)
        };
        let body = |at: [f64; 2], angle: f64| {
            RigidBodyBuilder::dynamic()
                .translation(v2(at))
                .rotation(angle as f32)
                .can_sleep(false)
        };
        let ground = world.insert_body(RigidBodyBuilder::fixed());
        let (prox1, _) = world.insert(
            body(a1, theta[0] - PI),
            link(Vector::ZERO, Vector::new(-l1, 0.0)),
        );
        let (prox2, _) = world.insert(body(a2, theta[1]), link(Vector::ZERO, Vector::new(l1, 0.0)));
        let phi1 = (p[1] - b1[1]).atan2(p[0] - b1[0]);
        let phi2 = (p[1] - b2[1]).atan2(p[0] - b2[0]);
        let (dist1, _) = world.insert(body(b1, phi1), link(Vector::ZERO, Vector::new(l2, 0.0)));
        let (dist2, _) = world.insert(body(b2, phi2), link(Vector::ZERO, Vector::new(l2, 0.0)));
        let (ee, _) = world.insert(
            body(p, 0.0),
            ColliderBuilder::ball(g.end_effector_radius as f32).collision_groups(none),
        );

        let s = settings.stiffness as f32;
        let d = settings.damping as f32;
        let m = motor_angles(theta);
        let hinge = |a1: Vector, a2: Vector| {
            RevoluteJointBuilder::new()
                .local_anchor1(a1)
                .local_anchor2(a2)
                .contacts_enabled(false)
        };
        let m1 = world.insert_impulse_joint(
            ground,
            prox1,
            hinge(v2(a1), Vector::ZERO).motor_position(m[0] as f32, s, d),
        );
        let m2 = world.insert_impulse_joint(
            ground,
            prox2,
            hinge(v2(a2), Vector::ZERO).motor_position(m[1] as f32, s, d),
        );
        world.insert_impulse_joint(prox1, dist1, hinge(Vector::new(-l1, 0.0), Vector::ZERO));
        world.insert_impulse_joint(prox2, dist2, hinge(Vector::new(l1, 0.0), Vector::ZERO));
        world.insert_impulse_joint(dist1, ee, hinge(Vector::new(l2, 0.0), Vector::ZERO));
        world.insert_impulse_joint(dist2, ee, hinge(Vector::new(l2, 0.0), Vector::ZERO));

        Ok(Robot {
            fb: fb.clone(),
            settings: settings.clone(),
            world,
            prox: [prox1, prox2],
            dist: [dist1, dist2],
            ee,
            motors: [m1, m2],
            steps: 0,
        })
    }

    /// The kinematic model.
    pub fn five_bar(&self) -> &FiveBar {
        &self.fb
    }

    /// Simulated time since construction (s).
    pub fn time(&self) -> f64 {
        self.steps as f64 * self.settings.dt
    }

    /// Physics steps taken since construction.
    pub fn steps(&self) -> u64 {
        self.steps
    }

    fn set_motors(&mut self, theta: [f64; 2], omega: [f64; 2]) {
        let m = motor_angles(theta);
        let (s, d) = (self.settings.stiffness as f32, self.settings.damping as f32);
        for k in 0..2 {
            if let Some(j) = self.world.impulse_joints.get_mut(self.motors[k], false) {
                j.data
                    .set_motor(JointAxis::AngX, m[k] as f32, omega[k] as f32, s, d);
            }
        }
    }

    fn step(&mut self) -> Result<(), SimError> {
        self.world.step();
        self.steps += 1;
        let p = self.world.bodies[self.ee].translation();
        if !(p.x.is_finite() && p.y.is_finite()) {
            return Err(SimError::Physics(
                "the simulation diverged (non-finite body position); lower robot.stiffness or \
                 robot.dt"
                    .into(),
            ));
        }
        Ok(())
    }

    /// End-effector position read from its simulated body (mm).
    pub fn end_effector(&self) -> [f64; 2] {
        let p = self.world.bodies[self.ee].translation();
        [p.x as f64, p.y as f64]
    }

    /// Ground truth read from the simulated bodies: end-effector position and motor angles
    /// (`θ1 ∈ (0, 2π]`, `θ2 ∈ (−π, π]`, as returned by [`FiveBar::inverse`]).
    pub fn truth(&self) -> Truth {
        let [x, y] = self.end_effector();
        let r1 = self.world.bodies[self.prox[0]].rotation().angle() as f64;
        let r2 = self.world.bodies[self.prox[1]].rotation().angle() as f64;
        // r1 ∈ (−π, π]: θ1 ∈ (0, 2π], the range of the elbows-out inverse kinematics.
        Truth {
            x,
            y,
            angles: Some([r1 + PI, r2]),
        }
    }

    /// Distal-end positions of both distal links `[left, right]`, read from their bodies (mm):
    /// they coincide with the end-effector when the loop is closed.
    pub fn distal_tips(&self) -> [[f64; 2]; 2] {
        let l2 = self.fb.geometry().distal as f32;
        self.dist.map(|h| {
            let q = self.world.bodies[h]
                .position()
                .transform_point(Vector::new(l2, 0.0));
            [q.x as f64, q.y as f64]
        })
    }

    /// Commands `(x, y)` and steps until the end-effector is within `settle_tolerance` of it for
    /// `settle_steps` consecutive steps. Returns the ground truth at rest.
    pub fn drive_to(&mut self, x: f64, y: f64) -> Result<Truth, SimError> {
        check_inside(&self.fb, x, y)?;
        let theta = self.fb.inverse(x, y)?;
        self.set_motors(theta, [0.0, 0.0]);
        let tol2 = self.settings.settle_tolerance.powi(2);
        let mut run = 0;
        for _ in 0..self.settings.max_settle_steps {
            self.step()?;
            let p = self.end_effector();
            if (p[0] - x).powi(2) + (p[1] - y).powi(2) <= tol2 {
                run += 1;
                if run >= self.settings.settle_steps {
                    return Ok(self.truth());
                }
            } else {
                run = 0;
            }
        }
        let p = self.end_effector();
        Err(SimError::NotSettled(format!(
            "({x}, {y}) mm not reached within {} mm after {} steps (end-effector at ({:.6}, \
             {:.6})); raise robot.max_settle_steps or robot.settle_tolerance",
            self.settings.settle_tolerance, self.settings.max_settle_steps, p[0], p[1]
        )))
    }

    /// Follows the timed path `path(t) -> [x, y]` from the current time up to time `t_end` (s),
    /// commanding at each step the mid-step target with velocity feed-forward. Returns the ground
    /// truth at `t_end`.
    pub fn follow(
        &mut self,
        path: &dyn Fn(f64) -> [f64; 2],
        t_end: f64,
    ) -> Result<Truth, SimError> {
        let dt = self.settings.dt;
        let target_steps = (t_end / dt).round();
        if !target_steps.is_finite() || target_steps < 0.0 {
            return Err(SimError::NotFinite(format!("follow end time {t_end}")));
        }
        let target_steps = target_steps as u64;
        while self.steps < target_steps {
            let t = self.steps as f64 * dt;
            let angles = |t: f64| -> Result<[f64; 2], SimError> {
                let [x, y] = path(t);
                check_inside(&self.fb, x, y)?;
                self.fb.inverse(x, y)
            };
            let a0 = angles(t)?;
            let am = angles(t + dt / 2.0)?;
            let a1 = angles(t + dt)?;
            let omega = [(a1[0] - a0[0]) / dt, (a1[1] - a0[1]) / dt];
            self.set_motors(am, omega);
            self.step()?;
        }
        Ok(self.truth())
    }

    /// The visible shapes, read from the colliders at their simulated poses.
    pub fn scene(&self) -> Scene {
        let mut parts = Vec::with_capacity(5);
        let bodies = [
            (self.prox[0], Part::Proximal),
            (self.prox[1], Part::Proximal),
            (self.dist[0], Part::Distal),
            (self.dist[1], Part::Distal),
            (self.ee, Part::EndEffector),
        ];
        for (h, part) in bodies {
            let body = &self.world.bodies[h];
            for &ch in body.colliders() {
                let col = &self.world.colliders[ch];
                let pose = col.position();
                let tp = |v: Vector| {
                    let q = pose.transform_point(v);
                    [q.x as f64, q.y as f64]
                };
                let shape = col.shape();
                if let Some(c) = shape.as_capsule() {
                    parts.push((
                        part,
                        Primitive::Capsule {
                            a: tp(c.segment.a),
                            b: tp(c.segment.b),
                            radius: c.radius as f64,
                        },
                    ));
                } else if let Some(b) = shape.as_ball() {
                    parts.push((
                        part,
                        Primitive::Disc {
                            centre: tp(Vector::ZERO),
                            radius: b.radius as f64,
                        },
                    ));
                }
            }
        }
        Scene { parts }
    }
}

fn check_inside(fb: &FiveBar, x: f64, y: f64) -> Result<(), SimError> {
    if !(x.is_finite() && y.is_finite()) {
        return Err(SimError::NotFinite(format!("pose ({x}, {y})")));
    }
    if !fb.contains(x, y) {
        let w = fb.workspace();
        return Err(SimError::OutsideWorkspace(format!(
            "({x}, {y}) mm is outside the workspace x ∈ [{}, {}], y ∈ [{}, {}]",
            w.x_min, w.x_max, w.y_min, w.y_max
        )));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::Geometry;

    #[test]
    fn built_at_rest_matches_kinematics() {
        let fb = Geometry::default().check().unwrap();
        let r = Robot::new_at(&fb, &RobotSettings::default(), 3.0, 40.0).unwrap();
        let t = r.truth();
        assert!(
            (t.x - 3.0).abs() < 1e-5 && (t.y - 40.0).abs() < 1e-5,
            "{t:?}"
        );
        let th = fb.inverse(3.0, 40.0).unwrap();
        let [a, b] = t.angles.unwrap();
        assert!((a - th[0]).abs() < 1e-6 && (b - th[1]).abs() < 1e-6);
    }

    #[test]
    fn bad_settings_are_rejected() {
        let fb = Geometry::default().check().unwrap();
        let s = RobotSettings {
            dt: 0.0,
            ..RobotSettings::default()
        };
        assert!(matches!(Robot::new(&fb, &s), Err(SimError::Settings(_))));
    }
}
