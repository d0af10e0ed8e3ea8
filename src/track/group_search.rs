//! Choosing the group of features a frame combines: the conflict graph (pairs within the conflict
//! threshold), its complete subgraphs, and the selection policies (largest subset, lowest
//! conflict, splitting), with the single-feature fallback when no group is eligible.
//!
//! The policies see the features only through [`GroupLevels`], so that every evidential tracker
//! (the paper's on cells, the continuous one on poses) selects its groups by the same rules.
//!
//! No policy lists every complete subgraph (2^n of them for a complete graph of n features): the
//! maximal cliques come from Bron–Kerbosch with pivoting, and the searches below them walk the
//! cliques depth first in lexicographic order, pruned by size and by Theorem 4.3 (a group's level
//! only grows as features are added), so the levels computed follow what the policy needs. The
//! largest subset looks for each size from the largest down (the size bound then cuts every
//! branch that cannot reach it), and with cheap pair levels a candidate whose pair with a member
//! is beyond the bound at hand is dropped before any group holding it is computed.

use std::cmp::Ordering;

pub(super) use super::mask_map::{memoised_level, MaskMap};

use super::settings::SelectionPolicy;
use crate::evidence::ConflictLevel;

#[path = "group_exhaustive.rs"]
mod exhaustive;
#[path = "group_split.rs"]
mod split;
#[cfg(test)]
use exhaustive::all_cliques;
use exhaustive::every_clique;
#[cfg(test)]
pub(crate) use exhaustive::select_group_exhaustive;
pub(super) use split::select_group_keeping;

/// A group of features as a bit mask: bit `i` is feature `i`.
pub type GroupMask = u64;

/// The group of the features present in `values` (`Some`).
pub fn present_mask<T>(values: &[Option<T>]) -> GroupMask {
    (values.iter().enumerate())
        .filter(|(_, v)| v.is_some())
        .fold(0, |m, (i, _)| m | 1 << i)
}

/// Two levels of conflict closer than this are a tie.
pub(super) const TIE: f64 = 1e-12;

/// The outcome of group selection for one frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Selection {
    /// Level of conflict and mask of the chosen group (`None` only without a usable feature).
    pub chosen: Option<(f64, GroupMask)>,
    /// Levels and masks of the splitting policy's alternatives, the chosen one first (empty for
    /// the other policies and on fallback).
    pub alternatives: Vec<(f64, GroupMask)>,
    /// No eligible group existed: the chosen group is the fallback feature alone.
    pub fallback: bool,
}

/// What group selection asks of one frame's usable features (bit `i` of a mask is feature `i`).
pub trait GroupLevels {
    /// Level of conflict of usable features `i < j`.
    fn pair_level(&mut self, i: usize, j: usize) -> f64;
    /// Level of conflict of a group of at least two usable features; it may only grow as
    /// features are added (Theorem 4.3), which the selection uses to prune.
    fn group_level(&mut self, group: GroupMask) -> f64;
    /// The feature combined alone when no group is eligible.
    fn fallback_feature(&self) -> Option<usize>;
    /// Whether a group whose level is beyond a bound proves every larger group beyond it
    /// (levels computed by combination do, up to rounding; a level found by a local fit may
    /// not). Without it, the selection lists every complete subgraph, as the paper's §4.1 does.
    fn levels_grow_exactly(&self) -> bool {
        true
    }
    /// Whether the search should, before going below a group, drop each candidate whose pair
    /// with the group is already beyond the threshold (sound by Theorem 4.3; it costs every
    /// candidate's level up front and pays when levels are costly and a few features conflict
    /// with many: the size bound then sees only the compatible candidates).
    fn narrow_candidates(&self) -> bool {
        false
    }
    /// Whether a pair's group level costs next to nothing (the paper's Bayesian levels: a few
    /// state tuples). The search then drops, before going below a group, each candidate whose
    /// pair with the newest member is beyond the bound at hand (sound by Theorem 4.3), so that
    /// groups are ruled out, and the size bound tightened, before any of their levels is computed.
    fn cheap_pairs(&self) -> bool {
        false
    }
    /// Whether the levels of groups that leave out a few features cost less than growing a
    /// group by one feature: the splitting search then asks its look-ahead (the group with
    /// every candidate) before the group's own level, which it no longer needs when the
    /// look-ahead is eligible.
    fn look_ahead_first(&mut self) -> bool {
        false
    }
    /// Bounds on the level of `group` that cost far less than the level (the paper's Bayesian
    /// level summed over the cells in eight lanes), each within 1e-11 of the level's side of it
    /// (rounding); `None` without them. `walked` is a prefix of `group` (the walk's group, or
    /// 0) whose bounds may be asked next: what is built for it may be kept. With
    /// [`GroupLevels::look_ahead_first`] the splitting search settles a group against the
    /// threshold by them when they are clear of it, and computes the level only otherwise.
    fn level_bounds(&mut self, _group: GroupMask, _walked: GroupMask) -> Option<LevelBounds> {
        None
    }
    /// The levels of `groups` (distinct, in lexicographic order, each of at least two
    /// features), the same bits as [`GroupLevels::group_level`] gives each: an implementation
    /// may compute several at once.
    fn group_levels(&mut self, groups: &[GroupMask]) -> Vec<f64> {
        groups.iter().map(|&g| self.group_level(g)).collect()
    }
    /// Lower bounds on the levels of `group` without each of its members (ascending), each at
    /// most that group's level up to a relative 1e-12, so that the largest subset rules groups
    /// one feature short of a maximum clique out before computing them; `None` without them.
    fn floors_without_one(&mut self, _group: GroupMask) -> Option<Vec<f64>> {
        None
    }
}

