//! Unit tests of `adaptive.rs`.
use super::*;
use proptest::prelude::*;

fn mesh(n: usize, step: f64) -> Vec<[f64; 2]> {
    let mut out = Vec::new();
    for j in 0..n {
        for i in 0..n {
            // centred on x = 0 so the step at x = 0.3 lies inside
            let x0 = -step * (n - 1) as f64 / 2.0;
            out.push([x0 + step * i as f64, 38.0 + step * j as f64]);
        }
    }
    out
}

fn field(poses: &[[f64; 2]], f: impl Fn([f64; 2]) -> Vec<Option<f64>>) -> Vec<Vec<Option<f64>>> {
    poses.iter().map(|&p| f(p)).collect()
}

fn step(p: [f64; 2]) -> Vec<Option<f64>> {
    vec![Some(((p[0] - 0.3) / 0.2).tanh()), Some(0.01 * p[1])]
}

#[test]
fn settings_check_rejects_out_of_range() {
    assert!(AdaptiveSettings::default().check().is_ok());
    for t in [0.0, -0.1, 1.5, f64::NAN, f64::INFINITY] {
        let s = AdaptiveSettings {
            threshold: t,
            ..Default::default()
        };
        assert!(matches!(s.check(), Err(AdaptiveError::Settings(_))), "{t}");
    }
    for m in [-1.0, f64::NAN] {
        let s = AdaptiveSettings {
            min_spacing: m,
            ..Default::default()
        };
        assert!(matches!(s.check(), Err(AdaptiveError::Settings(_))), "{m}");
    }
    let s = AdaptiveSettings {
        max_samples: 1,
        ..Default::default()
    };
    assert!(matches!(s.check(), Err(AdaptiveError::Settings(_))));
    let e: Result<AdaptiveSettings, _> = serde_json::from_str(r#"{"treshold": 0.1}"#);
    assert!(e.is_err(), "unknown fields must be rejected");
}

#[test]
fn radius_is_factor_times_mesh_spacing() {
    let r = neighbour_radius(&mesh(5, 2.0)).unwrap();
    assert!((r - 2.0 * NEIGHBOUR_FACTOR).abs() < 1e-12, "{r}");
    assert!(neighbour_radius(&[[0.0, 0.0]]).is_err());
    assert!(neighbour_radius(&[[1.0, 1.0], [1.0, 1.0], [1.0, 1.0], [2.0, 2.0]]).is_err());
}

#[test]
fn mesh_pairs_are_axis_neighbours_and_midpoint_splits_them() {
    let mut m = mesh(4, 1.0);
    let pairs = neighbour_pairs(&m, 1.01);
    // a 4×4 mesh has 2·4·3 = 24 axis pairs and no diagonals
    assert_eq!(pairs.len(), 24);
    assert!(pairs
        .iter()
        .all(|&(a, b)| a < b && (dist(m[a], m[b]) - 1.0).abs() < 1e-12));
    // splitting (0, 1) by its midpoint replaces that pair by two half pairs
    m.push([-1.0, 38.0]);
    let pairs = neighbour_pairs(&m, 1.01);
    assert!(!pairs.contains(&(0, 1)));
    assert!(pairs.contains(&(0, 16)) && pairs.contains(&(1, 16)));
    assert_eq!(pairs.len(), 25);
}

#[test]
fn missing_values_and_constant_features_never_violate() {
    let m = mesh(6, 1.0);
    let s = |p: [f64; 2]| ((p[0] - 0.3) / 0.2).tanh();
    // with both values present the step violates ...
    let full = field(&m, |p| vec![Some(s(p)), Some(5.0)]);
    assert!(!violations(&m, &full, 1.01, 0.01).is_empty());
    // ... but not when every other column misses it (each horizontal pair has a None; vertical
    // pairs share x), although its range stays ≈ 2; the constant never does
    let f = field(&m, |p| {
        let column = (p[0] + 2.5).round() as i64;
        vec![(column % 2 == 0).then_some(s(p)), Some(5.0)]
    });
    assert!(violations(&m, &f, 1.01, 0.01).is_empty());
    // a feature constant up to rounding is constant
    let g = field(&m, |p| vec![Some(1.0 + 1e-14 * p[0])]);
    assert!(violations(&m, &g, 1.01, 0.01).is_empty());
}

#[test]
fn step_field_refines_near_step_and_converges() {
    let m = mesh(20, 1.0);
    let f = field(&m, step);
    let s = AdaptiveSettings {
        threshold: 0.25,
        max_samples: 2000,
        max_rounds: 20,
        min_spacing: 0.01,
    };
    let mut calls = 0;
    let out = refine(m.clone(), f, &s, |new| {
        calls += 1;
        Ok(field(new, step))
    })
    .unwrap();
    assert_eq!(out.stop, StopReason::Converged);
    assert_eq!(calls, out.added_per_round.len());
    assert!(!out.added().is_empty());
    assert!(
        out.added().iter().all(|p| (p[0] - 0.3).abs() < 1.0),
        "{:?}",
        out.added()
    );
    assert!(violations(&out.poses, &out.features, out.neighbour_radius, 0.25).is_empty());
    assert_eq!(
        out.violations_per_round.len(),
        out.added_per_round.len() + 1
    );
    assert_eq!(out.violations_per_round.last(), Some(&0));
}

#[test]
fn spacing_limit_is_reported() {
    let m = mesh(6, 1.0);
    let f = field(&m, step);
    let s = AdaptiveSettings {
        threshold: 0.05,
        max_samples: 1000,
        max_rounds: 50,
        min_spacing: 0.3,
    };
    let out = refine(m, f, &s, |new| Ok(field(new, step))).unwrap();
    assert_eq!(out.stop, StopReason::SpacingLimit);
    assert!(out.remaining_violations() > 0);
    for (i, p) in out.poses.iter().enumerate() {
        for q in &out.poses[i + 1..] {
            assert!(dist(*p, *q) >= 0.3 - 1e-12, "{p:?} {q:?}");
        }
    }
}

#[test]
fn max_rounds_zero_only_evaluates() {
    let m = mesh(6, 1.0);
    let f = field(&m, step);
    let s = AdaptiveSettings {
        max_rounds: 0,
        ..Default::default()
    };
    let out = refine(m.clone(), f, &s, |_| Err("must not be called".into())).unwrap();
    assert_eq!(out.stop, StopReason::MaxRounds);
    assert_eq!(out.poses, m);
    assert!(out.remaining_violations() > 0);
}

#[test]
fn bad_inputs_are_errors() {
    let m = mesh(3, 1.0);
    let f = field(&m, step);
    let s = AdaptiveSettings::default();
    let ok = |new: &[[f64; 2]]| Ok(field(new, step));
    assert!(matches!(
        refine(m.clone(), f[..8].to_vec(), &s, ok),
        Err(AdaptiveError::LengthMismatch(_))
    ));
    let mut bad = m.clone();
    bad[4] = [f64::NAN, 40.0];
    assert!(matches!(
        refine(bad, f.clone(), &s, ok),
        Err(AdaptiveError::NotFinite(_))
    ));
    let mut badf = f.clone();
    badf[2][0] = Some(f64::INFINITY);
    assert!(matches!(
        refine(m.clone(), badf, &s, ok),
        Err(AdaptiveError::NotFinite(_))
    ));
    let mut ragged = f.clone();
    ragged[3].pop();
    assert!(matches!(
        refine(m.clone(), ragged, &s, ok),
        Err(AdaptiveError::LengthMismatch(_))
    ));
    let small = AdaptiveSettings {
        max_samples: 5,
        ..Default::default()
    };
    assert!(matches!(
        refine(m.clone(), f.clone(), &small, ok),
        Err(AdaptiveError::Settings(_))
    ));
    // measure returning the wrong number of rows, or non-finite values
    assert!(matches!(
        refine(m.clone(), f.clone(), &s, |_| Ok(vec![])),
        Err(AdaptiveError::LengthMismatch(_))
    ));
    assert!(matches!(
        refine(m.clone(), f.clone(), &s, |new| Ok(vec![
            vec![
                Some(f64::NAN),
                None
            ];
            new.len()
        ])),
        Err(AdaptiveError::NotFinite(_))
    ));
    match refine(m, f, &s, |_| Err("camera unplugged".into())) {
        Err(AdaptiveError::Measure { round, message, .. }) => {
            assert_eq!(round, 1);
            assert_eq!(message, "camera unplugged");
        }
        other => panic!("expected a measure error, got {other:?}"),
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]
    #[test]
    fn budget_is_never_exceeded_and_bookkeeping_adds_up(
        pts in prop::collection::vec((-10.0f64..10.0, -10.0f64..10.0), 3..40),
        budget_extra in 0usize..30,
        threshold in 0.02f64..0.6,
        min_spacing in 0.0f64..0.5,
        rounds in 0usize..6,
    ) {
        let poses: Vec<[f64; 2]> = pts.iter().map(|&(x, y)| [x, y]).collect();
        let g = |p: [f64; 2]| vec![Some((p[0] * 0.7).sin() + p[1] * 0.05), (p[1] > 0.0).then_some(p[0] * p[1])];
        let f = field(&poses, g);
        let s = AdaptiveSettings { threshold, max_samples: poses.len() + budget_extra, max_rounds: rounds, min_spacing };
        match refine(poses.clone(), f, &s, |new| Ok(field(new, g))) {
            Ok(out) => {
                prop_assert!(out.poses.len() <= s.max_samples);
                prop_assert_eq!(out.poses.len(), out.features.len());
                prop_assert_eq!(&out.poses[..poses.len()], &poses[..]);
                prop_assert_eq!(out.poses.len(), poses.len() + out.added_per_round.iter().sum::<usize>());
                prop_assert!(out.added_per_round.len() <= rounds);
                prop_assert!(out.added_per_round.iter().all(|&n| n > 0));
                for (k, row) in out.added().iter().zip(&out.features[poses.len()..]) {
                    prop_assert_eq!(row, &g(*k));
                }
                prop_assert_eq!(out.stop == StopReason::Converged, out.remaining.is_empty());
                prop_assert!(out.remaining.iter().all(|v| v.change > threshold));
            }
            // random points can coincide mostly; that is the only allowed error
            Err(e) => prop_assert!(matches!(e, AdaptiveError::Initial(_)), "{e}"),
        }
    }
}
