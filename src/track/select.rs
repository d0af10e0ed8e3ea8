//! Choosing the group of features a frame combines: the conflict graph (pairs within the conflict
//! threshold), its complete subgraphs, and the selection policies (largest subset, lowest
//! conflict, splitting), with the single-feature fallback when no group is eligible.
//!
//! The policies see the features only through [`GroupLevels`], so that every evidential tracker
//! (the paper's on cells, the continuous one on poses) selects its groups by the same rules.

use std::collections::HashMap;

use super::conflict::TIE;
use super::settings::SelectionPolicy;
use super::tracker::{lex, Tracker, Usable};
use crate::evidence::ConflictLevel;

/// The outcome of group selection for one frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Selection {
    /// Level of conflict and mask of the chosen group (`None` only without a usable feature).
    pub chosen: Option<(f64, u32)>,
    /// Levels and masks of the splitting policy's alternatives, the chosen one first (empty for
    /// the other policies and on fallback).
    pub alternatives: Vec<(f64, u32)>,
    /// No eligible group existed: the chosen group is the fallback feature alone.
    pub fallback: bool,
}

/// What group selection asks of one frame's usable features (bit `i` of a mask is feature `i`).
pub trait GroupLevels {
    /// Level of conflict of usable features `i < j`.
    fn pair_level(&mut self, i: usize, j: usize) -> f64;
    /// Level of conflict of a group of at least two usable features; it may only grow as
    /// features are added (Theorem 4.3), which the selection uses to prune.
    fn group_level(&mut self, group: u32) -> f64;
    /// The feature combined alone when no group is eligible.
    fn fallback_feature(&self) -> Option<usize>;
}

/// A group's level (0 for one feature), memoised in `memo`. With a finite `bound`, a group whose
/// prefix (the group without its highest feature) is already known to exceed the bound is not
/// combined: K only grows as features are added (Theorem 4.3), so it cannot be below the bound;
/// it is recorded as +∞.
pub(super) fn memoised_level(
    memo: &mut HashMap<u32, f64>,
    group: u32,
    bound: f64,
    compute: impl FnOnce() -> f64,
) -> f64 {
    if group.count_ones() <= 1 {
        return 0.0;
    }
    if let Some(&k) = memo.get(&group) {
        return k;
    }
    let parent = group & !(1u32 << (31 - group.leading_zeros()));
    let k = match memo.get(&parent) {
        Some(&kp) if kp.is_nan() || kp > bound + TIE => f64::INFINITY,
        _ => compute(),
    };
    memo.insert(group, k);
    k
}

/// Chooses the group to combine among the usable features (`usable_mask`, not empty, of
/// `features`): the selection `policy` on the complete subgraphs of the conflict graph, else the
/// fallback feature. A group is eligible when its own level is within `threshold`, the quantity
/// §4.3 learns it from; the graph's pairwise test is the necessary condition (Theorem 4.3: K only
/// grows as features are added), which prunes the candidates.
pub fn select_group(
    levels: &mut impl GroupLevels,
    features: usize,
    usable_mask: u32,
    policy: SelectionPolicy,
    threshold: ConflictLevel,
) -> Selection {
    let f = features;
    let adj = conflict_graph(levels, f, usable_mask, threshold);
    let groups = cliques(usable_mask, &adj, f);
    let mut memo: HashMap<u32, f64> = HashMap::new();
    let mut level =
        |g: u32, bound: f64| memoised_level(&mut memo, g, bound, || levels.group_level(g));
    let min_size = policy.min_size();
    let mut chosen: Option<(f64, u32)> = None;
    let mut alternatives: Vec<(f64, u32)> = Vec::new();
    match policy {
        SelectionPolicy::LargestSubset => {
            // Groups come by increasing size in lexicographic order: scan from the largest.
            let mut size = groups.last().map_or(0, |g| g.count_ones());
            while size >= 1 && chosen.is_none() {
                for &g in groups.iter().filter(|g| g.count_ones() == size) {
                    let k = level(g, f64::INFINITY);
                    if threshold.admits(k) && chosen.is_none_or(|(best, _)| k < best - TIE) {
                        chosen = Some((k, g));
                    }
                }
                size -= 1;
            }
            // A single feature while several are usable means no pair is compatible.
            if chosen.is_some_and(|(_, g)| g.count_ones() == 1) && usable_mask.count_ones() > 1 {
                chosen = None;
            }
        }
        SelectionPolicy::LowestConflict { .. } => {
            for &g in groups
                .iter()
                .filter(|g| g.count_ones() as usize >= min_size)
            {
                let bound = chosen.map_or(f64::INFINITY, |(k, _)| k);
                let k = level(g, bound);
                if threshold.admits(k) {
                    let better = match chosen {
                        None => true,
                        Some((best, bg)) => {
                            k < best - TIE || (k <= best + TIE && g.count_ones() > bg.count_ones())
                        }
                    };
                    if better {
                        chosen = Some((k, g));
                    }
                }
            }
        }
        SelectionPolicy::Splitting { .. } => {
            for &g in groups
                .iter()
                .rev()
                .filter(|g| g.count_ones() as usize >= min_size)
            {
                if alternatives.iter().any(|&(_, a)| g & a == g) {
                    continue;
                }
                let k = level(g, f64::INFINITY);
                if threshold.admits(k) {
                    alternatives.push((k, g));
                }
            }
            alternatives.sort_by(|a, b| {
                b.1.count_ones()
                    .cmp(&a.1.count_ones())
                    .then(a.0.total_cmp(&b.0))
                    .then(lex(a.1).cmp(&lex(b.1)))
            });
            chosen = alternatives.first().copied();
        }
    }
    let fallback = chosen.is_none();
    if fallback {
        alternatives.clear();
        chosen = levels.fallback_feature().map(|i| (0.0, 1u32 << i));
    }
    Selection {
        chosen,
        alternatives,
        fallback,
    }
}

