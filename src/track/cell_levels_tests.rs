//! The pruned selection on the paper tracker's own levels (pairs from their state tuples, groups
//! grown one feature at a time) against the exhaustive enumeration, on random frames with stuck
//! and outlying features.

use super::super::cell_products::{CellProducts, MAX_LEFT_OUT};
use super::super::group_search::{present_mask, select_group_exhaustive, select_group_keeping};
use super::*;
use crate::evidence::{ConflictLevel, Refining};
use crate::track::{
    FrameEstimate, SelectionPolicy, TrackSettings, TrackedFeature, TrackerModel, MAX_ALTERNATIVES,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::collections::HashMap;

/// A linear feature: its direction, the lower end of its bins, their width, its state count.
type Spec = ([f64; 2], f64, f64, usize);

/// A feature that cuts the projection of the pose on `coef` into `states` equal bins (half a
/// unit of margin at each end): the feature, its lowest value and its bin width.
fn projection_feature(
    poses: &[[f64; 2]],
    coef: [f64; 2],
    states: usize,
) -> (TrackedFeature, f64, f64) {
    let values: Vec<f64> = poses
        .iter()
        .map(|p| coef[0] * p[0] + coef[1] * p[1])
        .collect();
    let lo = values.iter().copied().fold(f64::INFINITY, f64::min) - 0.5;
    let hi = values.iter().copied().fold(f64::NEG_INFINITY, f64::max) + 0.5;
    let w = (hi - lo) / states as f64;
    let assignment: Vec<usize> = values
        .iter()
        .map(|v| (((v - lo) / w).floor() as usize).min(states - 1))
        .collect();
    let feature = TrackedFeature {
        refining: Refining::from_assignment(states, &assignment).unwrap(),
        validation_error: None,
    };
    (feature, lo, w)
}

/// A tracker over the 12 × 12 mesh of the 11 mm square with `n` linear features of random
/// direction and 2–4 states, and the features' directions and bins.
fn random_tracker(
    rng: &mut ChaCha8Rng,
    n: usize,
    constructor: Constructor,
) -> (Tracker, Vec<Spec>) {
    let poses: Vec<[f64; 2]> = (0..144)
        .map(|q| [f64::from(q % 12), f64::from(q / 12)])
        .collect();
    let mut features = Vec::new();
    let mut specs = Vec::new();
    for _ in 0..n {
        let a: f64 = rng.random_range(0.0..std::f64::consts::PI);
        let coef = [a.cos(), a.sin()];
        let states = rng.random_range(2..=4);
        let (feature, lo, w) = projection_feature(&poses, coef, states);
        features.push(feature);
        specs.push((coef, lo, w, states));
    }
    let model = TrackerModel::new(poses, features).unwrap();
    let settings = TrackSettings {
        constructor,
        ..TrackSettings::default()
    };
    (
        Tracker::new(model, settings.check().unwrap()).unwrap(),
        specs,
    )
}

/// One frame at a random pose: each feature's likelihoods of its states, some features stuck
/// on one state whatever the pose, some reporting a pose 6 mm away.
fn random_frame(rng: &mut ChaCha8Rng, specs: &[Spec]) -> Vec<Option<Vec<f64>>> {
    let p = [rng.random_range(0.0..11.0), rng.random_range(0.0..11.0)];
    let far = [if p[0] < 5.5 { p[0] + 6.0 } else { p[0] - 6.0 }, p[1]];
    specs
        .iter()
        .map(|&(coef, lo, w, states)| {
            let kind = rng.random_range(0..8);
            if kind == 0 {
                let stuck = rng.random_range(0..states);
                return Some(
                    (0..states)
                        .map(|s| if s == stuck { 1.0 } else { 0.02 })
                        .collect(),
                );
            }
            let q = if kind == 1 { far } else { p };
            let v = coef[0] * q[0] + coef[1] * q[1] + rng.random_range(-0.2 * w..0.2 * w);
            Some(
                (0..states)
                    .map(|s| {
                        let c = lo + (s as f64 + 0.5) * w;
                        (-(v - c).powi(2) / (0.5 * w * w)).exp()
                    })
                    .collect(),
            )
        })
        .collect()
}

#[test]
fn the_pruned_selection_equals_the_exhaustive_one_on_random_frames_with_faulty_features() {
    let mut rng = ChaCha8Rng::seed_from_u64(32);
    let policies = [
        SelectionPolicy::LargestSubset,
        SelectionPolicy::LowestConflict { min_size: 1 },
        SelectionPolicy::LowestConflict { min_size: 2 },
        SelectionPolicy::LowestConflict { min_size: 3 },
        SelectionPolicy::Splitting { min_size: 1 },
        SelectionPolicy::Splitting { min_size: 2 },
        SelectionPolicy::Splitting { min_size: 3 },
    ];
    // Chosen groups that left features out, and splits into several alternatives.
    let (mut partial, mut split) = (0, 0);
    for constructor in [Constructor::Bayesian, Constructor::Consonant] {
        for _model in 0..10 {
            let top = if constructor == Constructor::Bayesian {
                12
            } else {
                9
            };
            let n = rng.random_range(4..=top);
            let (tracker, specs) = random_tracker(&mut rng, n, constructor);
            for _frame in 0..6 {
                let lik = random_frame(&mut rng, &specs);
                let (usable, _) = tracker.measure(&lik).unwrap();
                let all = present_mask(&usable);
                let full = tracker.raw_level(all, &usable);
                // Thresholds around the frame's own full level, so that some groups pass.
                let thresholds = [0.3, 0.6, 0.9, 1.1].map(|f| ConflictLevel::from_value(f * full));
                for threshold in thresholds.into_iter().chain([ConflictLevel::Infinite]) {
                    for policy in policies {
                        let mut levels = tracker.cell_levels(&usable);
                        let pruned = select_group(&mut levels, n, all, policy, threshold);
                        let mut levels = tracker.cell_levels(&usable);
                        let every = select_group_exhaustive(&mut levels, n, all, policy, threshold);
                        assert_eq!(
                            pruned, every,
                            "{constructor:?} n {n} {policy:?} {threshold:?}"
                        );
                        let chosen = pruned.chosen.map_or(0, |c| c.1);
                        partial += usize::from(chosen != all && chosen.count_ones() > 1);
                        split += usize::from(pruned.alternatives.len() > 1);
                    }
                }
            }
        }
    }
    assert!(
        partial > 100 && split > 20,
        "partial {partial}, split {split}"
    );
}

#[test]
fn floors_without_one_feature_never_exceed_the_levels_they_bound() {
    let mut rng = ChaCha8Rng::seed_from_u64(33);
    let (mut checked, mut positive) = (0, 0);
    for _model in 0..10 {
        let n = rng.random_range(4..=12);
        let (tracker, specs) = random_tracker(&mut rng, n, Constructor::Bayesian);
        for _frame in 0..6 {
            let lik = random_frame(&mut rng, &specs);
            let (usable, _) = tracker.measure(&lik).unwrap();
            let all = present_mask(&usable);
            let floors = tracker
                .cell_levels(&usable)
                .floors_without_one(all)
                .unwrap();
            assert_eq!(floors.len(), all.count_ones() as usize);
            for (i, floor) in members(all).zip(floors) {
                let exact = tracker.raw_level(all & !(1 << i), &usable);
                assert!(
                    floor <= exact + 1e-12 * (1.0 + exact.abs()),
                    "n {n} without {i}: floor {floor} above level {exact}"
                );
                checked += 1;
                positive += usize::from(floor > 0.0);
            }
        }
    }
    assert!(
        checked > 200 && positive > checked / 4,
        "{positive} of {checked}"
    );
    // Consonant levels give no floors: the search walks instead.
    let (tracker, specs) = random_tracker(&mut rng, 5, Constructor::Consonant);
    let (usable, _) = tracker.measure(&random_frame(&mut rng, &specs)).unwrap();
    assert!(tracker
        .cell_levels(&usable)
        .floors_without_one(31)
        .is_none());
}

/// The bench's 10,000 × 32 frame scaled down: `n` linear features of 3 states with directions
/// spread over a half turn on the `side` × `side` mesh of the 19 mm square, at a random pose;
/// the features in `corrupt` report a pose 8 mm away in x. The tracker, and the frame's
/// likelihoods clean and corrupted.
fn bench_shaped(
    rng: &mut ChaCha8Rng,
    n: usize,
    side: usize,
    corrupt: &[usize],
) -> (Tracker, [Vec<Option<Vec<f64>>>; 2]) {
    let step = 19.0 / (side - 1) as f64;
    let poses: Vec<[f64; 2]> = (0..side * side)
        .map(|q| [(q % side) as f64 * step, (q / side) as f64 * step])
        .collect();
    let mut features = Vec::new();
    let mut specs = Vec::new();
    for i in 0..n {
        let a = (i as f64 * 180.0 / n as f64).to_radians();
        let coef = [a.cos(), a.sin()];
        let (feature, lo, w) = projection_feature(&poses, coef, 3);
        features.push(feature);
        specs.push((coef, lo, w));
    }
    let model = TrackerModel::new(poses, features).unwrap();
    let tracker = Tracker::new(model, TrackSettings::default().check().unwrap()).unwrap();
    let p = [rng.random_range(0.0..19.0), rng.random_range(0.0..19.0)];
    let shifted = [if p[0] < 11.0 { p[0] + 8.0 } else { p[0] - 8.0 }, p[1]];
    let frame = |faulty: &[usize]| {
        (specs.iter().enumerate())
            .map(|(i, &(coef, lo, w))| {
                let q = if faulty.contains(&i) { shifted } else { p };
                let v = coef[0] * q[0] + coef[1] * q[1];
                Some(
                    (0..3)
                        .map(|s| (-(v - (lo + (s as f64 + 0.5) * w)).powi(2) / (0.5 * w * w)).exp())
                        .collect(),
                )
            })
            .collect()
    };
    (tracker, [frame(&[]), frame(corrupt)])
}

#[test]
fn splitting_the_bench_frame_scaled_down_equals_the_exhaustive_selection() {
    let mut rng = ChaCha8Rng::seed_from_u64(34);
    let mut split = 0;
    for (n, side, corrupt) in [(14, 30, [0, 7]), (12, 40, [0, 6]), (13, 25, [0, 3])] {
        for _frame in 0..3 {
            let (tracker, [clean, faulty]) = bench_shaped(&mut rng, n, side, &corrupt);
            let (usable, _) = tracker.measure(&clean).unwrap();
            let all = present_mask(&usable);
            let level = tracker.raw_level(all, &usable);
            let (usable, _) = tracker.measure(&faulty).unwrap();
            let mut kept = Kept {
                inner: tracker.cell_levels(&usable),
                levels: HashMap::new(),
            };
            for factor in [1.05, 1.5, 3.0] {
                let threshold = ConflictLevel::from_value(factor * level);
                for min_size in [2, 4] {
                    let policy = SelectionPolicy::Splitting { min_size };
                    let mut levels = tracker.cell_levels(&usable);
                    let pruned = select_group(&mut levels, n, all, policy, threshold);
                    let every = select_group_exhaustive(&mut kept, n, all, policy, threshold);
                    assert_eq!(pruned, every, "n {n} side {side} ×{factor} min {min_size}");
                    split += usize::from(pruned.alternatives.len() > 5);
                }
            }
        }
    }
    // Most frames split into many alternatives, as the bench's does.
    assert!(
        split > 20,
        "{split} selections with more than 5 alternatives"
    );
}

/// Counts the group levels the selection asks for.
struct Counting<'a> {
    inner: CellLevels<'a>,
    calls: usize,
}

