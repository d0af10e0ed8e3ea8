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
    /// Popped tuples whose buffers the next ones reuse.
    spare: Vec<Tuples>,
    /// Tuple numbers by (parent tuple, state), `u32::MAX` where unset between calls.
    remap: Vec<u32>,
    /// The largest cell value per tuple ([`TupleStack::agreement`]).
    top: Vec<f64>,
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
        // Nothing to grow from (a maximum clique, before any walk): one direct computation is
        // cheaper than building every prefix.
        self.keep_prefixes(group);
        if self.chain.is_empty() && group.count_ones() > 2 {
            return tracker.bayesian_group_level(group, usable);
        }
        self.grow(tracker, usable, group)?;
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

    /// Σ_t p(t)·max_t c / Σ_t p(t) over the state tuples t of `group` (one or more usable
    /// features), p the product of the members' scaled contours and max_t c the largest
    /// `cell_max` on t's cells: 1 − K(m_group, C) for a consonant C of that cell contour (the
    /// contours' scales cancel). `None` when the sum underflows (the caller combines instead).
    pub(super) fn agreement(
        &mut self,
        tracker: &Tracker,
        usable: &[Option<Usable>],
        group: GroupMask,
        cell_max: &[f64],
    ) -> Option<f64> {
        self.grow(tracker, usable, group)?;
        let tuples = self.chain.last()?;
        let top = &mut self.top;
        top.clear();
        top.resize(tuples.product.len(), 0.0);
        for (&t, &c) in tuples.id.iter().zip(cell_max) {
            top[t as usize] = top[t as usize].max(c);
        }
        let (mut agree, mut total) = (0.0, 0.0);
        for (&p, &c) in tuples.product.iter().zip(top.iter()) {
            agree += p * c;
            total += p;
        }
        if !tuples.positive.iter().any(|&p| p) {
            return Some(0.0);
        }
        (total.is_finite() && total > 1e-280).then_some(agree / total)
    }

    /// Keeps the longest prefix of `group` already built.
    fn keep_prefixes(&mut self, group: GroupMask) {
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
            self.spare.extend(self.chain.pop());
        }
    }

    /// Builds the chain up to `group` from its longest prefix already built; `None` when a
    /// member is not usable.
    fn grow(
        &mut self,
        tracker: &Tracker,
        usable: &[Option<Usable>],
        group: GroupMask,
    ) -> Option<()> {
        self.keep_prefixes(group);
        let mut built = self.chain.last().map_or(0, |t| t.group);
        for i in members(group & !built) {
            built |= 1 << i;
            let next = self.extend(tracker, built, i, usable[i].as_ref()?);
            self.chain.push(next);
        }
        Some(())
    }

    /// The tuples of `group`: the last group of the chain (or none) with feature `i` added.
    fn extend(
        &mut self,
        tracker: &Tracker,
        group: GroupMask,
        i: usize,
        feature: &Usable,
    ) -> Tuples {
        let states = tracker.to_cells[i].assignment();
        let n = tracker.to_cells[i].coarse_size();
        let cells = states.len();
        let (parent_id, parent_count) = match self.chain.last() {
            Some(t) => (Some(&t.id), t.product.len()),
            None => (None, 1),
        };
        // Buffers from popped tuples and the scratch table (all u32::MAX between calls):
        // a search's walk allocates nothing after its first groups.
        let mut next = self.spare.pop().unwrap_or_else(|| Tuples {
            group,
            id: Vec::with_capacity(cells),
            product: Vec::with_capacity(cells),
            positive: Vec::with_capacity(cells),
        });
        next.group = group;
        let Tuples {
            id,
            product,
            positive,
            ..
        } = &mut next;
        id.clear();
        product.clear();
        positive.clear();
        let remap = &mut self.remap;
        if remap.len() < parent_count * n {
            remap.resize(parent_count * n, u32::MAX);
        }
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
        for (u, &su) in states.iter().enumerate() {
            remap[parent_id.map_or(0, |ids| ids[u] as usize) * n + su] = u32::MAX;
        }
        next
    }
}
