//! Unit tests of `combine.rs`.
use super::*;
use crate::evidence::Subset;

fn s(n: usize, v: &[usize]) -> Subset {
    Subset::from_indices(n, v.iter().copied()).unwrap()
}

#[test]
fn dempster_by_hand() {
    // m1: {0}:0.6, {0,1}:0.4 ; m2: {1}:0.5, {0,1,2}:0.5 on 3 elements.
    // Products: {0}∩{1}=∅ 0.3; {0} 0.3; {1} 0.2; {0,1} 0.2. κ = 0.3.
    let m1 = MassFunction::new(3, vec![(s(3, &[0]), 0.6), (s(3, &[0, 1]), 0.4)]).unwrap();
    let m2 = MassFunction::new(3, vec![(s(3, &[1]), 0.5), (Subset::full(3), 0.5)]).unwrap();
    let c = dempster(&m1, &m2).unwrap();
    assert!((c.conflict_mass - 0.3).abs() < 1e-15);
    assert!((c.conflict_level - (1.0f64 / 0.7).ln()).abs() < 1e-15);
    let m = c.mass.unwrap();
    assert_eq!(m.len(), 3);
    assert!((m.belief(&s(3, &[0])) - 0.3 / 0.7).abs() < 1e-15);
    assert!((m.belief(&s(3, &[1])) - 0.2 / 0.7).abs() < 1e-15);
    assert!((m.commonality(&s(3, &[0, 1])) - 0.2 / 0.7).abs() < 1e-15);
    let conj = conjunctive(&m1, &m2).unwrap();
    assert!((conj.empty_mass() - 0.3).abs() < 1e-15);
    assert!((conflict(&m1, &m2).unwrap() - 0.3).abs() < 1e-15);
}

#[test]
fn total_conflict_is_infinite_not_nan() {
    let a = MassFunction::new(2, vec![(s(2, &[0]), 1.0)]).unwrap();
    let b = MassFunction::new(2, vec![(s(2, &[1]), 1.0)]).unwrap();
    let c = dempster(&a, &b).unwrap();
    assert!(c.is_total_conflict());
    assert_eq!(c.conflict_level, f64::INFINITY);
    assert_eq!(c.conflict_mass, 1.0);
    assert_eq!(contour_product([&a, &b]).unwrap(), None);
    let conj = conjunctive(&a, &b).unwrap();
    assert_eq!(conj.empty_mass(), 1.0);
    assert_eq!(level_of_conflict(1.0), f64::INFINITY);
    assert_eq!(level_of_conflict(f64::NAN), f64::INFINITY);
    assert_eq!(level_of_conflict(0.0), 0.0);
}

#[test]
fn errors_on_bad_inputs() {
    let a = MassFunction::vacuous(2).unwrap();
    let b = MassFunction::vacuous(3).unwrap();
    assert!(matches!(
        dempster(&a, &b),
        Err(EvidenceError::FrameMismatch { .. })
    ));
    assert!(matches!(
        dempster_all(std::iter::empty()),
        Err(EvidenceError::NothingToCombine)
    ));
    assert!(conflict(&a, &b).is_err());
}

#[test]
fn large_frames_use_the_dynamic_path() {
    let n = 1000;
    let a = MassFunction::new(n, vec![(s(n, &[1, 999]), 0.5), (s(n, &[5]), 0.5)]).unwrap();
    let b = MassFunction::new(n, vec![(s(n, &[999]), 0.5), (s(n, &[1, 5]), 0.5)]).unwrap();
    let c = dempster(&a, &b).unwrap();
    let m = c.mass.unwrap();
    assert_eq!(m.len(), 3);
    assert!((c.conflict_mass - 0.25).abs() < 1e-15);
    assert!((m.plausibility(&s(n, &[999])) - 1.0 / 3.0).abs() < 1e-15);
}

use crate::evidence::testutil::random_mass;
use proptest::prelude::*;
use std::collections::HashMap;

/// Plain reference: all products through a HashMap, normalised once at the end.
fn reference(fs: &[&MassFunction]) -> (HashMap<Subset, f64>, f64) {
    let n = fs[0].frame_size();
    let mut cur: HashMap<Subset, f64> = fs[0].focal().map(|(s, m)| (s.clone(), m)).collect();
    for f in &fs[1..] {
        let mut next = HashMap::new();
        for (a, ma) in &cur {
            for (b, mb) in f.focal() {
                *next.entry(a.intersection(b)).or_insert(0.0) += ma * mb;
            }
        }
        cur = next;
    }
    let kappa = cur.remove(&Subset::empty(n)).unwrap_or(0.0);
    (cur, kappa)
}

fn as_map(m: &MassFunction) -> HashMap<Subset, f64> {
    m.focal().map(|(s, x)| (s.clone(), x)).collect()
}

fn close_maps(a: &HashMap<Subset, f64>, b: &HashMap<Subset, f64>, tol: f64) -> bool {
    a.len() == b.len()
        && a.iter()
            .all(|(k, v)| b.get(k).is_some_and(|w| (v - w).abs() <= tol))
}