impl GroupLevels for Counting<'_> {
    fn pair_level(&mut self, i: usize, j: usize) -> f64 {
        self.inner.pair_level(i, j)
    }
    fn group_level(&mut self, group: GroupMask) -> f64 {
        self.calls += 1;
        self.inner.group_level(group)
    }
    fn fallback_feature(&self) -> Option<usize> {
        self.inner.fallback_feature()
    }
    fn cheap_pairs(&self) -> bool {
        self.inner.cheap_pairs()
    }
    fn floors_without_one(&mut self, group: GroupMask) -> Option<Vec<f64>> {
        self.inner.floors_without_one(group)
    }
}

#[test]
fn splitting_the_bench_frame_looks_ahead_instead_of_listing_the_eligible_groups() {
    // The bench's frame with 24 features on a 60 × 60 mesh: feature 0 reports a pose 8 mm
    // away, so the maximal eligible groups holding it are many, each with many eligible
    // groups inside it that the search never computes.
    let mut rng = ChaCha8Rng::seed_from_u64(2026);
    let (tracker, [clean, faulty]) = bench_shaped(&mut rng, 24, 60, &[0, 12]);
    let (usable, _) = tracker.measure(&clean).unwrap();
    let all = present_mask(&usable);
    let level = tracker.raw_level(all, &usable);
    let (usable, _) = tracker.measure(&faulty).unwrap();
    let threshold = ConflictLevel::from_value(1.05 * level);
    let mut levels = Counting {
        inner: tracker.cell_levels(&usable),
        calls: 0,
    };
    let policy = SelectionPolicy::Splitting { min_size: 2 };
    let s = select_group(&mut levels, 24, all, policy, threshold);
    let alternatives = s.alternatives.len();
    println!("{alternatives} alternatives, {} levels", levels.calls);
    assert!(alternatives > 50, "{alternatives} alternatives");
    assert!(
        levels.calls < 6 * alternatives,
        "{} levels for {alternatives} alternatives",
        levels.calls
    );
}

