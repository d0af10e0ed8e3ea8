//! Choosing the group of features a frame combines: the conflict graph (pairs within the conflict
//! threshold), its complete subgraphs, and the selection policies (largest subset, lowest
//! conflict, splitting), with the single-feature fallback when no group is eligible.

use std::collections::HashMap;

use super::conflict::TIE;
use super::settings::SelectionPolicy;
use super::tracker::{lex, Tracker, Usable};

/// The outcome of group selection for one frame.
pub(super) struct Selection {
    /// Level of conflict and mask of the chosen group (`None` only without a usable feature).
    pub(super) chosen: Option<(f64, u32)>,
    /// Levels and masks of the splitting policy's alternatives, the chosen one first (empty for
    /// the other policies and on fallback).
    pub(super) alternatives: Vec<(f64, u32)>,
    /// No eligible group existed: the chosen group is the fallback feature alone.
    pub(super) fallback: bool,
}

impl Tracker {
    /// Choose the group to combine among the usable features (`usable_mask`, not empty): the
    /// selection policy on the complete subgraphs of the conflict graph, else the fallback feature.
    pub(super) fn select(&self, usable: &[Option<Usable>], usable_mask: u32) -> Selection {
        let f = usable.len();
        let adj = self.conflict_graph(usable);
        let groups = cliques(usable_mask, &adj, f);
        let mut memo: HashMap<u32, f64> = HashMap::new();
        let policy = self.settings.selection;
        // A group is eligible when its own level is within the threshold, the quantity §4.3
        // learns it from; the graph's pairwise test is the necessary condition (Theorem 4.3: K
        // only grows as features are added), which prunes the candidates.
        let threshold = self.settings.conflict_threshold;
        let min_size = policy.min_size();
        let mut chosen: Option<(f64, u32)> = None;
        let mut alternatives: Vec<(f64, u32)> = Vec::new();
        match policy {
            SelectionPolicy::LargestSubset => {
                // Groups come by increasing size in lexicographic order: scan from the largest.
                let mut size = groups.last().map_or(0, |g| g.count_ones());
                while size >= 1 && chosen.is_none() {
                    for &g in groups.iter().filter(|g| g.count_ones() == size) {
                        let k = self.level(g, usable, &mut memo, f64::INFINITY);
                        if threshold.admits(k) && chosen.is_none_or(|(best, _)| k < best - TIE) {
                            chosen = Some((k, g));
                        }
                    }
                    size -= 1;
                }
                // A single feature while several are usable means no pair is compatible.
                if chosen.is_some_and(|(_, g)| g.count_ones() == 1) && usable_mask.count_ones() > 1
                {
                    chosen = None;
                }
            }
            SelectionPolicy::LowestConflict { .. } => {
                for &g in groups
                    .iter()
                    .filter(|g| g.count_ones() as usize >= min_size)
                {
                    let bound = chosen.map_or(f64::INFINITY, |(k, _)| k);
                    let k = self.level(g, usable, &mut memo, bound);
                    if threshold.admits(k) {
                        let better = match chosen {
                            None => true,
                            Some((best, bg)) => {
                                k < best - TIE
                                    || (k <= best + TIE && g.count_ones() > bg.count_ones())
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
                    let k = self.level(g, usable, &mut memo, f64::INFINITY);
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
            chosen = self.fallback_feature(usable).map(|i| (0.0, 1u32 << i));
        }
        Selection {
            chosen,
            alternatives,
            fallback,
        }
    }

    /// The conflict graph of a frame: per feature, the mask of the usable features whose pairwise
    /// level of conflict with it is finite and within the threshold.
    fn conflict_graph(&self, usable: &[Option<Usable>]) -> Vec<u32> {
        let f = usable.len();
        let mut adj = vec![0u32; f];
        for i in 0..f {
            let Some(a) = &usable[i] else { continue };
            for j in i + 1..f {
                let Some(b) = &usable[j] else { continue };
                let k = self.pair_level(i, j, a, b);
                if self.settings.conflict_threshold.admits(k) {
                    adj[i] |= 1 << j;
                    adj[j] |= 1 << i;
                }
            }
        }
        adj
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
