//! The continuous rules: the cautious rule on consonant functions against `evidence::rules`,
//! levels that grow exactly, the sub-grid search against every point, and model files.

use super::super::frame::Frame;
use super::super::Continuous;
use super::discounted_term;
use crate::estimator::test_maps::{
    feature_row, feature_value, fitted_continuous, workspace_points,
};
use crate::estimator::PoseEstimator;
use crate::evidence::{combine_all_within, MassFunction, Rule, Subset, WorkLimits};
use crate::planar::distance;
use crate::track::{members, Combine, Discount, GroupMask};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::collections::HashMap;

const NOISE: f64 = 0.002;

/// The consonant function of contour `pl` (every value > 0, non-dogmatic; mass 1 − max on ∅).
fn consonant(pl: &[f64]) -> MassFunction {
    let n = pl.len();
    let order = ranked(pl);
    let mut focal = vec![(Subset::empty(n), 1.0 - pl[order[0]])];
    for k in 0..n {
        let next = if k + 1 < n { pl[order[k + 1]] } else { 0.0 };
        let set = Subset::from_indices(n, order[..=k].iter().copied()).unwrap();
        focal.push((set, pl[order[k]] - next));
    }
    MassFunction::unnormalised(n, focal).unwrap()
}

/// Elements by decreasing contour (ties by index).
fn ranked(pl: &[f64]) -> Vec<usize> {
    let mut order: Vec<usize> = (0..pl.len()).collect();
    order.sort_by(|&a, &b| pl[b].total_cmp(&pl[a]).then(a.cmp(&b)));
    order
}

/// Brute force from the definition: the weights of each consonant function's canonical
/// decomposition on its chain (∅ weighs its height; the k-th level set pl_(k+1)/pl_(k)),
/// combined by their minimum, and the contour Π_{A ∌ x} w(A).
fn cautious_contour(fs: &[Vec<f64>]) -> Vec<f64> {
    let n = fs[0].len();
    let mut weights: HashMap<Vec<usize>, f64> = HashMap::new();
    for pl in fs {
        let order = ranked(pl);
        let mut put = |mut set: Vec<usize>, w: f64| {
            set.sort_unstable();
            let e = weights.entry(set).or_insert(1.0);
            *e = e.min(w);
        };
        put(Vec::new(), pl[order[0]]);
        for k in 1..n {
            put(order[..k].to_vec(), pl[order[k]] / pl[order[k - 1]]);
        }
    }
    (0..n)
        .map(|x| {
            (weights.iter())
                .filter(|(set, _)| !set.contains(&x))
                .map(|(_, w)| w)
                .product()
        })
        .collect()
}

fn library_cautious(fs: &[Vec<f64>]) -> Vec<f64> {
    let masses: Vec<MassFunction> = fs.iter().map(|pl| consonant(pl)).collect();
    let combined = combine_all_within(Rule::Cautious, &masses, &WorkLimits::DEFAULT).unwrap();
    combined.mass.unwrap().contour()
}

/// Random contours on `n` elements from `levels` distinct values (few levels: shared level sets).
fn random_contours(rng: &mut ChaCha8Rng, n: usize, k: usize, levels: usize) -> Vec<Vec<f64>> {
    let values: Vec<f64> = (0..levels).map(|_| rng.random_range(0.05..=1.0)).collect();
    (0..k)
        .map(|_| {
            let mut pl: Vec<f64> = (0..n)
                .map(|_| values[rng.random_range(0..levels)])
                .collect();
            if rng.random_bool(0.5) {
                let top = pl.iter().copied().fold(0.0, f64::max);
                pl.iter_mut().for_each(|v| *v /= top);
            }
            pl
        })
        .collect()
}