#[test]
fn a_capped_frame_keeps_the_uncapped_frames_first_alternatives_and_counts_them_all() {
    // The bench's frame scaled down, split into many alternatives of several sizes.
    let mut rng = ChaCha8Rng::seed_from_u64(35);
    let (base, [clean, faulty]) = bench_shaped(&mut rng, 14, 30, &[0, 7]);
    let level = base.full_conflict_level(&clean).unwrap();
    let tracker = |cap: usize| {
        let settings = TrackSettings {
            conflict_threshold: ConflictLevel::from_value(1.05 * level),
            selection: SelectionPolicy::Splitting { min_size: 2 },
            max_alternatives: cap,
            ..TrackSettings::default()
        };
        Tracker::new(base.model().clone(), settings.check().unwrap()).unwrap()
    };
    let all = tracker(MAX_ALTERNATIVES).track(&faulty).unwrap();
    let found = all.alternatives.len();
    let sizes = |e: &FrameEstimate| -> Vec<usize> {
        e.alternatives.iter().map(|a| a.group.len()).collect()
    };
    assert!(
        found > 5 && sizes(&all)[0] > sizes(&all)[found - 1],
        "{:?}",
        sizes(&all)
    );
    assert_eq!(
        (all.alternatives_found, all.flags.alternatives_capped),
        (found, false)
    );
    for cap in [1, 2, found - 1, found, found + 1] {
        let capped = tracker(cap).track(&faulty).unwrap();
        let kept = cap.min(found);
        assert_eq!(
            capped.alternatives[..],
            all.alternatives[..kept],
            "cap {cap}"
        );
        assert_eq!(capped.alternatives_found, found);
        assert_eq!(capped.flags.alternatives_capped, cap < found);
        // No reliabilities here: the estimate is the first alternative's, capped or not.
        assert_eq!(capped.estimate, all.estimate);
    }
}