/// A floor and a ceiling of a group's level ([`GroupLevels::level_bounds`]); the ceiling is
/// +∞ when only the floor is known.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LevelBounds {
    /// At most the level (up to rounding).
    pub floor: f64,
    /// At least the level (up to rounding), or +∞.
    pub ceiling: f64,
}

/// Feature indices of a group mask, ascending.
pub fn members(mut mask: GroupMask) -> impl Iterator<Item = usize> {
    std::iter::from_fn(move || {
        (mask != 0).then(|| {
            let i = mask.trailing_zeros() as usize;
            mask &= mask - 1;
            i
        })
    })
}

/// Feature indices of a group mask, ascending (also its lexicographic key).
pub(crate) fn lex(mask: GroupMask) -> Vec<usize> {
    members(mask).collect()
}

/// Compares two groups as their ascending lists of feature indices, without building the lists.
pub(crate) fn lex_cmp(a: GroupMask, b: GroupMask) -> Ordering {
    let differ = a ^ b;
    if differ == 0 {
        return Ordering::Equal;
    }
    // Below the lowest differing feature both lists agree; the group holding that feature is
    // the smaller unless the other one ends there.
    let low = differ.trailing_zeros();
    let a_holds = a >> low & 1 == 1;
    let other = if a_holds { b } else { a };
    let holder_is_smaller = low < 63 && other >> (low + 1) != 0;
    if a_holds == holder_is_smaller {
        Ordering::Less
    } else {
        Ordering::Greater
    }
}

/// Chooses the group to combine among the usable features (`usable_mask`, not empty, of
/// `features`): the selection `policy` on the complete subgraphs of the conflict graph, else the
/// fallback feature. A group is eligible when its own level is within `threshold`, the quantity
/// §4.3 learns it from; the graph's pairwise test is the necessary condition (Theorem 4.3: K only
/// grows as features are added), which prunes the candidates.
///
/// Ties: the largest-subset policy keeps the first group in lexicographic order unless a later
/// one of the same size is lower by more than 1e-12; the lowest-conflict policy takes, among the
/// groups within 1e-12 of the lowest level, the largest, then the first in lexicographic order;
/// the splitting policy's alternatives are the maximal eligible groups.
pub fn select_group(
    levels: &mut impl GroupLevels,
    features: usize,
    usable_mask: GroupMask,
    policy: SelectionPolicy,
    threshold: ConflictLevel,
) -> Selection {
    let exhaustive = !levels.levels_grow_exactly();
    choose(
        levels,
        features,
        usable_mask,
        policy,
        threshold,
        exhaustive,
        None,
    )
    .0
}

