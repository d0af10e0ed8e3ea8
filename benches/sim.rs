//! Simulated rig: rendering one frame (target ≤ 1 ms median) and driving through the dense mesh
//! (target ≤ 0.5 s for 400 nodes); the render check's mismatch at an estimate, rendered by the
//! simulator or predicted from the 400 sample frames, and learning those frames' silhouettes.

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use evitrack::experiment::RenderCheck;
use evitrack::sim::{Motion, Robot, SimSettings};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use std::hint::black_box;

fn render(c: &mut Criterion) {
    let s = SimSettings::default();
    let rig = s.check().expect("default settings are valid");
    let mut robot = Robot::new(&rig.five_bar, &rig.robot).expect("robot");
    let mut group = c.benchmark_group("render_frame");
    for (name, x, y) in [("centre", 0.0, 47.5), ("corner", -9.5, 38.0)] {
        robot.drive_to(x, y).expect("settles");
        let scene = robot.scene();
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        group.bench_with_input(
            BenchmarkId::new("170x120_noise", name),
            &scene,
            |b, scene| {
                b.iter(|| {
                    black_box(
                        rig.camera
                            .render(scene, &rig.noise, &mut rng)
                            .expect("render"),
                    )
                })
            },
        );
    }
    group.finish();
}

fn drive_mesh(c: &mut Criterion) {
    let s = SimSettings::default();
    let rig = s.check().expect("default settings are valid");
    let mut group = c.benchmark_group("drive_mesh");
    group.sample_size(10);
    for spacing in [2.0, 1.0] {
        let targets = Motion::Mesh { spacing }
            .targets(&rig.five_bar)
            .expect("mesh");
        group.bench_with_input(
            BenchmarkId::from_parameter(targets.len()),
            &targets,
            |b, targets| {
                b.iter(|| {
                    let mut robot =
                        Robot::new_at(&rig.five_bar, &rig.robot, targets[0].x, targets[0].y)
                            .expect("robot");
                    for t in targets {
                        black_box(robot.drive_to(t.x, t.y).expect("settles"));
                    }
                    robot.steps()
                })
            },
        );
    }
    group.finish();
}

fn simulate_mesh(c: &mut Criterion) {
    let s = SimSettings::default();
    let mut group = c.benchmark_group("simulate");
    group.sample_size(10);
    group.bench_function("mesh_400_frames", |b| {
        b.iter(|| {
            evitrack::sim::simulate(&s, &Motion::Mesh { spacing: 1.0 }, 7, &mut |_, _| {})
                .expect("simulate")
        })
    });
    group.finish();
}

fn render_check(c: &mut Criterion) {
    let s = SimSettings::default();
    let sample = evitrack::sim::simulate(&s, &Motion::Mesh { spacing: 1.0 }, 7, &mut |_, _| {})
        .expect("simulate");
    let silhouette = evitrack::features::SilhouetteConfig::default();
    let renderer = RenderCheck::new(&s, &silhouette).expect("default settings are valid");
    let from_samples = (renderer.clone().with_samples(&sample, 2)).expect("400 silhouettes");
    let at = [0.37, 47.08];
    let frame = evitrack::sim::render_pose(&s, at[0], at[1], 3).expect("rendered");
    let observed = renderer.observe(&frame);
    let estimate = Some([at[0] + 0.05, at[1] - 0.05]);
    let mut group = c.benchmark_group("render_check");
    // A frame's silhouette and stray pixels, once per frame for every method.
    group.bench_function("observe", |b| {
        b.iter(|| black_box(renderer.observe(black_box(&frame))))
    });
    group.bench_function("mismatch_simulator", |b| {
        b.iter(|| black_box(renderer.mismatch(&observed, estimate)))
    });
    group.bench_function("mismatch_samples", |b| {
        b.iter(|| black_box(from_samples.mismatch(&observed, estimate)))
    });
    group.sample_size(10);
    group.bench_function("learn_400_sample_silhouettes", |b| {
        b.iter(|| black_box(renderer.clone().with_samples(&sample, 2).is_some()))
    });
    group.finish();
}

criterion_group!(benches, render, drive_mesh, simulate_mesh, render_check);
criterion_main!(benches);
