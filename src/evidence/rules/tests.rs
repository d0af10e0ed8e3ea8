//! Every rule against its brute-force definition (`brute.rs`) on random small frames, to 1e-12
//! (divided by 1 − κ for the rules that normalise), including total conflict and dogmatic inputs.

use super::brute::{self, Bf, Map};
use super::*;
use crate::evidence::testutil::random_mass;
use proptest::prelude::*;

const TOL: f64 = 1e-12;

/// Largest absolute difference between two functions, a set missing from one counting as 0.
fn gap(a: &Map, b: &Map) -> f64 {
    a.keys()
        .chain(b.keys())
        .map(|k| (a.get(k).unwrap_or(&0.0) - b.get(k).unwrap_or(&0.0)).abs())
        .fold(0.0, f64::max)
}

fn as_map(m: &MassFunction) -> Map {
    brute::to_bf(m).into_iter().collect()
}

/// `k` random functions on `n` elements; with `clash`, the first two are certain of different
/// singletons (total conflict; needs n ≥ 2).
fn inputs(n: usize, k: usize, seed: u64, clash: bool) -> Vec<MassFunction> {
    let mut fs: Vec<MassFunction> = (0..k)
        .map(|i| random_mass(n, 4, seed.wrapping_add(101 * i as u64)))
        .collect();
    if clash && n >= 2 && k >= 2 {
        fs[0] = MassFunction::new(n, vec![(Subset::singleton(n, 0), 1.0)]).unwrap();
        fs[1] = MassFunction::new(n, vec![(Subset::singleton(n, 1), 1.0)]).unwrap();
    }
    fs
}

/// The level the brute force's κ implies.
fn level(kappa: f64) -> f64 {
    crate::evidence::level_of_conflict(kappa)
}

fn check_level(c: &Combination, kappa: f64) -> Result<(), TestCaseError> {
    prop_assert!(
        (c.conflict_mass - kappa).abs() < TOL,
        "κ {} vs {kappa}",
        c.conflict_mass
    );
    if kappa < 0.999 {
        let want = level(kappa);
        prop_assert!((c.conflict_level - want).abs() < 1e-9 * (1.0 + want));
    } else if kappa >= 1.0 {
        prop_assert_eq!(c.conflict_level, f64::INFINITY);
    }
    Ok(())
}