/// [`select_group`] by the pruned search, or with `exhaustive` over every complete subgraph;
/// with `keep`, only the splitting policy's first alternatives ([`select_group_keeping`]).
/// Also the number of alternatives found.
fn choose(
    levels: &mut impl GroupLevels,
    features: usize,
    usable_mask: GroupMask,
    policy: SelectionPolicy,
    threshold: ConflictLevel,
    exhaustive: bool,
    keep: Option<usize>,
) -> (Selection, usize) {
    let adj = conflict_graph(levels, features, usable_mask, threshold);
    // The number of alternatives found, when only some are kept.
    let mut found = None;
    let (mut chosen, mut alternatives) = if exhaustive {
        every_clique(levels, &adj, usable_mask, policy, threshold)
    } else {
        let cheap_pairs = levels.cheap_pairs();
        let look_ahead_first = levels.look_ahead_first();
        let mut search = Search {
            levels: &mut *levels,
            adj,
            memo: MaskMap::default(),
            ranges: MaskMap::default(),
            threshold,
            cut: threshold.value(),
            pairs: if cheap_pairs {
                vec![f64::NAN; features * features]
            } else {
                Vec::new()
            },
            features,
            look_ahead_first,
            keep,
        };
        match policy {
            SelectionPolicy::LargestSubset => (search.largest(usable_mask), Vec::new()),
            SelectionPolicy::LowestConflict { min_size } => {
                (search.lowest(usable_mask, min_size), Vec::new())
            }
            SelectionPolicy::Splitting { min_size } => {
                let (alternatives, count) = search.maximal_eligible(usable_mask, min_size);
                found = Some(count);
                (alternatives.first().copied(), alternatives)
            }
        }
    };
    let fallback = chosen.is_none();
    if fallback {
        alternatives.clear();
        chosen = levels.fallback_feature().map(|i| (0.0, 1 << i));
    }
    let found = found.unwrap_or(alternatives.len());
    alternatives.truncate(keep.unwrap_or(found));
    let selection = Selection {
        chosen,
        alternatives,
        fallback,
    };
    (selection, if fallback { 0 } else { found })
}

/// A chosen group and the splitting policy's alternatives, each with its level.
type Choice = (Option<(f64, GroupMask)>, Vec<(f64, GroupMask)>);

/// The splitting policy's order: decreasing size, then increasing level, then feature list.
fn sort_alternatives(alternatives: &mut [(f64, GroupMask)]) {
    alternatives.sort_by(|a, b| {
        b.1.count_ones()
            .cmp(&a.1.count_ones())
            .then(a.0.total_cmp(&b.0))
            .then(lex_cmp(a.1, b.1))
    });
}

/// The conflict graph of a frame: per feature, the mask of the usable features whose pairwise
/// level of conflict with it is finite and within the threshold.
fn conflict_graph(
    levels: &mut impl GroupLevels,
    f: usize,
    usable_mask: GroupMask,
    threshold: ConflictLevel,
) -> Vec<GroupMask> {
    let mut adj = vec![0; f];
    for i in members(usable_mask) {
        for j in members(usable_mask & !(2u64 << i).wrapping_sub(1)) {
            if threshold.admits(levels.pair_level(i, j)) {
                adj[i] |= 1 << j;
                adj[j] |= 1 << i;
            }
        }
    }
    adj
}

/// The maximal cliques among `p` (Bron–Kerbosch with Tomita's pivot), in no particular order.
fn maximal_cliques(p: GroupMask, adj: &[GroupMask]) -> Vec<GroupMask> {
    fn extend(
        r: GroupMask,
        mut p: GroupMask,
        mut x: GroupMask,
        adj: &[GroupMask],
        out: &mut Vec<GroupMask>,
    ) {
        if p == 0 {
            if x == 0 {
                out.push(r);
            }
            return;
        }
        let pivot = members(p | x)
            .max_by_key(|&u| (p & adj[u]).count_ones())
            .unwrap_or(0);
        for v in members(p & !adj[pivot]) {
            extend(r | 1 << v, p & adj[v], x & adj[v], adj, out);
            p &= !(1 << v);
            x |= 1 << v;
        }
    }
    let mut out = Vec::new();
    extend(0, p, 0, adj, &mut out);
    out
}

/// One frame's selection: the conflict graph and the group levels computed so far.
struct Search<'a, L: GroupLevels> {
    levels: &'a mut L,
    adj: Vec<GroupMask>,
    memo: MaskMap<f64>,
    /// Bounds of levels not computed ([`GroupLevels::level_bounds`]), widened by their rounding.
    ranges: MaskMap<(f64, f64)>,
    threshold: ConflictLevel,
    /// The bound beyond which no group the current walk looks for can lie: candidates whose
    /// pair with a member is beyond it are dropped (with cheap pairs). It never rises in a walk.
    cut: f64,
    /// With cheap pairs, the pairs' levels by `i * features + j` (NaN until computed), the
    /// pairwise test's lookups cheaper than the memo's; empty otherwise.
    pairs: Vec<f64>,
    features: usize,
    /// [`GroupLevels::look_ahead_first`].
    look_ahead_first: bool,
    /// How many of the splitting policy's first alternatives to keep (all: `None`).
    keep: Option<usize>,
}