#[test]
fn the_cautious_rule_on_consonant_functions_is_its_definition_and_not_the_minimum() {
    let mut rng = ChaCha8Rng::seed_from_u64(30);
    let mut below_min = 0;
    for round in 0..400 {
        let n = rng.random_range(2..=12);
        let k = rng.random_range(2..=4);
        let fs = random_contours(&mut rng, n, k, if round % 2 == 0 { 3 } else { 40 });
        let library = library_cautious(&fs);
        let brute = cautious_contour(&fs);
        for x in 0..n {
            assert!(
                (library[x] - brute[x]).abs() < 1e-12,
                "{fs:?}: {library:?} {brute:?}"
            );
            let product: f64 = fs.iter().map(|pl| pl[x]).product();
            let min = fs.iter().map(|pl| pl[x]).fold(1.0, f64::min);
            assert!(product - 1e-12 <= library[x] && library[x] <= min + 1e-12);
            if library[x] < min - 1e-6 {
                below_min += 1;
            }
        }
        // Chains sharing only ∅: min of heights × product of normalised contours.
        let chains: Vec<Vec<Vec<usize>>> = (fs.iter())
            .map(|pl| {
                let order = ranked(pl);
                (1..n)
                    .filter(|&j| pl[order[j]] < pl[order[j - 1]])
                    .map(|j| {
                        let mut s = order[..j].to_vec();
                        s.sort_unstable();
                        s
                    })
                    .collect()
            })
            .collect();
        let shared =
            (0..k).any(|a| (a + 1..k).any(|b| chains[a].iter().any(|s| chains[b].contains(s))));
        if !shared {
            let heights: Vec<f64> = fs
                .iter()
                .map(|pl| pl.iter().copied().fold(0.0, f64::max))
                .collect();
            let lowest = heights.iter().copied().fold(1.0, f64::min);
            for x in 0..n {
                let normalised: f64 = fs.iter().zip(&heights).map(|(pl, h)| pl[x] / h).product();
                assert!((library[x] - lowest * normalised).abs() < 1e-12);
            }
        }
    }
    // The minimum of the contours is not the cautious rule's result in general.
    assert!(below_min > 100, "{below_min}");
    let fs = vec![vec![1.0, 0.6, 0.3], vec![0.3, 0.6, 1.0]];
    assert!((library_cautious(&fs)[1] - 0.36).abs() < 1e-12);
    // It is when one function's weights are all below the other's: pl^γ, γ ≥ 1.
    for _ in 0..50 {
        let n = rng.random_range(2..=12);
        let pl: Vec<f64> = (0..n).map(|_| rng.random_range(0.05..=1.0)).collect();
        let gamma = rng.random_range(1.0..3.0);
        let fs = vec![pl.clone(), pl.iter().map(|v| v.powf(gamma)).collect()];
        for (c, m) in library_cautious(&fs).iter().zip(&fs[1]) {
            assert!((c - m).abs() < 1e-12);
        }
    }
}

#[test]
fn the_discounted_term_is_minus_twice_the_log_of_the_discounted_contour() {
    for &a in &[0.1, 0.5, 0.9, 0.999] {
        for &z in &[0.0, 1e-8, 0.3, 1.0, 4.0, 40.0] {
            let (t, slope) = discounted_term(z, a);
            let want = -2.0 * (1.0 - a + a * (-0.5 * z * z).exp()).ln();
            assert!((t - want).abs() <= 1e-12 * (1.0 + want), "{a} {z}");
            let h = 1e-6;
            let numeric = (discounted_term(z + h, a).0 - discounted_term(z - h, a).0) / (2.0 * h);
            assert!(
                (slope - numeric).abs() < 1e-5 * (1.0 + slope.abs()),
                "{a} {z}"
            );
            assert!(t <= -2.0 * (1.0 - a).ln() + 1e-12);
        }
    }
    assert_eq!(discounted_term(3.0, 1.0), (9.0, 6.0));
}

/// The fitted test maps under another rule and discounting (nothing refitted).
fn with_rule(base: &Continuous, rule: Rule, discount: Discount, combine: Combine) -> Continuous {
    let mut file = base.file.clone();
    file.settings.rule = rule;
    file.settings.discount = discount;
    file.settings.combine = combine;
    Continuous::assemble(file, base.surrogate.clone())
}

/// A random pose's features with about a quarter stuck at another pose's value or beyond range.
fn faulty_frame(features: usize, rng: &mut ChaCha8Rng) -> (Vec<Option<f64>>, [f64; 2]) {
    let q = workspace_points(1, rng)[0];
    let mut row = feature_row(features, q, NOISE, rng);
    for (i, v) in row.iter_mut().enumerate() {
        let u: f64 = rng.random();
        if u < 0.15 {
            *v = Some(feature_value(i, workspace_points(1, rng)[0]));
        } else if u < 0.25 {
            *v = v.map(|x| x + 3.0);
        }
    }
    (row, q)
}

fn random_group(usable: GroupMask, rng: &mut ChaCha8Rng) -> GroupMask {
    members(usable)
        .filter(|_| rng.random_bool(0.5))
        .fold(0, |m, i| m | 1 << i)
}