fn frame() -> impl Strategy<Value = usize> {
    prop_oneof![1usize..=70, Just(130), Just(400), Just(600)]
}

proptest! {
    #[test]
    fn dempster_matches_plain_reference(n in frame(), k in 1usize..5, seed in any::<u64>()) {
        let fs: Vec<MassFunction> = (0..k).map(|i| random_mass(n, 4, seed.wrapping_add(i as u64))).collect();
        let refs: Vec<&MassFunction> = fs.iter().collect();
        let (unnorm, kappa) = reference(&refs);
        let c = dempster_all(&fs).unwrap();
        prop_assert!((c.conflict_mass - kappa).abs() < 1e-12);
        prop_assert_eq!(conflict_level_all(&fs).unwrap(), c.conflict_level);
        prop_assert!(!c.conflict_level.is_nan());
        match &c.mass {
            None => prop_assert!(unnorm.is_empty()),
            Some(m) => {
                let norm: HashMap<Subset, f64> = unnorm.iter().map(|(s, x)| (s.clone(), x / (1.0 - kappa))).collect();
                prop_assert!(close_maps(&as_map(m), &norm, 1e-12));
                prop_assert!((m.masses().iter().sum::<f64>() - 1.0).abs() < 1e-12);
                prop_assert!(m.masses().iter().all(|&x| x > 0.0));
            }
        }
        let conj = conjunctive_all(&fs).unwrap();
        prop_assert!((conj.empty_mass() - kappa).abs() < 1e-12);
        prop_assert!((conj.masses().iter().sum::<f64>() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn dempster_is_commutative_and_associative(n in frame(), seed in any::<u64>()) {
        let a = random_mass(n, 3, seed);
        let b = random_mass(n, 3, seed ^ 1);
        let c = random_mass(n, 3, seed ^ 2);
        let ab = dempster(&a, &b).unwrap();
        let ba = dempster(&b, &a).unwrap();
        prop_assert!((ab.conflict_level - ba.conflict_level).abs() < 1e-12 || ab.conflict_level == ba.conflict_level);
        match (&ab.mass, &ba.mass) {
            (Some(x), Some(y)) => prop_assert!(close_maps(&as_map(x), &as_map(y), 1e-12)),
            (None, None) => {}
            _ => prop_assert!(false, "commutativity broke total conflict"),
        }
        let bc = dempster(&b, &c).unwrap();
        let left = ab.mass.as_ref().map(|x| dempster(x, &c).unwrap());
        let right = bc.mass.as_ref().map(|y| dempster(&a, y).unwrap());
        let left = left.and_then(|r| r.mass);
        let right = right.and_then(|r| r.mass);
        match (left, right) {
            (Some(x), Some(y)) => prop_assert!(close_maps(&as_map(&x), &as_map(&y), 1e-12)),
            (None, None) => {}
            _ => prop_assert!(false, "associativity broke total conflict"),
        }
    }

    #[test]
    fn vacuous_is_identity(n in frame(), seed in any::<u64>()) {
        let a = random_mass(n, 4, seed);
        let v = MassFunction::vacuous(n).unwrap();
        let c = dempster(&v, &a).unwrap();
        prop_assert!(c.conflict_level.abs() < 1e-12);
        prop_assert!(close_maps(&as_map(&c.mass.unwrap()), &as_map(&a), 1e-15));
    }

    #[test]
    fn belief_below_plausibility(n in frame(), seed in any::<u64>(), density in 0.0f64..1.0) {
        let a = random_mass(n, 4, seed);
        let probe = random_mass(n, 1, seed ^ 7).focal_sets()[0].clone();
        let probe = if density < 0.1 { Subset::empty(n) } else { probe };
        let bel = a.belief(&probe);
        let pl = a.plausibility(&probe);
        prop_assert!(bel <= pl + 1e-15);
        prop_assert!((a.belief(&probe.complement()) - (1.0 - pl)).abs() < 1e-12);
        prop_assert!(a.commonality(&probe) <= pl + 1e-15 || probe.is_empty());
    }

    #[test]
    fn contour_product_is_relative_plausibility_of_combination(n in frame(), k in 1usize..5, seed in any::<u64>()) {
        let fs: Vec<MassFunction> = (0..k).map(|i| random_mass(n, 4, seed.wrapping_add(31 * i as u64))).collect();
        let fast = contour_product(&fs).unwrap();
        let slow = dempster_all(&fs).unwrap();
        match (fast, slow.mass) {
            (Some(p), Some(m)) => {
                let r = crate::evidence::relative_plausibility(&m).unwrap();
                for (x, y) in p.iter().zip(&r) {
                    prop_assert!((x - y).abs() < 1e-12);
                }
            }
            (None, None) => {}
            (p, m) => prop_assert!(false, "fast path {:?} disagrees with combination {:?}", p.is_some(), m.is_some()),
        }
    }

    #[test]
    fn pairwise_conflict_matches_combination(n in frame(), seed in any::<u64>()) {
        let a = random_mass(n, 4, seed);
        let b = random_mass(n, 4, seed ^ 3);
        let c = dempster(&a, &b).unwrap();
        prop_assert!((conflict(&a, &b).unwrap() - c.conflict_mass).abs() < 1e-12);
        prop_assert!((level_of_conflict(conflict(&a, &b).unwrap()) - c.conflict_level).abs() < 1e-9
            || c.conflict_level.is_infinite());
    }

    #[test]
    fn conflict_level_is_additive_theorem_4_3(n in frame(), k in 2usize..5, seed in any::<u64>()) {
        let fs: Vec<MassFunction> = (0..k).map(|i| random_mass(n, 3, seed.wrapping_add(17 * i as u64))).collect();
        let all = dempster_all(&fs).unwrap();
        let head = dempster_all(&fs[..k - 1]).unwrap();
        match head.mass {
            None => prop_assert_eq!(all.conflict_level, f64::INFINITY),
            Some(h) => {
                let last = dempster(&h, &fs[k - 1]).unwrap();
                let sum = head.conflict_level + last.conflict_level;
                if sum.is_finite() {
                    prop_assert!((all.conflict_level - sum).abs() < 1e-9 * (1.0 + sum));
                } else {
                    prop_assert_eq!(all.conflict_level, f64::INFINITY);
                }
            }
        }
    }
}

/// Issue 15, item 1: a kept mass that is subnormal after one step (1e-310) used to be divided by,
/// giving inf/inf, null masses and plausibilities. The running result is rescaled instead.
#[test]
fn a_subnormal_running_mass_is_rescaled_not_divided_by() {
    let a = MassFunction::new(3, vec![(s(3, &[0]), 1e-310), (s(3, &[1]), 1.0)]).unwrap();
    let b = MassFunction::new(3, vec![(s(3, &[0]), 1.0)]).unwrap();
    let c = dempster_all([&a, &b, &b]).unwrap();
    let m = c.mass.expect("a combination exists");
    assert_eq!(m.len(), 1);
    assert_eq!(m.masses(), &[1.0]);
    assert_eq!(m.contour(), vec![1.0, 0.0, 0.0]);
    // K = −ln(1e-310), whatever the subnormal's lost digits (relative 1e-3).
    assert!((c.conflict_level - 310.0 * std::f64::consts::LN_10).abs() < 1.0);
    assert!(c.conflict_level.is_finite());
}

/// Issue 15, item 2: two masses of 1e-300 on a shared element keep 1e-600, which underflows; the
/// step is redone in log scale instead of reporting total conflict.
#[test]
fn products_that_underflow_are_not_total_conflict() {
    let a = MassFunction::new(3, vec![(s(3, &[0]), 1e-300), (s(3, &[1]), 1.0)]).unwrap();
    let b = MassFunction::new(3, vec![(s(3, &[0]), 1e-300), (s(3, &[2]), 1.0)]).unwrap();
    let c = dempster(&a, &b).unwrap();
    let m = c.mass.expect("not total conflict");
    assert_eq!(m.masses(), &[1.0]);
    assert_eq!(m.contour(), vec![1.0, 0.0, 0.0]);
    let expected = 600.0 * std::f64::consts::LN_10;
    assert!(
        (c.conflict_level - expected).abs() < 1e-9 * expected,
        "{}",
        c.conflict_level
    );
    assert_eq!(
        conflict_level_all([&a, &b]).unwrap().to_bits(),
        c.conflict_level.to_bits()
    );
    // A third function agreeing with the first after the underflow: the level only grows.
    let third = MassFunction::new(3, vec![(s(3, &[0, 1]), 1.0)]).unwrap();
    let k3 = dempster_all([&a, &b, &third]).unwrap().conflict_level;
    assert!((k3 - expected).abs() < 1e-9 * expected);
    // True total conflict stays total.
    let z = MassFunction::new(3, vec![(s(3, &[2]), 1.0)]).unwrap();
    let y = MassFunction::new(3, vec![(s(3, &[1]), 1.0)]).unwrap();
    assert!(dempster(&z, &y).unwrap().is_total_conflict());
}

/// Issue 15, item 3: the conjunctive conflict mass stays in [0, 1] and equals 1 − the kept mass
/// when the conflict is large, over many functions (17 used to give 1.000000000000006).
#[test]
fn conjunctive_conflict_never_exceeds_one() {
    use crate::evidence::testutil::random_mass;
    let mut worst: f64 = 0.0;
    for seed in 0..300u64 {
        let fs: Vec<MassFunction> = (0..17).map(|k| random_mass(6, 3, seed * 17 + k)).collect();
        let m = conjunctive_all(&fs).unwrap();
        let empty = m.empty_mass();
        assert!((0.0..=1.0).contains(&empty), "seed {seed}: {empty}");
        let kept: f64 = m
            .focal()
            .filter(|(x, _)| !x.is_empty())
            .map(|(_, v)| v)
            .sum();
        if empty > 0.5 {
            worst = worst.max((empty + kept - 1.0).abs());
        }
    }
    assert!(worst < 1e-15, "{worst}");
}
