//! The simulated rig: kinematics against physics, rendering exactness, determinism, errors.

use evitrack::sim::{
    self, CameraSettings, Geometry, Motion, NoiseSettings, Part, Robot, RobotSettings, SimError,
    SimSettings,
};

fn grid(n: usize) -> Vec<[f64; 2]> {
    let w = Geometry::default().workspace;
    let mut out = Vec::new();
    for j in 0..n {
        for i in 0..n {
            out.push([
                w.x_min + (w.x_max - w.x_min) * i as f64 / (n - 1) as f64,
                w.y_min + (w.y_max - w.y_min) * j as f64 / (n - 1) as f64,
            ]);
        }
    }
    out
}

#[test]
fn ik_fk_round_trip_over_workspace() {
    let fb = Geometry::default().check().unwrap();
    for [x, y] in grid(25) {
        let th = fb.inverse(x, y).unwrap();
        let p = fb.forward(th).unwrap();
        assert!(
            (p[0] - x).abs() < 1e-9 && (p[1] - y).abs() < 1e-9,
            "({x}, {y}) -> {p:?}"
        );
    }
}

#[test]
fn settled_end_effector_matches_command_and_forward_kinematics() {
    let fb = Geometry::default().check().unwrap();
    let mut robot = Robot::new(&fb, &RobotSettings::default()).unwrap();
    // corners and a scatter of interior points, in a non-serpentine order (long moves)
    let mut targets = grid(4);
    targets.extend([[0.3, 47.7], [-9.5, 57.0], [9.5, 38.0], [1.25, 50.5]]);
    for [x, y] in targets {
        let t = robot.drive_to(x, y).unwrap();
        let e = (t.x - x).hypot(t.y - y);
        assert!(
            e < 1e-3,
            "commanded ({x}, {y}), simulated ({}, {}), error {e} mm",
            t.x,
            t.y
        );
        let [theta1, theta2] = t.angles.expect("the simulated robot has joint angles");
        let fk = fb.forward([theta1, theta2]).unwrap();
        let e_fk = (fk[0] - t.x).hypot(fk[1] - t.y);
        assert!(
            e_fk < 1e-3,
            "FK of simulated angles off by {e_fk} mm at ({x}, {y})"
        );
        let ik = fb.inverse(x, y).unwrap();
        let e_th = (ik[0] - theta1).abs().max((ik[1] - theta2).abs());
        assert!(
            e_th < 1e-4,
            "simulated angles {:?} vs IK {ik:?}",
            [theta1, theta2]
        );
    }
}

#[test]
fn loop_stays_closed_while_moving() {
    let fb = Geometry::default().check().unwrap();
    let mut robot = Robot::new(&fb, &RobotSettings::default()).unwrap();
    let path = |t: f64| [8.0 * (3.0 * t).sin(), 47.5 + 8.0 * (2.0 * t).sin()];
    let mut worst: f64 = 0.0;
    for k in 1..=40 {
        robot.follow(&path, k as f64 * 0.025).unwrap();
        let ee = robot.end_effector();
        for tip in robot.distal_tips() {
            worst = worst.max((tip[0] - ee[0]).hypot(tip[1] - ee[1]));
        }
    }
    assert!(
        worst < 1e-3,
        "distal tips drift {worst} mm from the end-effector"
    );
}

#[test]
fn following_with_feed_forward_tracks_the_path() {
    let fb = Geometry::default().check().unwrap();
    let path = |t: f64| [6.0 * (2.0 * t).cos(), 47.5 + 6.0 * (2.0 * t).sin()];
    let p0 = path(0.0);
    let mut robot = Robot::new_at(&fb, &RobotSettings::default(), p0[0], p0[1]).unwrap();
    let mut sq = 0.0;
    let n = 50;
    for k in 1..=n {
        let t = k as f64 * 0.02;
        let truth = robot.follow(&path, t).unwrap();
        let p = path(t);
        sq += (truth.x - p[0]).powi(2) + (truth.y - p[1]).powi(2);
    }
    let rms = (sq / n as f64).sqrt();
    // 12 mm/s on a 6 mm circle: feed-forward keeps the lag far below a pixel (0.2 mm)
    assert!(rms < 0.01, "RMS tracking error {rms} mm");
}

#[test]
fn pose_outside_workspace_is_an_error() {
    let fb = Geometry::default().check().unwrap();
    let mut robot = Robot::new(&fb, &RobotSettings::default()).unwrap();
    assert!(matches!(
        robot.drive_to(0.0, 60.0),
        Err(SimError::OutsideWorkspace(_))
    ));
    assert!(matches!(
        robot.drive_to(f64::NAN, 40.0),
        Err(SimError::NotFinite(_))
    ));
    let s = SimSettings::default();
    assert!(sim::render_pose(&s, 12.0, 45.0, 0).is_err());
    assert!(sim::render_pose(&s, 0.0, f64::INFINITY, 0).is_err());
    // the robot is still usable after a refused command
    assert!(robot.drive_to(1.0, 40.0).is_ok());
}

