//! The selection against the exhaustive enumeration it replaced, on random graphs and levels.

use super::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Levels that only grow as features are added, on a coarse grid so that exact ties are common:
/// a cost per feature and per pair, and +∞ for groups holding a forbidden triple.
struct RandomLevels {
    single: Vec<f64>,
    pair: Vec<Vec<f64>>,
    forbidden: Vec<GroupMask>,
    fallback: Option<usize>,
    calls: usize,
    /// Whether the search may bound groups by their pairs' levels.
    cheap: bool,
}

impl RandomLevels {
    fn new(rng: &mut ChaCha8Rng, n: usize) -> Self {
        let grid = |rng: &mut ChaCha8Rng, top: u32| f64::from(rng.random_range(0..top)) * 0.25;
        let single = (0..n).map(|_| grid(rng, 3)).collect();
        let mut pair = vec![vec![0.0; n]; n];
        for (i, j) in (0..n).flat_map(|i| (i + 1..n).map(move |j| (i, j))) {
            let v = if rng.random_bool(0.15) {
                f64::INFINITY
            } else {
                grid(rng, 6)
            };
            pair[i][j] = v;
            pair[j][i] = v;
        }
        let triples = if n >= 3 { rng.random_range(0..3) } else { 0 };
        let forbidden = (0..triples)
            .map(|_| {
                let mut t: GroupMask = 0;
                while t.count_ones() < 3 {
                    t |= 1 << rng.random_range(0..n);
                }
                t
            })
            .collect();
        Self {
            single,
            pair,
            forbidden,
            fallback: Some(rng.random_range(0..n)),
            calls: 0,
            cheap: rng.random_bool(0.5),
        }
    }

    fn value(&self, group: GroupMask) -> f64 {
        if self.forbidden.iter().any(|&t| t & !group == 0) {
            return f64::INFINITY;
        }
        let m = lex(group);
        let mut k: f64 = m.iter().map(|&i| self.single[i]).sum();
        for (a, &i) in m.iter().enumerate() {
            for &j in &m[a + 1..] {
                k += self.pair[i][j];
            }
        }
        // Rounding noise far below the tie margin, as two paths to one level would leave.
        k + (group % 7) as f64 * 1e-16
    }
}

impl GroupLevels for RandomLevels {
    fn pair_level(&mut self, i: usize, j: usize) -> f64 {
        self.value(1 << i | 1 << j)
    }
    fn group_level(&mut self, group: GroupMask) -> f64 {
        self.calls += 1;
        self.value(group)
    }
    fn fallback_feature(&self) -> Option<usize> {
        self.fallback
    }
    fn cheap_pairs(&self) -> bool {
        self.cheap
    }
}

#[test]
fn every_policy_chooses_as_the_exhaustive_enumeration_on_random_graphs() {
    let mut rng = ChaCha8Rng::seed_from_u64(16);
    let mut outcomes = [0usize; 3]; // several features, one feature, fallback
    for case in 0..20_000 {
        let n = rng.random_range(1..=12);
        let mut levels = RandomLevels::new(&mut rng, n);
        let usable = loop {
            let u: GroupMask = rng.random_range(1..1u64 << n);
            if u != 0 {
                break u;
            }
        };
        let threshold = match rng.random_range(0..3) {
            0 => ConflictLevel::Infinite,
            _ => ConflictLevel::Finite(f64::from(rng.random_range(0..24)) * 0.25),
        };
        let policy = match rng.random_range(0..3) {
            0 => SelectionPolicy::LargestSubset,
            1 => SelectionPolicy::LowestConflict {
                min_size: rng.random_range(1..4),
            },
            _ => SelectionPolicy::Splitting {
                min_size: rng.random_range(1..4),
            },
        };
        let old = choose(&mut levels, n, usable, policy, threshold, true, None);
        let (new, found) = choose(&mut levels, n, usable, policy, threshold, false, None);
        assert_eq!(
            (&new, found),
            (&old.0, old.1),
            "case {case}: n {n}, usable {usable:b}, {policy:?}, {threshold:?}"
        );
        // Keeping the first alternatives only: the same first ones, the same count.
        let keep = rng.random_range(1..4);
        let (kept, kept_found) =
            choose(&mut levels, n, usable, policy, threshold, false, Some(keep));
        assert_eq!(kept.chosen, new.chosen);
        assert_eq!(kept.alternatives[..], new.alternatives[..keep.min(found)]);
        assert_eq!(kept_found, found);
        outcomes[match new.chosen {
            _ if new.fallback => 2,
            Some((_, g)) if g.count_ones() > 1 => 0,
            _ => 1,
        }] += 1;
    }
    // The cases reach every outcome often.
    assert!(outcomes.iter().all(|&c| c > 2000), "{outcomes:?}");
}