/// The Bayesian levels computed directly, one group at a time (`Tracker::bayesian_group_level`,
/// the general path on underflow): the levels the grown ones must equal bit for bit.
struct Direct<'a> {
    tracker: &'a Tracker,
    usable: &'a [Option<Usable>],
}

impl GroupLevels for Direct<'_> {
    fn pair_level(&mut self, i: usize, j: usize) -> f64 {
        match (&self.usable[i], &self.usable[j]) {
            (Some(a), Some(b)) => self.tracker.pair_level(i, j, a, b),
            _ => f64::INFINITY,
        }
    }
    fn group_level(&mut self, group: GroupMask) -> f64 {
        (self.tracker.bayesian_group_level(group, self.usable))
            .unwrap_or_else(|| self.tracker.general_level(group, self.usable))
    }
    fn fallback_feature(&self) -> Option<usize> {
        self.tracker.fallback_feature(self.usable)
    }
}

/// Levels kept across the selections of one frame (a group's level does not depend on the
/// threshold): the exhaustive reference computes each group once a frame, not once a selection.
struct Kept<L> {
    inner: L,
    levels: HashMap<GroupMask, f64>,
}

impl<L: GroupLevels> GroupLevels for Kept<L> {
    fn pair_level(&mut self, i: usize, j: usize) -> f64 {
        self.inner.pair_level(i, j)
    }
    fn group_level(&mut self, group: GroupMask) -> f64 {
        let inner = &mut self.inner;
        *(self.levels)
            .entry(group)
            .or_insert_with(|| inner.group_level(group))
    }
    fn fallback_feature(&self) -> Option<usize> {
        self.inner.fallback_feature()
    }
}