/// The conflict graph of a frame: per feature, the mask of the usable features whose pairwise
/// level of conflict with it is finite and within the threshold.
fn conflict_graph(
    levels: &mut impl GroupLevels,
    f: usize,
    usable_mask: u32,
    threshold: ConflictLevel,
) -> Vec<u32> {
    let mut adj = vec![0u32; f];
    for i in (0..f).filter(|i| usable_mask >> i & 1 == 1) {
        for j in (i + 1..f).filter(|j| usable_mask >> j & 1 == 1) {
            if threshold.admits(levels.pair_level(i, j)) {
                adj[i] |= 1 << j;
                adj[j] |= 1 << i;
            }
        }
    }
    adj
}

/// The paper's tracker seen by the selection: its cells, pairwise and group levels.
struct CellLevels<'a> {
    tracker: &'a Tracker,
    usable: &'a [Option<Usable>],
}

impl GroupLevels for CellLevels<'_> {
    fn pair_level(&mut self, i: usize, j: usize) -> f64 {
        match (&self.usable[i], &self.usable[j]) {
            (Some(a), Some(b)) => self.tracker.pair_level(i, j, a, b),
            _ => f64::INFINITY,
        }
    }

    fn group_level(&mut self, group: u32) -> f64 {
        self.tracker.raw_level(group, self.usable)
    }

    fn fallback_feature(&self) -> Option<usize> {
        self.tracker.fallback_feature(self.usable)
    }
}

impl Tracker {
    /// Choose the group to combine among the usable features (`usable_mask`, not empty).
    pub(super) fn select(&self, usable: &[Option<Usable>], usable_mask: u32) -> Selection {
        let mut levels = CellLevels {
            tracker: self,
            usable,
        };
        select_group(
            &mut levels,
            usable.len(),
            usable_mask,
            self.settings.selection,
            self.settings.conflict_threshold,
        )
    }

    /// The fallback feature: lowest validation error (features without one after those with one),
    /// then lowest index.
    fn fallback_feature(&self, usable: &[Option<Usable>]) -> Option<usize> {
        let features = self.model.features();
        (0..usable.len())
            .filter(|&i| usable[i].is_some())
            .min_by(|&a, &b| {
                let ea = features[a].validation_error.unwrap_or(f64::INFINITY);
                let eb = features[b].validation_error.unwrap_or(f64::INFINITY);
                ea.total_cmp(&eb).then(a.cmp(&b))
            })
    }
}

/// All complete subgraphs among the usable features, grown bottom-up: the groups of size d + 1 are
/// the groups of size d extended by a higher-indexed feature adjacent to all their members.
/// Returned by increasing size, lexicographic within a size.
fn cliques(usable: u32, adj: &[u32], f: usize) -> Vec<u32> {
    let mut all: Vec<u32> = (0..f)
        .filter(|&i| usable >> i & 1 == 1)
        .map(|i| 1u32 << i)
        .collect();
    let mut start = 0;
    while start < all.len() {
        let end = all.len();
        for g in start..end {
            let group = all[g];
            let top = 31 - group.leading_zeros() as usize;
            for (j, &aj) in adj.iter().enumerate().take(f).skip(top + 1) {
                if usable >> j & 1 == 1 && aj & group == group {
                    all.push(group | 1 << j);
                }
            }
        }
        start = end;
    }
    all
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cliques_grow_bottom_up() {
        // Triangle 0-1-2 plus edge 2-3.
        let adj = [0b0110, 0b0101, 0b1011, 0b0100];
        let g = cliques(0b1111, &adj, 4);
        assert_eq!(
            g,
            vec![0b0001, 0b0010, 0b0100, 0b1000, 0b0011, 0b0101, 0b0110, 0b1100, 0b0111]
        );
        // Without feature 1 usable.
        let g = cliques(0b1101, &adj, 4);
        assert_eq!(g, vec![0b0001, 0b0100, 0b1000, 0b0101, 0b1100]);
    }
}