proptest! {
    #[test]
    fn every_rule_equals_its_brute_force(
        n in 1usize..=12, k in 1usize..=4, seed in any::<u64>(), clash in prop::bool::weighted(0.2)
    ) {
        let fs = inputs(n, k, seed, clash);
        let bf: Vec<Bf> = fs.iter().map(brute::to_bf).collect();
        let full = ((1u32 << n) - 1) as u16;
        let (dempster, kappa) = brute::dempster(&bf);
        let (murphy, murphy_kappa) = brute::murphy(&bf);
        for rule in Rule::ALL {
            if rule == Rule::Cautious {
                continue;
            }
            let c = combine_all(rule, &fs).unwrap();
            let want = match rule {
                Rule::Dempster => dempster.clone(),
                Rule::Conjunctive => Some(brute::conjunctive(&bf)),
                Rule::Yager => Some(brute::yager(&bf, full)),
                Rule::DuboisPrade => Some(brute::dubois_prade(&bf)),
                Rule::Pcr6 => Some(brute::pcr6(&bf)),
                Rule::Disjunctive => Some(brute::disjunctive(&bf)),
                Rule::Murphy => murphy.clone(),
                Rule::Cautious => unreachable!(),
            };
            // Dividing by 1 − κ scales the rounding of the unnormalised masses by 1 / (1 − κ)
            // (a gap of 1.3e-12 at κ = 0.9998 is 2.5e-16 before it).
            let tolerance = match rule {
                Rule::Dempster => TOL / (1.0 - kappa),
                Rule::Murphy => TOL / (1.0 - murphy_kappa),
                _ => TOL,
            };
            match (&c.mass, &want) {
                (Some(m), Some(w)) => {
                    let g = gap(&as_map(m), w);
                    prop_assert!(g < tolerance, "{}: gap {g} (κ {kappa})", rule.name());
                    prop_assert!(m.masses().iter().all(|&x| x > 0.0));
                }
                (None, None) => {}
                _ => prop_assert!(false, "{}: result exists {} vs {}", rule.name(), c.mass.is_some(), want.is_some()),
            }
            if rule == Rule::Murphy {
                check_level(&c, murphy_kappa)?;
            } else {
                check_level(&c, kappa)?;
            }
        }
    }

    #[test]
    fn cautious_equals_its_brute_force(
        n in 1usize..=9, k in 1usize..=3, seed in any::<u64>(), alpha in 0.05f64..0.95
    ) {
        // Discounted so that m(Ω) > 0; one input left alone if it is already non-dogmatic.
        let fs = discount_all(&inputs(n, k, seed, false), &[alpha]).unwrap();
        let bf: Vec<Bf> = fs.iter().map(brute::to_bf).collect();
        let want = brute::cautious(&bf, n);
        let c = combine_all(Rule::Cautious, &fs).unwrap();
        let m = c.mass.as_ref().unwrap();
        prop_assert!(gap(&as_map(m), &want) < TOL, "gap {}", gap(&as_map(m), &want));
        check_level(&c, *want.get(&0).unwrap_or(&0.0))?;
        // Idempotent: a function combined with itself is itself.
        let same = combine_all(Rule::Cautious, [&fs[0], &fs[0]]).unwrap();
        prop_assert!(gap(&as_map(same.mass.as_ref().unwrap()), &as_map(&fs[0])) < TOL);
    }

    #[test]
    fn discounting_is_shafers(n in 1usize..=12, seed in any::<u64>(), alpha in 0.0f64..=1.0) {
        let f = random_mass(n, 4, seed);
        let d = discount_all(std::slice::from_ref(&f), &[alpha]).unwrap();
        let full = ((1u32 << n) - 1) as u16;
        let mut want: Map = brute::to_bf(&f).into_iter().map(|(a, m)| (a, alpha * m)).collect();
        *want.entry(full).or_insert(0.0) += 1.0 - alpha;
        prop_assert!(gap(&as_map(&d[0]), &want) < TOL);
    }
}

#[test]
fn cautious_on_a_frame_of_twelve() {
    let fs = discount_all(&inputs(12, 3, 7, false), &[0.7, 0.8, 0.9]).unwrap();
    let bf: Vec<Bf> = fs.iter().map(brute::to_bf).collect();
    let c = combine_all(Rule::Cautious, &fs).unwrap();
    let g = gap(&as_map(c.mass.as_ref().unwrap()), &brute::cautious(&bf, 12));
    assert!(g < TOL, "{g}");
}

#[test]
fn refusals_are_errors_not_panics() {
    let n = 3;
    let dogmatic = MassFunction::new(n, vec![(Subset::singleton(n, 0), 1.0)]).unwrap();
    let soft = dogmatic.discount(0.5).unwrap();
    assert_eq!(
        combine_all(Rule::Cautious, [&soft, &dogmatic]),
        Err(EvidenceError::Dogmatic { function: 1 })
    );
    let big = MassFunction::vacuous(MAX_CAUTIOUS_FRAME + 1).unwrap();
    assert!(matches!(
        combine_all(Rule::Cautious, [&big]),
        Err(EvidenceError::FrameTooLargeForRule { .. })
    ));
    let open = MassFunction::unnormalised(
        n,
        vec![(Subset::empty(n), 0.5), (Subset::singleton(n, 0), 0.5)],
    )
    .unwrap();
    for rule in [
        Rule::Yager,
        Rule::DuboisPrade,
        Rule::Pcr6,
        Rule::Disjunctive,
    ] {
        assert_eq!(
            combine_all(rule, [&soft, &open]),
            Err(EvidenceError::UnnormalisedInput {
                rule: rule.name(),
                function: 1
            })
        );
    }
    assert!(matches!(
        discount_all(&[soft.clone(), soft.clone()], &[0.5, 0.5, 0.5]),
        Err(EvidenceError::LengthMismatch { .. })
    ));
    assert!(matches!(
        discount_all(&[soft], &[1.5]),
        Err(EvidenceError::InvalidReliability { .. })
    ));
    let limits = WorkLimits {
        tuples: 8,
        ..WorkLimits::DEFAULT
    };
    let fs = inputs(4, 4, 3, false);
    let tuples: usize = fs.iter().map(MassFunction::len).product();
    let pcr6 = combine_all_within(Rule::Pcr6, &fs, &limits);
    assert_eq!(tuples > 8, pcr6.is_err(), "{tuples} tuples");
}