/// Every group of `all` leaving out at most `out` features, in lexicographic order.
fn nearly_all(all: GroupMask, out: u32) -> Vec<GroupMask> {
    let mut groups: Vec<GroupMask> = (0..1u64 << all.count_ones())
        .map(|bits| {
            (members(all).enumerate())
                .filter(|&(k, _)| bits >> k & 1 == 1)
                .fold(0, |m, (_, i)| m | 1 << i)
        })
        .filter(|&g: &GroupMask| g.count_ones() >= 2 && (all & !g).count_ones() <= out)
        .collect();
    groups.sort_by(|&a, &b| super::super::group_search::lex_cmp(a, b));
    groups
}

#[test]
fn levels_of_groups_leaving_out_a_few_features_are_the_direct_levels_bit_for_bit() {
    // Random frames with stuck and outlying features, and the bench's frame scaled down; groups
    // asked for in lexicographic order (the walk's) and shuffled, leaving out up to one feature
    // more than the products on the cells take (those go on numbering tuples): every group
    // leaving out at most 3, one in eight of the others (the test's time is in the levels).
    let mut rng = ChaCha8Rng::seed_from_u64(36);
    let mut frames = Vec::new();
    for n in [16, 17] {
        let (tracker, specs) = random_tracker(&mut rng, n, Constructor::Bayesian);
        for _ in 0..2 {
            let frame = random_frame(&mut rng, &specs);
            frames.push((tracker.clone(), frame));
        }
    }
    for (n, side, corrupt) in [(16, 30, [0, 8]), (18, 20, [0, 9])] {
        let (tracker, [clean, faulty]) = bench_shaped(&mut rng, n, side, &corrupt);
        frames.push((tracker.clone(), clean));
        frames.push((tracker, faulty));
    }
    let (mut compared, mut beyond_products) = (0, 0);
    for (tracker, frame) in &frames {
        let (usable, _) = tracker.measure(frame).unwrap();
        let all = present_mask(&usable);
        let mut groups = nearly_all(all, MAX_LEFT_OUT + 1);
        groups.retain(|&g| (all & !g).count_ones() <= 3 || rng.random_range(0..8) == 0);
        // The direct levels once: they do not depend on the order the groups are asked in.
        let direct: Vec<Option<u64>> = (groups.iter())
            .map(|&g| tracker.bayesian_group_level(g, &usable).map(f64::to_bits))
            .collect();
        let mut order: Vec<usize> = (0..groups.len()).collect();
        for shuffled in [false, true] {
            if shuffled {
                for k in (1..order.len()).rev() {
                    order.swap(k, rng.random_range(0..=k));
                }
            }
            let mut levels = tracker.cell_levels(&usable);
            if !shuffled {
                // Several at once, as the splitting search asks for its alternatives.
                let mut one_by_one = tracker.cell_levels(&usable);
                for (&g, k) in groups.iter().zip(levels.group_levels(&groups)) {
                    let one = one_by_one.group_level(g);
                    assert_eq!(k.to_bits(), one.to_bits(), "group {g:b} together");
                }
            }
            // The per-cell path itself (the stack would take the direct path for a large group
            // while its chain is empty).
            let mut products = CellProducts::default();
            for &k in &order {
                let (g, direct) = (groups[k], direct[k]);
                let grown = levels.tuples.level(tracker, &usable, g);
                assert_eq!(grown.map(f64::to_bits), direct, "group {g:b}");
                let on_cells = products.level(tracker, &usable, g);
                if (all & !g).count_ones() <= MAX_LEFT_OUT {
                    let on_cells = on_cells.expect("a group leaving out a few features");
                    assert_eq!(
                        on_cells.map(f64::to_bits),
                        direct,
                        "group {g:b} on the cells"
                    );
                    compared += 1;
                } else {
                    assert!(on_cells.is_none(), "group {g:b} leaves out too many");
                    beyond_products += 1;
                }
            }
        }
    }
    assert!(
        compared > 5_000 && beyond_products > 1_000,
        "{compared} levels on the cells compared, {beyond_products} beyond them"
    );
}

