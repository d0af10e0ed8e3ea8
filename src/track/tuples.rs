//! The Bayesian group level of `Tracker::bayesian_level`, grown one feature at a time: the
//! selection's search walks groups in lexicographic order, so a group's state tuples are its
//! prefix's tuples refined by one feature (one pass over the cells instead of one per member).
//! Every product and sum is taken in the same order as there, so the levels are bit-identical.

use super::group_search::{members, GroupMask};
use super::tracker::{Tracker, Usable};

/// The distinct state tuples of one group on the cells.
struct Tuples {
    group: GroupMask,
    /// Each cell's tuple, numbered by first occurrence.
    id: Vec<u32>,
    /// Each tuple's product of the members' scaled contours, in member order.
    product: Vec<f64>,
    /// Whether every factor of that product is positive.
    positive: Vec<bool>,
}

/// The chain of prefixes of the last group asked for, each with its tuples.
#[derive(Default)]
pub(super) struct TupleStack {
    chain: Vec<Tuples>,
}

impl TupleStack {
    /// The Bayesian level of `group` (at least two usable features), or `None` when the sum
    /// underflows and the general path must decide, as `Tracker::bayesian_level`.
    pub(super) fn level(
        &mut self,
        tracker: &Tracker,
        usable: &[Option<Usable>],
        group: GroupMask,
    ) -> Option<f64> {
        // Keep the longest prefix of `group` already built.
        let is_prefix = |p: GroupMask| {
            let top = 63 - p.leading_zeros();
            let below = if top == 63 {
                GroupMask::MAX
            } else {
                (2 << top) - 1
            };
            group & below == p
        };
        while self.chain.last().is_some_and(|t| !is_prefix(t.group)) {
            self.chain.pop();
        }
        // Nothing to grow from (a maximum clique, before any walk): one direct computation is
        // cheaper than building every prefix.
        if self.chain.is_empty() && group.count_ones() > 2 {
            return tracker.bayesian_group_level(group, usable);
        }
        let mut built = self.chain.last().map_or(0, |t| t.group);
        for i in members(group & !built) {
            built |= 1 << i;
            let next = self.extend(tracker, built, i, usable[i].as_ref()?);
            self.chain.push(next);
        }
        let tuples = self.chain.last()?;
        if !tuples.positive.iter().any(|&p| p) {
            return Some(f64::INFINITY);
        }
        let mut s = 0.0;
        for &p in &tuples.product {
            s += p;
        }
        if s.is_nan() || s <= 1e-280 {
            return None;
        }
        let scales: Vec<f64> = members(group)
            .map(|i| usable[i].as_ref().map(|u| u.scale))
            .collect::<Option<_>>()?;
        let log_scale: f64 = scales.iter().map(|c| c.ln()).sum();
        Some((-(s.ln() + log_scale)).max(0.0))
    }

    /// The tuples of `group`: the last group of the chain (or none) with feature `i` added.
    fn extend(&self, tracker: &Tracker, group: GroupMask, i: usize, feature: &Usable) -> Tuples {
        let states = tracker.to_cells[i].assignment();
        let n = tracker.to_cells[i].coarse_size();
        let cells = states.len();
        let (parent_id, parent_count) = match self.chain.last() {
            Some(t) => (Some(&t.id), t.product.len()),
            None => (None, 1),
        };
        let mut remap = vec![u32::MAX; parent_count * n];
        let mut id = Vec::with_capacity(cells);
        let mut product = Vec::new();
        let mut positive = Vec::new();
        for (u, &su) in states.iter().enumerate() {
            let p = parent_id.map_or(0, |ids| ids[u] as usize);
            let key = p * n + su;
            if remap[key] == u32::MAX {
                remap[key] = product.len() as u32;
                let c = feature.contour[su];
                let (before, all_positive) = match self.chain.last() {
                    Some(t) => (t.product[p], t.positive[p]),
                    None => (1.0, true),
                };
                product.push(before * c);
                positive.push(all_positive && c > 0.0);
            }
            id.push(remap[key]);
        }
        Tuples {
            group,
            id,
            product,
            positive,
        }
    }
}