/// Issue 29, item 1: two masses of 1e-200 on {0} and a certain {0}. The product 1e-400 used to
/// underflow and its focal set was dropped, so the third function met nothing: "inf" in one
/// order, 745.13 in another. The exact level is −ln(1e-400) = 921.03 in every order, every rule.
#[test]
fn an_underflowing_product_keeps_its_focal_set_in_every_order() {
    let n = 2;
    let small = MassFunction::new(
        n,
        vec![
            (Subset::singleton(n, 0), 1e-200),
            (Subset::singleton(n, 1), 1.0),
        ],
    )
    .unwrap();
    let certain = MassFunction::new(n, vec![(Subset::singleton(n, 0), 1.0)]).unwrap();
    let want = 400.0 * std::f64::consts::LN_10;
    let orders = [
        [&small, &small, &certain],
        [&small, &certain, &small],
        [&certain, &small, &small],
    ];
    for order in orders {
        for rule in Rule::ALL {
            if matches!(rule, Rule::Cautious | Rule::Murphy | Rule::Disjunctive) {
                continue; // their own levels (below for Murphy), or none to lose
            }
            let c = combine_all(rule, order).unwrap();
            assert!(
                (c.conflict_level - want).abs() < 1e-12 * want,
                "{}: {}",
                rule.name(),
                c.conflict_level
            );
        }
        let d = combine_all(Rule::Dempster, order).unwrap();
        assert_eq!(d.mass.unwrap().contour(), vec![1.0, 0.0]);
    }
    // Many small steps: 1e-200 six times then {0}: K = 1200 ln 10.
    let mut many = vec![&small; 6];
    many.push(&certain);
    let k = crate::evidence::conflict_level_all(many).unwrap();
    assert!(
        (k - 1200.0 * std::f64::consts::LN_10).abs() < 1e-12 * k,
        "{k}"
    );
}

#[test]
fn total_conflict_per_rule() {
    let n = 2;
    let a = MassFunction::new(n, vec![(Subset::singleton(n, 0), 1.0)]).unwrap();
    let b = MassFunction::new(n, vec![(Subset::singleton(n, 1), 1.0)]).unwrap();
    for rule in Rule::ALL {
        if rule == Rule::Cautious {
            continue;
        }
        let c = combine_all(rule, [&a, &b]).unwrap();
        let contour = c.mass.as_ref().map(MassFunction::contour);
        let want = match rule {
            Rule::Dempster => None,
            Rule::Conjunctive => Some(vec![0.0, 0.0]),
            // Murphy: the mean (½, ½) with itself: no conflict.
            Rule::Murphy => Some(vec![0.5, 0.5]),
            Rule::Pcr6 => Some(vec![0.5, 0.5]),
            _ => Some(vec![1.0, 1.0]),
        };
        assert_eq!(contour, want, "{}", rule.name());
        let inf = rule != Rule::Murphy;
        assert_eq!(c.conflict_level.is_infinite(), inf, "{}", rule.name());
    }
}