#[test]
fn splitting_the_bench_frame_scaled_down_equals_the_direct_levels_exhaustive_selection() {
    // The alternatives, their order, their levels' bits and their count (`alternatives_found`)
    // of the pruned search on the grown levels against every clique on the direct levels.
    let mut rng = ChaCha8Rng::seed_from_u64(37);
    let mut compared = 0;
    for (n, side, corrupt) in [(16, 30, [0, 8]), (17, 40, [0, 6]), (16, 25, [3, 11])] {
        let (tracker, [clean, faulty]) = bench_shaped(&mut rng, n, side, &corrupt);
        let (usable, _) = tracker.measure(&clean).unwrap();
        let all = present_mask(&usable);
        let level = tracker.raw_level(all, &usable);
        let (usable, _) = tracker.measure(&faulty).unwrap();
        let mut direct = Kept {
            inner: Direct {
                tracker: &tracker,
                usable: &usable,
            },
            levels: HashMap::new(),
        };
        for factor in [1.02, 1.05, 1.2, 2.0] {
            let threshold = ConflictLevel::from_value(factor * level);
            for min_size in [2, 5] {
                let policy = SelectionPolicy::Splitting { min_size };
                let mut levels = tracker.cell_levels(&usable);
                assert!(levels.look_ahead_first());
                let pruned = select_group(&mut levels, n, all, policy, threshold);
                let every = select_group_exhaustive(&mut direct, n, all, policy, threshold);
                assert_eq!(pruned, every, "n {n} side {side} ×{factor} min {min_size}");
                compared += pruned.alternatives.len();
                // A capped frame's first alternatives, the others settled by bounds.
                for keep in [1, 3, 16] {
                    let mut levels = tracker.cell_levels(&usable);
                    let (kept, found) =
                        select_group_keeping(&mut levels, n, all, policy, threshold, keep);
                    let first = &pruned.alternatives[..keep.min(found)];
                    assert_eq!(
                        (&kept.alternatives[..], found),
                        (first, pruned.alternatives.len())
                    );
                }
            }
        }
    }
    assert!(compared > 200, "{compared} alternatives compared");
}

#[test]
fn bounds_of_levels_hold_the_direct_levels() {
    // Groups in lexicographic order, the walk's group a prefix of each (so that bounds take a
    // built prefix times kept upper parts, as the search's do) or none.
    let mut rng = ChaCha8Rng::seed_from_u64(38);
    let (mut checked, mut two_sided) = (0, 0);
    for (n, side, corrupt) in [(16, 30, [0, 8]), (17, 20, [3, 11])] {
        let (tracker, [clean, faulty]) = bench_shaped(&mut rng, n, side, &corrupt);
        for frame in [clean, faulty] {
            let (usable, _) = tracker.measure(&frame).unwrap();
            let all = present_mask(&usable);
            let mut levels = tracker.cell_levels(&usable);
            let mut groups = nearly_all(all, MAX_LEFT_OUT + 1);
            groups.retain(|g| g.count_ones() >= 3 && rng.random_range(0..4) == 0);
            for g in groups {
                let Some(exact) = tracker.bayesian_group_level(g, &usable) else {
                    continue;
                };
                let first = rng.random_range(0..6);
                let walked = members(g).take(first).fold(0, |m, i| m | 1 << i);
                let b = levels
                    .level_bounds(g, walked)
                    .expect("bounds on a 16-feature model");
                let slack = 1e-11 * (1.0 + exact.abs());
                assert!(
                    b.floor <= exact + slack && exact <= b.ceiling + slack,
                    "group {g:b}: level {exact} outside {b:?}"
                );
                checked += 1;
                if b.ceiling.is_finite() {
                    assert!(b.ceiling - b.floor <= slack, "group {g:b}: {b:?}");
                    two_sided += 1;
                }
                // Now and then the level itself, so the chain moves on as the search's does.
                if rng.random_range(0..4) == 0 {
                    levels.group_level(g);
                }
            }
        }
    }
    assert!(
        checked > 3_000 && two_sided > checked / 4 && two_sided < checked,
        "{two_sided} two-sided of {checked}"
    );
}