impl<L: GroupLevels> Search<'_, L> {
    /// A group's level, 0 for one feature, memoised.
    fn level(&mut self, group: GroupMask) -> f64 {
        if group.count_ones() <= 1 {
            return 0.0;
        }
        if let Some(&k) = self.memo.get(&group) {
            return k;
        }
        let k = self.levels.group_level(group);
        self.memo.insert(group, k);
        k
    }

    /// Whether no group containing one of level `k` can have a level within `bound`: K only
    /// grows as features are added (Theorem 4.3); the slack absorbs rounding.
    fn beyond(k: f64, bound: f64) -> bool {
        !(k.is_finite() && k <= bound + TIE)
    }

    /// Walks the cliques that extend `group` by the features of `candidates` (each adjacent to
    /// every member, above its highest), depth first in lexicographic order; `visit(group,
    /// candidates)` says whether to go below a clique.
    fn walk<V>(&mut self, group: GroupMask, candidates: GroupMask, visit: &mut V)
    where
        V: FnMut(&mut Self, GroupMask, GroupMask) -> bool,
    {
        let mut rest = candidates;
        while rest != 0 {
            let j = rest.trailing_zeros() as usize;
            rest &= rest - 1;
            let next = group | 1 << j;
            let below = self.pair_compatible(j, rest & self.adj[j]);
            if visit(self, next, below) {
                let below = self.compatible(next, below);
                self.walk(next, below, visit);
            }
        }
    }

    /// The `candidates` whose pair with feature `j` is within the cut (all of them without cheap
    /// pairs). The candidates came down already checked against the group's other members.
    fn pair_compatible(&mut self, j: usize, candidates: GroupMask) -> GroupMask {
        // At the threshold the conflict graph's edges already tell.
        if self.pairs.is_empty() || self.cut >= self.threshold.value() {
            return candidates;
        }
        let cut = self.cut;
        let mut kept = 0;
        for k in members(candidates) {
            let slot = j * self.features + k;
            if self.pairs[slot].is_nan() {
                self.pairs[slot] = self.level(1 << j | 1 << k);
            }
            // A NaN level stays NaN and is beyond every bound, as `beyond` says.
            if !Self::beyond(self.pairs[slot], cut) {
                kept |= 1 << k;
            }
        }
        kept
    }

    /// The `candidates` that, added to `group`, stay within the threshold (all of them unless
    /// the levels ask to narrow): no group holding one of the others is eligible.
    fn compatible(&mut self, group: GroupMask, candidates: GroupMask) -> GroupMask {
        // Pairs rarely conflict (two level curves cross): narrow below groups that fix a pose.
        if !self.levels.narrow_candidates()
            || self.threshold == ConflictLevel::Infinite
            || group.count_ones() < 2
        {
            return candidates;
        }
        let bound = self.threshold.value();
        members(candidates)
            .filter(|&k| !Self::beyond(self.level(group | 1 << k), bound))
            .fold(0, |m, k| m | 1 << k)
    }

    /// Of `groups` (in lexicographic order), the first eligible one unless a later one is lower
    /// by more than the tie margin.
    fn first_lowest(&mut self, groups: &[GroupMask]) -> Option<(f64, GroupMask)> {
        let mut chosen: Option<(f64, GroupMask)> = None;
        for &g in groups {
            let k = self.level(g);
            if self.threshold.admits(k) && chosen.is_none_or(|(best, _)| k < best - TIE) {
                chosen = Some((k, g));
            }
        }
        chosen
    }

    /// The largest eligible group. The maximum cliques come first (for a complete graph, the
    /// one group of every feature): when none is eligible, one walk per size, largest first,
    /// lists the eligible groups of that size (a feature or two at fault leave a size near the
    /// top, where the size bound leaves few branches).
    fn largest(&mut self, usable: GroupMask) -> Option<(f64, GroupMask)> {
        if usable.count_ones() == 1 {
            return Some((0.0, usable));
        }
        let maximal = maximal_cliques(usable, &self.adj);
        let omega = maximal.iter().map(|g| g.count_ones()).max().unwrap_or(0);
        // A single feature while several are usable means no pair is compatible.
        if omega < 2 {
            return None;
        }
        let mut top: Vec<GroupMask> = maximal
            .iter()
            .copied()
            .filter(|g| g.count_ones() == omega)
            .collect();
        top.sort_by(|&a, &b| lex_cmp(a, b));
        if let Some(chosen) = self.first_lowest(&top) {
            return Some(chosen);
        }
        let mut below = omega;
        if omega > 2 {
            if let Some(found) = self.one_short(&maximal, &top, omega) {
                if !found.is_empty() {
                    return self.first_lowest(&found);
                }
                below = omega - 1;
            }
        }
        // Every larger clique is ruled out: look for eligible groups of each size below, largest
        // first, so that the size bound prunes every branch that cannot reach it.
        let bound = self.threshold.value();
        self.cut = bound;
        for size in (2..below).rev() {
            let mut found = Vec::new();
            self.walk(0, usable, &mut |s, g, candidates| {
                let n = g.count_ones();
                if n + candidates.count_ones() < size {
                    return false;
                }
                if n < 2 {
                    return true;
                }
                let k = s.level(g);
                if n == size && s.threshold.admits(k) {
                    found.push(g);
                }
                n < size && !Self::beyond(k, bound)
            });
            if !found.is_empty() {
                return self.first_lowest(&found);
            }
        }
        None
    }

    /// The eligible groups one feature short of the `top` maximum cliques (size `omega`), in
    /// lexicographic order, or `None` without floors. Every such clique is a maximal clique of
    /// that size or a top one without a member; a floor beyond the bound rules a group out
    /// uncomputed (the walk would compute most of its prefixes to reach it).
    fn one_short(
        &mut self,
        maximal: &[GroupMask],
        top: &[GroupMask],
        omega: u32,
    ) -> Option<Vec<GroupMask>> {
        let bound = self.threshold.value();
        // Beyond the bound by this much, a floor's rounding cannot matter.
        let margin = TIE + 1e-9 * (1.0 + bound.abs());
        let mut groups: Vec<GroupMask> = maximal
            .iter()
            .copied()
            .filter(|g| g.count_ones() == omega - 1)
            .collect();
        let mut ruled_out = Vec::new();
        for &m in top {
            let floors = self.levels.floors_without_one(m)?;
            for (i, floor) in members(m).zip(floors) {
                let g = m & !(1 << i);
                if floor > bound + margin {
                    ruled_out.push(g);
                } else {
                    groups.push(g);
                }
            }
        }
        groups.sort_by(|&a, &b| lex_cmp(a, b));
        groups.dedup();
        groups.retain(|g| !ruled_out.contains(g));
        let mut found = Vec::new();
        for g in groups {
            if self.threshold.admits(self.level(g)) {
                found.push(g);
            }
        }
        Some(found)
    }

    /// The eligible group of at least `min_size` features with the lowest level; ties within the
    /// margin go to the larger group, then to the lexicographically first.
    fn lowest(&mut self, usable: GroupMask, min_size: usize) -> Option<(f64, GroupMask)> {
        let m = min_size.max(1) as u32;
        let bound = self.threshold.value();
        // K only grows, so the lowest level is a group of exactly `m` features.
        let mut lowest: Option<f64> = None;
        self.cut = bound;
        self.walk(0, usable, &mut |s, g, candidates| {
            let n = g.count_ones();
            if n + candidates.count_ones() < m {
                return false;
            }
            let k = s.level(g);
            if Self::beyond(k, lowest.map_or(bound, |l| l.min(bound))) {
                return false;
            }
            if n == m && s.threshold.admits(k) && lowest.is_none_or(|l| k < l) {
                lowest = Some(k);
                s.cut = s.cut.min(k);
            }
            n < m
        });
        let lowest = lowest?;
        self.cut = lowest + TIE;
        let mut chosen: Option<(f64, GroupMask)> = None;
        self.walk(0, usable, &mut |s, g, candidates| {
            let n = g.count_ones();
            let size = chosen.map_or(m - 1, |(_, c)| c.count_ones());
            if n + candidates.count_ones() <= size {
                return false;
            }
            let k = s.level(g);
            if Self::beyond(k, lowest + TIE) {
                return false;
            }
            if n > size && k <= lowest + TIE && s.threshold.admits(k) {
                chosen = Some((k, g));
            }
            true
        });
        chosen
    }
}

#[cfg(test)]
#[path = "group_search_tests.rs"]
mod tests;