#[test]
fn levels_grow_exactly_and_the_sub_grid_search_finds_every_points_minimum() {
    let base = fitted_continuous(8, 20, 100, NOISE, true, 1);
    let threshold = base.threshold().value();
    let mut rng = ChaCha8Rng::seed_from_u64(31);
    let settings = [
        (Rule::Dempster, Discount::Fixed(0.7)),
        (Rule::Dempster, Discount::Learned),
        (Rule::Cautious, Discount::None),
        (Rule::Cautious, Discount::Fixed(0.5)),
    ];
    for (rule, discount) in settings {
        let model = with_rule(&base, rule, discount, Combine::Selected);
        assert!(!model.fusion.plain());
        for _ in 0..6 {
            let (row, _) = faulty_frame(8, &mut rng);
            let values = model.usable(row);
            let mut exact = Frame::new(&model, values.clone());
            let mut limited = Frame::new(&model, values);
            let usable = exact.usable_mask;
            for _ in 0..8 {
                let group = random_group(usable, &mut rng);
                let Some(j) = members(usable & !group).next() else {
                    continue;
                };
                let (below, above) = (group, group | 1 << j);
                let (a, b) = (
                    exact.grid_level(below, f64::INFINITY).value,
                    exact.grid_level(above, f64::INFINITY).value,
                );
                assert!(
                    b >= a - 1e-9 * (1.0 + a),
                    "{rule:?} {discount:?}: {a} > {b}"
                );
                // With a threshold: exact up to it, beyond it otherwise.
                for (mask, want) in [(below, a), (above, b)] {
                    let got = limited.grid_level(mask, threshold).value;
                    if want <= threshold {
                        assert!((got - want).abs() <= 1e-9 * (1.0 + want), "{got} {want}");
                    } else {
                        assert!(got > threshold, "{got} {threshold}");
                    }
                }
                if rule == Rule::Dempster && group != 0 {
                    // Every sub-grid point of every node.
                    let list = exact.test_members(group).unwrap();
                    let (_, step, nodes, _) = model.surrogate.grid();
                    let mut least = f64::INFINITY;
                    for n in 0..nodes[0] * nodes[1] {
                        for dy in super::SUB {
                            for dx in super::SUB {
                                let offset = [dx * step[0], dy * step[1]];
                                let value =
                                    |stop| exact.sub_grid_value(&list, group, n, offset, stop);
                                let (full, stopped) = (value(f64::INFINITY), value(least));
                                // Stopped at the least so far: the same bits below it, and
                                // never below it otherwise.
                                match full < least {
                                    true => assert_eq!(stopped.to_bits(), full.to_bits()),
                                    false => assert!(stopped >= least, "{stopped} < {least}"),
                                }
                                least = least.min(full);
                            }
                        }
                    }
                    assert_eq!(0.5 * least, a);
                }
            }
        }
    }
}

#[test]
fn discounting_resists_stuck_features_and_the_cautious_rule_keeps_dempsters_estimate() {
    let base = fitted_continuous(8, 20, 100, NOISE, false, 1);
    let all = |rule, discount| with_rule(&base, rule, discount, Combine::All);
    let dempster = all(Rule::Dempster, Discount::None);
    let discounted = all(Rule::Dempster, Discount::Fixed(0.7));
    let cautious = all(Rule::Cautious, Discount::None);
    let same = with_rule(
        &base,
        Rule::Dempster,
        Discount::Fixed(1.0),
        Combine::Selected,
    );
    let mut rng = ChaCha8Rng::seed_from_u64(32);
    let (mut plain_error, mut discounted_error) = (0.0, 0.0);
    for _ in 0..10 {
        let q = workspace_points(1, &mut rng)[0];
        let clean = feature_row(8, q, NOISE, &mut rng);
        // α = 1 is Dempster's path, bit for bit.
        assert_eq!(
            same.estimate(&clean).unwrap(),
            base.estimate(&clean).unwrap()
        );
        let (d, c) = (
            dempster.estimate(&clean).unwrap(),
            cautious.estimate(&clean).unwrap(),
        );
        assert_eq!(d.pose, c.pose);
        assert!(c.conflict_level.unwrap() <= d.conflict_level.unwrap() + 1e-12);
        let mut stuck = clean.clone();
        let elsewhere = workspace_points(1, &mut rng)[0];
        for i in [1, 6] {
            stuck[i] = Some(feature_value(i, elsewhere));
        }
        plain_error += distance(dempster.estimate(&stuck).unwrap().pose.unwrap(), q);
        discounted_error += distance(discounted.estimate(&stuck).unwrap().pose.unwrap(), q);
    }
    assert!(
        discounted_error < 0.5 * plain_error,
        "{discounted_error} vs {plain_error}"
    );
}

#[test]
fn model_files_leave_the_defaults_out_and_keep_a_rule() {
    let base = fitted_continuous(4, 10, 30, NOISE, false, 2);
    let text = base.to_json().unwrap();
    for key in ["\"rule\"", "\"discount\"", "\"combine\""] {
        assert!(!text.contains(key), "{key}");
    }
    // A file without the keys (every file written before them) reads as Dempster's.
    let read = Continuous::from_json(&text).unwrap();
    assert!(read.fusion.plain());
    let cautious = with_rule(&base, Rule::Cautious, Discount::Learned, Combine::All);
    let text = cautious.to_json().unwrap();
    assert!(
        text.contains("\"cautious\"") && text.contains("\"learned\""),
        "{text}"
    );
    let read = Continuous::from_json(&text).unwrap();
    assert_eq!(read.fusion.rule, Rule::Cautious);
    assert_eq!(read.fusion.alpha, cautious.fusion.alpha);
    let row = feature_row(4, [1.0, 45.0], NOISE, &mut ChaCha8Rng::seed_from_u64(3));
    assert_eq!(
        read.estimate(&row).unwrap(),
        cautious.estimate(&row).unwrap()
    );
}