#[test]
fn same_seed_gives_byte_identical_frames() {
    let s = SimSettings::default();
    let m = Motion::SubsampledMesh {
        spacing: 1.0,
        every: 6,
    };
    let a = sim::simulate(&s, &m, 11, &mut |_, _| {}).unwrap();
    let b = sim::simulate(&s, &m, 11, &mut |_, _| {}).unwrap();
    let c = sim::simulate(&s, &m, 12, &mut |_, _| {}).unwrap();
    assert_eq!(a.len(), 16);
    let nodes = m.targets(&Geometry::default().check().unwrap()).unwrap();
    let mut last_t = -1.0;
    for (f, n) in a.frames.iter().zip(&nodes) {
        let tr = f.truth.unwrap();
        assert!((tr.x - n.x).hypot(tr.y - n.y) < 1e-3, "frame off its node");
        assert!(f.t > last_t, "frame times increase");
        last_t = f.t;
    }
    for (fa, fb) in a.frames.iter().zip(&b.frames) {
        assert_eq!(fa.image.as_raw(), fb.image.as_raw());
        assert_eq!(fa.truth, fb.truth);
    }
    assert_ne!(a.frames[0].image.as_raw(), c.frames[0].image.as_raw());
}

#[test]
fn end_effector_centroid_matches_truth_on_noiseless_frame() {
    let s = SimSettings {
        noise: NoiseSettings::none(),
        ..SimSettings::default()
    };
    let rig = s.check().unwrap();
    let mut robot = Robot::new(&rig.five_bar, &rig.robot).unwrap();
    let bg = rig.camera.background;
    let mut rng = <rand_chacha::ChaCha8Rng as rand::SeedableRng>::seed_from_u64(0);
    for [x, y] in [
        [0.0, 47.5],
        [-9.5, 38.0],
        [3.37, 51.13],
        [9.5, 57.0],
        [-4.21, 42.9],
    ] {
        let truth = robot.drive_to(x, y).unwrap();
        let scene = robot.scene().only(Part::EndEffector);
        assert_eq!(scene.parts.len(), 1);
        let img = rig.camera.render(&scene, &rig.noise, &mut rng).unwrap();
        let (mut sw, mut si, mut sj) = (0.0, 0.0, 0.0);
        for (i, j, p) in img.enumerate_pixels() {
            let w = p.0[0] as f64 - bg;
            sw += w;
            si += w * i as f64;
            sj += w * j as f64;
        }
        let expect = rig.camera.geometry.world_to_pixel(truth.x, truth.y);
        let (ci, cj) = (si / sw, sj / sw);
        let err = (ci - expect[0]).hypot(cj - expect[1]);
        assert!(
            err < 0.05,
            "centroid ({ci}, {cj}) vs truth {expect:?}: {err} px"
        );
    }
}

#[test]
fn full_frame_shows_links_and_disc() {
    let s = SimSettings {
        noise: NoiseSettings::none(),
        ..SimSettings::default()
    };
    let img = sim::render_pose(&s, 0.0, 47.5, 0).unwrap();
    assert_eq!(img.dimensions(), (170, 120));
    let fg = img.iter().filter(|&&p| p > 200).count();
    let bg = img.iter().filter(|&&p| p < 40).count();
    assert!(fg > 300 && bg > 10_000, "fg {fg} bg {bg}");
    // the disc centre is bright, a corner is background
    let c = CameraSettings::default()
        .check([0.0, 47.5])
        .unwrap()
        .geometry;
    let p = c.world_to_pixel(0.0, 47.5);
    assert_eq!(
        img.get_pixel(p[0].round() as u32, p[1].round() as u32).0[0],
        220
    );
    assert_eq!(img.get_pixel(0, 0).0[0], 30);
}

#[test]
fn timed_motion_frames_follow_the_path() {
    let s = SimSettings::default();
    let m = Motion::Circle {
        centre: None,
        radius: 5.0,
        speed: 20.0,
        duration: 1.0,
        fps: 20.0,
    };
    let mut calls = 0;
    let d = sim::simulate(&s, &m, 3, &mut |done, total| {
        calls += 1;
        assert_eq!(total, 20);
        assert_eq!(done, calls);
    })
    .unwrap();
    assert_eq!(d.len(), 20);
    let targets = m.targets(&Geometry::default().check().unwrap()).unwrap();
    for (f, t) in d.frames.iter().zip(&targets) {
        assert_eq!(f.t, t.t);
        let tr = f.truth.unwrap();
        assert!(
            (tr.x - t.x).hypot(tr.y - t.y) < 0.02,
            "frame at {} s off the path",
            f.t
        );
    }
}

#[test]
fn bad_settings_are_errors_not_panics() {
    let mut s = SimSettings::default();
    s.camera.width = 0;
    assert!(matches!(
        sim::simulate(&s, &Motion::Mesh { spacing: 1.0 }, 0, &mut |_, _| {}),
        Err(SimError::Settings(_))
    ));
    let mut s = SimSettings::default();
    s.geometry.workspace.x_max = 80.0;
    let e = s.check().unwrap_err().to_string();
    assert!(
        e.contains("corner bottom-right") && e.contains("cannot reach"),
        "{e}"
    );
    let s: Result<SimSettings, _> = toml::from_str("[camera]\nwidht = 3\n");
    assert!(s.is_err());
}
