//! The adaptive sample trajectory: refinement where features change fast, the budget, determinism,
//! and the loop driven by the real simulator.

use evitrack::adaptive::{self, AdaptiveOutcome, AdaptiveSettings, StopReason};
use evitrack::sim::{self, SimSettings};

type Rows = Vec<Vec<Option<f64>>>;

/// An `n × n` mesh of spacing `step` (mm), `x` centred on 0, `y` from 38 mm.
fn mesh(n: usize, step: f64) -> Vec<[f64; 2]> {
    let x0 = -step * (n - 1) as f64 / 2.0;
    (0..n)
        .flat_map(|j| (0..n).map(move |i| [x0 + step * i as f64, 38.0 + step * j as f64]))
        .collect()
}

fn step_field(p: [f64; 2]) -> Vec<Option<f64>> {
    vec![Some(((p[0] - 0.3) / 0.2).tanh()), Some(0.02 * p[1])]
}

fn linear_field(p: [f64; 2]) -> Vec<Option<f64>> {
    vec![Some(0.3 * p[0] + 0.1 * p[1]), Some(-p[1])]
}

fn rows(poses: &[[f64; 2]], f: fn([f64; 2]) -> Vec<Option<f64>>) -> Rows {
    poses.iter().map(|&p| f(p)).collect()
}

fn dist(p: [f64; 2], q: [f64; 2]) -> f64 {
    (p[0] - q[0]).hypot(p[1] - q[1])
}

/// Condition 2 checked from scratch (brute-force Gabriel test over all samples): the number of
/// neighbouring pairs where a present feature changes by more than `threshold` × its range.
fn brute_violations(poses: &[[f64; 2]], feats: &Rows, radius: f64, threshold: f64) -> usize {
    let width = feats[0].len();
    let range: Vec<f64> = (0..width)
        .map(|k| {
            let v: Vec<f64> = feats.iter().filter_map(|r| r[k]).collect();
            v.iter().cloned().fold(f64::MIN, f64::max) - v.iter().cloned().fold(f64::MAX, f64::min)
        })
        .collect();
    let mut count = 0;
    for i in 0..poses.len() {
        for j in i + 1..poses.len() {
            let d = dist(poses[i], poses[j]);
            if d > radius {
                continue;
            }
            let mid = [
                (poses[i][0] + poses[j][0]) / 2.0,
                (poses[i][1] + poses[j][1]) / 2.0,
            ];
            if (0..poses.len()).any(|k| k != i && k != j && dist(poses[k], mid) < d / 2.0 - 1e-9) {
                continue;
            }
            let bad = (0..width).any(|k| match (feats[i][k], feats[j][k]) {
                (Some(a), Some(b)) => range[k] > 0.0 && (a - b).abs() > threshold * range[k],
                _ => false,
            });
            count += bad as usize;
        }
    }
    count
}

fn run_step(settings: &AdaptiveSettings) -> (AdaptiveOutcome, Vec<Vec<[f64; 2]>>) {
    let m = mesh(20, 1.0);
    let f = rows(&m, step_field);
    let mut calls = Vec::new();
    let out = adaptive::refine(m, f, settings, |new| {
        calls.push(new.to_vec());
        Ok(rows(new, step_field))
    })
    .expect("refine on a valid mesh");
    (out, calls)
}

#[test]
fn step_field_is_refined_only_near_the_step_until_condition_holds() {
    let s = AdaptiveSettings {
        threshold: 0.25,
        max_samples: 2000,
        max_rounds: 30,
        min_spacing: 0.01,
    };
    let m = mesh(20, 1.0);
    // the unrefined mesh violates the condition (one pair per row across the step)
    assert!(brute_violations(&m, &rows(&m, step_field), 1.01, 0.25) >= 20);
    let (out, calls) = run_step(&s);
    assert_eq!(out.stop, StopReason::Converged);
    assert!((out.neighbour_radius - 1.01).abs() < 1e-12);
    assert_eq!(out.initial_count, 400);
    assert_eq!(&out.poses[..400], &m[..]);
    assert!(out.added().len() >= 20, "added {}", out.added().len());
    // every added point is near the step, inside the mesh; every row (the step does not depend on
    // y) is refined. Refined rows can also make near-diagonal Gabriel pairs between rows, so a
    // few points may fall between rows.
    for p in out.added() {
        assert!((p[0] - 0.3).abs() < 1.0, "added {p:?} far from the step");
        assert!(
            (38.0..=57.0).contains(&p[1]),
            "added {p:?} outside the mesh"
        );
    }
    for row in 0..20 {
        let y = 38.0 + row as f64;
        assert!(
            out.added().iter().any(|p| p[1] == y),
            "row y = {y} was not refined"
        );
    }
    // the condition holds, checked independently
    assert_eq!(brute_violations(&out.poses, &out.features, 1.01, 0.25), 0);
    assert_eq!(out.remaining_violations(), 0);
    // measure was called once per round, with exactly that round's additions
    assert_eq!(calls.len(), out.added_per_round.len());
    for (r, c) in calls.iter().enumerate() {
        assert_eq!(c.as_slice(), out.added_in_round(r));
    }
}

#[test]
fn step_field_budget_stops_refinement_and_is_reported() {
    let s = AdaptiveSettings {
        threshold: 0.25,
        max_samples: 430,
        max_rounds: 30,
        min_spacing: 0.01,
    };
    let (out, _) = run_step(&s);
    assert_eq!(out.stop, StopReason::BudgetSpent);
    assert_eq!(out.poses.len(), 430);
    assert_eq!(out.added().len(), 30);
    assert!(out.remaining_violations() > 0);
    assert_eq!(
        out.remaining_violations(),
        brute_violations(&out.poses, &out.features, 1.01, 0.25)
    );
    // worst first: the remaining violations are sorted by decreasing change
    assert!(out.remaining.windows(2).all(|w| w[0].change >= w[1].change));
}