#[test]
fn a_complete_graph_of_64_features_costs_one_group_level_under_largest_subset() {
    let mut levels = RandomLevels {
        single: vec![0.25; 64],
        pair: vec![vec![0.0; 64]; 64],
        forbidden: Vec::new(),
        fallback: Some(0),
        calls: 0,
        cheap: false,
    };
    let all = GroupMask::MAX;
    // The selection of every feature under `policy`, threshold ∞, and the group levels it cost.
    let select = |levels: &mut RandomLevels, policy| {
        levels.calls = 0;
        let s = select_group(levels, 64, all, policy, ConflictLevel::Infinite);
        (s, levels.calls)
    };
    let (s, calls) = select(&mut levels, SelectionPolicy::LargestSubset);
    assert_eq!((s.chosen.map(|c| c.1), calls), (Some(all), 1));
    // The splitting policy too: the one maximal clique is eligible, nothing below is searched.
    let (s, calls) = select(&mut levels, SelectionPolicy::Splitting { min_size: 2 });
    assert_eq!((s.alternatives.len(), calls), (1, 1));
    // Lowest conflict with min size 2, every level 0: the 2,016 pairs give the lowest level,
    // then one chain of ties grows it to every feature (62 more groups); nothing else is tried.
    levels.single = vec![0.0; 64];
    let (s, calls) = select(&mut levels, SelectionPolicy::LowestConflict { min_size: 2 });
    assert_eq!((s.chosen.map(|c| c.1), calls), (Some(all), 2016 + 62));
}

/// Levels of `n` features where feature `bad` adds `cost` with every other member (a faulty
/// feature); the others agree (0).
fn one_faulty_feature(n: usize, bad: usize, cost: f64, cheap: bool) -> RandomLevels {
    let mut pair = vec![vec![0.0; n]; n];
    for j in (0..n).filter(|&j| j != bad) {
        pair[bad][j] = cost;
        pair[j][bad] = cost;
    }
    RandomLevels {
        single: vec![0.0; n],
        pair,
        forbidden: Vec::new(),
        fallback: Some(0),
        calls: 0,
        cheap,
    }
}

#[test]
fn one_faulty_feature_among_32_costs_a_few_hundred_levels_under_largest_subset() {
    // Feature 0 with 10 others is at the threshold, with 11 beyond it: the largest eligible
    // group is every other feature. Walking down from the size of the full group, the size
    // bound leaves one missing feature per branch, so each chain holding feature 0 stops
    // after at most 11 members instead of listing the C(31, ≤ 10) eligible groups holding it.
    for cheap in [false, true] {
        let mut levels = one_faulty_feature(32, 0, 0.1, cheap);
        let all: GroupMask = (1 << 32) - 1;
        let threshold = ConflictLevel::Finite(1.0);
        let s = select_group(
            &mut levels,
            32,
            all,
            SelectionPolicy::LargestSubset,
            threshold,
        );
        assert_eq!(s.chosen.map(|c| c.1), Some(all & !1));
        assert!(levels.calls <= 400, "{} group levels", levels.calls);
    }
}

#[test]
fn cheap_pairs_rule_out_the_groups_above_the_lowest_level_before_computing_them() {
    // Every pair holding feature 11 costs 0.5, the others (about) 0: the lowest level is a pair
    // of the others and no group holding feature 11 can reach it. With cheap pairs those groups
    // are never computed.
    let n = 12;
    let all: GroupMask = (1 << n) - 1;
    let policy = SelectionPolicy::LowestConflict { min_size: 2 };
    let mut calls = Vec::new();
    for cheap in [false, true] {
        let mut levels = one_faulty_feature(n, 11, 0.5, cheap);
        let s = select_group(&mut levels, n, all, policy, ConflictLevel::Finite(10.0));
        assert_eq!(s.chosen.map(|c| c.1), Some(all & !(1 << 11)));
        calls.push(levels.calls);
    }
    // With cheap pairs: the 66 pairs, then the chain of ties {0, 1} ⊂ … ⊂ {0, …, 10} (9 groups
    // above the pairs); without, also each link of the chain with feature 11 added.
    assert_eq!(calls[1], 66 + 9, "{calls:?}");
    assert!(calls[1] < calls[0], "{calls:?}");
}

#[test]
fn groups_compare_as_their_ascending_feature_lists() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    for _ in 0..20_000 {
        let bits = rng.random_range(1..=64);
        let mask = |rng: &mut ChaCha8Rng| {
            let m: GroupMask = rng.random();
            if bits == 64 {
                m
            } else {
                m & ((1 << bits) - 1)
            }
        };
        let (a, b) = (mask(&mut rng), mask(&mut rng));
        assert_eq!(lex_cmp(a, b), lex(a).cmp(&lex(b)), "{a:b} {b:b}");
        if a != 0 {
            let prefix = a & !(1 << (63 - a.leading_zeros()));
            assert_eq!(lex_cmp(prefix, a), lex(prefix).cmp(&lex(a)));
        }
    }
}

#[test]
fn maximal_cliques_of_a_triangle_with_a_tail() {
    // Triangle 0-1-2 plus edge 2-3.
    let adj = [0b0110, 0b0101, 0b1011, 0b0100];
    let mut g = maximal_cliques(0b1111, &adj);
    g.sort_unstable();
    assert_eq!(g, vec![0b0111, 0b1100]);
    assert_eq!(
        all_cliques(0b1101, &adj),
        vec![0b0001, 0b0100, 0b1000, 0b0101, 0b1100]
    );
}
