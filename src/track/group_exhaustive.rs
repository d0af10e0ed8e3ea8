//! The reference the pruned search replaced and is tested against: every complete subgraph of
//! the conflict graph, each level computed (exponential in the number of features); also the
//! selection for levels that may not grow exactly.

use std::collections::HashMap;

use super::super::settings::SelectionPolicy;
use super::{members, memoised_level, sort_alternatives, Choice, GroupLevels, GroupMask, TIE};
use crate::evidence::ConflictLevel;

/// Every complete subgraph, by increasing size, lexicographic within a size (the old code).
pub(super) fn all_cliques(usable: GroupMask, adj: &[GroupMask]) -> Vec<GroupMask> {
    let mut all: Vec<GroupMask> = members(usable).map(|i| 1 << i).collect();
    let mut start = 0;
    while start < all.len() {
        let end = all.len();
        for g in start..end {
            let group = all[g];
            let top = 63 - group.leading_zeros() as usize;
            for (j, &aj) in adj.iter().enumerate().skip(top + 1) {
                if usable >> j & 1 == 1 && aj & group == group {
                    all.push(group | 1 << j);
                }
            }
        }
        start = end;
    }
    all
}

/// The chosen group and alternatives over every complete subgraph, by increasing size
/// (exponential in the number of features): for level functions that may not grow exactly, and
/// the search's reference.
pub(super) fn every_clique(
    levels: &mut impl GroupLevels,
    adj: &[GroupMask],
    usable_mask: GroupMask,
    policy: SelectionPolicy,
    threshold: ConflictLevel,
) -> Choice {
    let groups = all_cliques(usable_mask, adj);
    let mut memo: HashMap<GroupMask, f64> = HashMap::new();
    let mut level =
        |g: GroupMask, bound: f64| memoised_level(&mut memo, g, bound, || levels.group_level(g));
    let min_size = policy.min_size();
    let mut chosen: Option<(f64, GroupMask)> = None;
    let mut alternatives: Vec<(f64, GroupMask)> = Vec::new();
    match policy {
        SelectionPolicy::LargestSubset => {
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
            sort_alternatives(&mut alternatives);
            chosen = alternatives.first().copied();
        }
    }
    (chosen, alternatives)
}

/// [`super::select_group`] over every complete subgraph, whatever the levels: the reference the
/// pruned search is tested against.
#[cfg(test)]
pub(crate) fn select_group_exhaustive(
    levels: &mut impl GroupLevels,
    features: usize,
    usable_mask: GroupMask,
    policy: SelectionPolicy,
    threshold: ConflictLevel,
) -> super::Selection {
    super::choose(levels, features, usable_mask, policy, threshold, true, None).0
}