#[test]
fn budget_is_never_exceeded() {
    for max_samples in [400, 401, 419, 420, 421, 455, 500] {
        let s = AdaptiveSettings {
            threshold: 0.05,
            max_samples,
            max_rounds: 30,
            min_spacing: 0.001,
        };
        let (out, calls) = run_step(&s);
        assert!(out.poses.len() <= max_samples, "{max_samples}");
        assert_eq!(out.features.len(), out.poses.len());
        assert_eq!(
            calls.iter().map(Vec::len).sum::<usize>() + 400,
            out.poses.len()
        );
        if out.stop == StopReason::BudgetSpent {
            assert_eq!(out.poses.len(), max_samples);
        }
    }
}

#[test]
fn smooth_linear_field_adds_nothing() {
    let m = mesh(20, 1.0);
    let f = rows(&m, linear_field);
    let out = adaptive::refine(m.clone(), f.clone(), &AdaptiveSettings::default(), |_| {
        Err("a smooth field must not need new samples".into())
    })
    .expect("refine");
    assert_eq!(out.stop, StopReason::Converged);
    assert_eq!(out.poses, m);
    assert_eq!(out.features, f);
    assert!(out.added().is_empty() && out.added_per_round.is_empty());
    assert_eq!(out.violations_per_round, vec![0]);
}

#[test]
fn refine_is_deterministic() {
    let s = AdaptiveSettings {
        threshold: 0.1,
        max_samples: 470,
        max_rounds: 6,
        min_spacing: 0.02,
    };
    let (a, calls_a) = run_step(&s);
    let (b, calls_b) = run_step(&s);
    assert_eq!(calls_a, calls_b);
    assert_eq!(a, b);
    // bit-identical, not just equal
    assert_eq!(
        serde_json::to_string(&a).expect("serialise"),
        serde_json::to_string(&b).expect("serialise")
    );
}

const SEED: u64 = 11;

/// Toy measurement: the bright-pixel centroid (column, row) of the rendered frame.
fn centroid_features(s: &SimSettings, p: [f64; 2]) -> Result<Vec<Option<f64>>, String> {
    let img = sim::render_pose(s, p[0], p[1], SEED).map_err(|e| e.to_string())?;
    let (mut n, mut sx, mut sy) = (0.0, 0.0, 0.0);
    for (i, j, px) in img.enumerate_pixels() {
        if px.0[0] > 128 {
            n += 1.0;
            sx += i as f64;
            sy += j as f64;
        }
    }
    Ok(if n > 0.0 {
        vec![Some(sx / n), Some(sy / n)]
    } else {
        vec![None, None]
    })
}

#[test]
fn simulator_renders_the_added_poses() {
    let s = SimSettings::default();
    // a coarse 4 mm mesh inside the workspace
    let m: Vec<[f64; 2]> = (0..5)
        .flat_map(|j| (0..5).map(move |i| [-8.0 + 4.0 * i as f64, 39.5 + 4.0 * j as f64]))
        .collect();
    let f: Rows = m
        .iter()
        .map(|&p| centroid_features(&s, p))
        .collect::<Result<_, _>>()
        .expect("render the mesh");
    let settings = AdaptiveSettings {
        threshold: 0.2,
        max_samples: 33,
        max_rounds: 3,
        min_spacing: 0.5,
    };
    let out = adaptive::refine(m.clone(), f, &settings, |new| {
        new.iter().map(|&p| centroid_features(&s, p)).collect()
    })
    .expect("refine with the simulator");
    assert!(
        !out.added().is_empty(),
        "the centroid moves ~25 % of its range per 4 mm step"
    );
    assert!(out.poses.len() <= 33);
    assert!((out.neighbour_radius - 4.04).abs() < 1e-9);
    for (k, &p) in out.added().iter().enumerate() {
        // midpoints of mesh pairs lie on the 2 mm lattice of the mesh
        let (u, v) = ((p[0] + 8.0) / 2.0, (p[1] - 39.5) / 2.0);
        assert!(u == u.round() && v == v.round(), "{p:?} is not a midpoint");
        // the stored row is what a fresh render at that pose gives
        let fresh = centroid_features(&s, p).expect("fresh render");
        assert_eq!(out.features[out.initial_count + k], fresh, "pose {p:?}");
        assert!(fresh.iter().all(Option::is_some));
    }
    // the features of added poses differ from those of every mesh sample: they were rendered there
    for row in &out.features[out.initial_count..] {
        assert!(!out.features[..out.initial_count].contains(row));
    }
}

#[test]
fn errors_say_what_went_wrong() {
    let m = mesh(4, 1.0);
    let f = rows(&m, step_field);
    let e = adaptive::refine(m.clone(), f.clone(), &AdaptiveSettings::default(), |_| {
        Err("camera unplugged".into())
    })
    .expect_err("measure fails");
    let msg = e.to_string();
    assert!(
        msg.contains("camera unplugged") && msg.contains("round 1"),
        "{msg}"
    );
    let e = adaptive::refine(m[..3].to_vec(), f, &AdaptiveSettings::default(), |_| {
        Ok(vec![])
    })
    .expect_err("lengths differ");
    assert!(e.to_string().contains("3 initial poses"), "{e}");
}
