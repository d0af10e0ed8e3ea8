//! The Bayesian group level of `Tracker::bayesian_level`, grown one feature at a time: the
//! selection's search walks groups in lexicographic order, so a group's state tuples are its
//! prefix's tuples refined by one feature (one pass over the cells instead of one per member).
//! Every product and sum is taken in the same order as there, so the levels are bit-identical.

use super::cell_products::CellProducts;
use super::group_search::{members, GroupMask, LevelBounds};
use super::tracker::{Tracker, Usable};

/// The distinct state tuples of one group on the cells.
#[derive(Default)]
struct Tuples {
    group: GroupMask,
    /// Each cell's tuple, numbered by first occurrence.
    id: Vec<u32>,
    /// Each tuple's product of the members' scaled contours, in member order.
    product: Vec<f64>,
    /// Whether every factor of that product is positive.
    positive: Vec<bool>,
    /// Σ ln(scale) of the members, summed in member order.
    log_scale: f64,
}

/// The chain of prefixes of the last group asked for, each with its tuples, and the buffers of
/// dropped ones for reuse (the search asks for thousands of groups a frame).
#[derive(Default)]
pub(super) struct TupleStack {
    chain: Vec<Tuples>,
    /// Popped tuples whose buffers the next ones reuse.
    spare: Vec<Tuples>,
    /// Tuple numbers by (parent tuple, state) while a group is numbered (`u32::MAX`: none yet;
    /// all of it between groups).
    remap: Vec<u32>,
    /// Parent tuple and state of each new tuple, in order of first occurrence.
    firsts: Vec<(u32, u32)>,
    /// The largest cell value per tuple ([`TupleStack::agreement`]).
    top: Vec<f64>,
    /// Groups that leave out a few features, by their products on the cells.
    products: CellProducts,
}

/// The largest table of state pairs [`TupleStack::small_agreement`] fills (or twice the
/// cells, if more): beyond it, growing the pair's tuples costs less.
const SMALL_TABLE: usize = 4096;

/// Σ p·c over Σ p of a group's tuples: 0 when no tuple is positive, `None` when the total is
/// not a finite number above 1e-280.
/// Whether `p` is `group`'s members up to `p`'s last one: a chain built member by member
/// can be grown from it.
pub(super) fn is_prefix(p: GroupMask, group: GroupMask) -> bool {
    let top = 63 - p.leading_zeros();
    let below = if top == 63 {
        GroupMask::MAX
    } else {
        (2 << top) - 1
    };
    group & below == p
}

fn agreement_share(agree: f64, total: f64, positive: bool) -> Option<f64> {
    if !positive {
        return Some(0.0);
    }
    (total.is_finite() && total > 1e-280).then_some(agree / total)
}

thread_local! {
    /// The buffers the last frame on this thread left, for the next one (a frame's search asks
    /// for thousands of groups; without this each frame allocated its buffers anew).
    static KEPT: std::cell::RefCell<TupleStack> = std::cell::RefCell::new(TupleStack::default());
}

impl TupleStack {
    /// An empty stack with the buffers this thread's last frame gave back.
    pub(super) fn reused() -> Self {
        KEPT.with(|kept| std::mem::take(&mut *kept.borrow_mut()))
    }

    /// Gives the buffers back for the next frame on this thread; no tuple is kept, so every
    /// group of the next frame is built again.
    pub(super) fn recycle(mut self) {
        let chain = std::mem::take(&mut self.chain);
        self.spare.extend(chain);
        self.products.recycle();
        // A frame that is being dropped while the thread ends has nowhere to give them back.
        let _ = KEPT.try_with(|kept| {
            if let Ok(mut kept) = kept.try_borrow_mut() {
                *kept = self;
            }
        });
    }

    /// The Bayesian level of `group` (at least two usable features), or `None` when the sum
    /// underflows and the general path must decide, as `Tracker::bayesian_level`.
    pub(super) fn level(
        &mut self,
        tracker: &Tracker,
        usable: &[Option<Usable>],
        group: GroupMask,
    ) -> Option<f64> {
        // Groups leaving out a few features first: their products on the cells are grown
        // apart from the tuples, which the splitting search may never need.
        if let Some(level) = self.products.level(tracker, usable, group) {
            return level;
        }
        self.keep_prefixes(group);
        // Nothing to grow from and a large group (a maximum clique, before any walk): one
        // direct computation is cheaper than building every prefix.
        if self.chain.is_empty() && group.count_ones() > 4 {
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
        Some((-(s.ln() + tuples.log_scale)).max(0.0))
    }

    /// Bounds on the Bayesian level of `group` from the products on the cells
    /// ([`CellProducts::bounds`]).
    pub(super) fn bounds(
        &mut self,
        tracker: &Tracker,
        usable: &[Option<Usable>],
        group: GroupMask,
        walked: GroupMask,
    ) -> Option<LevelBounds> {
        let (floor, ceiling) = self.products.bounds(tracker, usable, group, walked)?;
        Some(LevelBounds { floor, ceiling })
    }

    /// The levels of `groups` that take the products on the cells, several at once
    /// ([`CellProducts::levels`]); `None` for the others.
    pub(super) fn levels_on_cells(
        &mut self,
        tracker: &Tracker,
        usable: &[Option<Usable>],
        groups: &[GroupMask],
    ) -> Vec<Option<Option<f64>>> {
        self.products.levels(tracker, usable, groups)
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
        if matches!(group.count_ones(), 1 | 2) {
            if let Some(agree) = self.small_agreement(tracker, usable, group, cell_max) {
                return agree;
            }
        }
        self.grown_agreement(tracker, usable, group, cell_max)
    }

    /// [`TupleStack::agreement`] of one feature or a pair without growing its tuples: the model
    /// lists them in order of first occurrence on the cells (the order the grown ones are
    /// numbered in), and their products are the same (1·c is c; then c_i·c_j), so the sums are
    /// the same bits; each tuple's largest cell value comes from a table over the state pairs.
    /// `None` (outer) when the table would be large: grow instead. `group` holds one or two
    /// features.
    pub(super) fn small_agreement(
        &mut self,
        tracker: &Tracker,
        usable: &[Option<Usable>],
        group: GroupMask,
        cell_max: &[f64],
    ) -> Option<Option<f64>> {
        let (i, j) = (
            group.trailing_zeros() as usize,
            63 - group.leading_zeros() as usize,
        );
        let (a, b) = match (usable.get(i)?, usable.get(j)?) {
            (Some(a), Some(b)) => (a, b),
            _ => return Some(None),
        };
        let states_i = tracker.to_cells[i].assignment();
        let top = &mut self.top;
        top.clear();
        let (mut agree, mut total, mut positive) = (0.0, 0.0, false);
        if i == j {
            top.resize(tracker.to_cells[i].coarse_size(), 0.0);
            for (&s, &c) in states_i.iter().zip(cell_max) {
                top[s] = top[s].max(c);
            }
            for &s in tracker.pair_tuples.states(i) {
                let p = a.contour[s as usize];
                agree += p * top[s as usize];
                total += p;
                positive |= p > 0.0;
            }
        } else {
            let nb = tracker.to_cells[j].coarse_size();
            let size = tracker.to_cells[i].coarse_size() * nb;
            if size > SMALL_TABLE.max(2 * cell_max.len()) {
                return None;
            }
            let tuples = tracker.pair_tuples.of(i, j);
            if let Some(ids) = tracker.pair_tuples.cell_tuples(i, j, &tracker.to_cells) {
                // The same maxima and the same sum, by tuple number.
                top.resize(tuples.len(), 0.0);
                for (&t, &c) in ids.iter().zip(cell_max) {
                    let t = &mut top[usize::from(t)];
                    *t = t.max(c);
                }
                for (&(x, y), &m) in tuples.iter().zip(top.iter()) {
                    let (ca, cb) = (a.contour[x as usize], b.contour[y as usize]);
                    let p = ca * cb;
                    agree += p * m;
                    total += p;
                    positive |= ca > 0.0 && cb > 0.0;
                }
                return Some(agreement_share(agree, total, positive));
            }
            top.resize(size, 0.0);
            let states_j = tracker.to_cells[j].assignment();
            for ((&x, &y), &c) in states_i.iter().zip(states_j).zip(cell_max) {
                let t = &mut top[x * nb + y];
                *t = t.max(c);
            }
            for &(x, y) in tuples {
                let (ca, cb) = (a.contour[x as usize], b.contour[y as usize]);
                let p = ca * cb;
                agree += p * top[x as usize * nb + y as usize];
                total += p;
                positive |= ca > 0.0 && cb > 0.0;
            }
        }
        Some(agreement_share(agree, total, positive))
    }

    /// [`TupleStack::agreement`] on the group's grown tuples.
    pub(super) fn grown_agreement(
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
        agreement_share(agree, total, tuples.positive.iter().any(|&p| p))
    }

    /// Keeps the longest prefix of `group` already built.
    fn keep_prefixes(&mut self, group: GroupMask) {
        while self
            .chain
            .last()
            .is_some_and(|t| !is_prefix(t.group, group))
        {
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
        let mut next = self.spare.pop().unwrap_or_default();
        next.group = group;
        next.id.clear();
        next.product.clear();
        next.positive.clear();
        let parent = self.chain.last();
        let parent_count = parent.map_or(1, |t| t.product.len());
        // The sum of ln(scale) in member order, as `members(..).map(ln).sum()` adds it.
        next.log_scale = parent.map_or(0.0, |t| t.log_scale) + feature.scale.ln();
        if let Some(t) = parent.filter(|t| t.product.len() == states.len()) {
            // Every cell has its own tuple, so the parent numbers cell k as k (by first
            // occurrence) and so does the group: the products in cell order, no numbering.
            next.id.extend(0..states.len() as u32);
            for ((&before, &all_positive), &su) in t.product.iter().zip(&t.positive).zip(states) {
                let c = feature.contour[su];
                next.product.push(before * c);
                next.positive.push(all_positive && c > 0.0);
            }
            return next;
        }
        // Every slot is `u32::MAX` between calls (the ones used are reset below): only a larger
        // table is filled, not the whole of it each time.
        if self.remap.len() < parent_count * n {
            self.remap.resize(parent_count * n, u32::MAX);
        }
        next.id.resize(states.len(), 0);
        // Number the tuples in one tight pass, then take the products of the new ones (in the
        // same order, so the same bits).
        let (remap, firsts) = (&mut self.remap, &mut self.firsts);
        firsts.clear();
        let mut number = |p: usize, su: usize| {
            let slot = &mut remap[p * n + su];
            if *slot == u32::MAX {
                *slot = firsts.len() as u32;
                firsts.push((p as u32, su as u32));
            }
            *slot
        };
        match parent {
            Some(t) => {
                for ((out, &p), &su) in next.id.iter_mut().zip(&t.id).zip(states) {
                    *out = number(p as usize, su);
                }
            }
            None => {
                for (out, &su) in next.id.iter_mut().zip(states) {
                    *out = number(0, su);
                }
            }
        }
        for &(p, su) in self.firsts.iter() {
            let c = feature.contour[su as usize];
            let (before, all_positive) = match parent {
                Some(t) => (t.product[p as usize], t.positive[p as usize]),
                None => (1.0, true),
            };
            next.product.push(before * c);
            next.positive.push(all_positive && c > 0.0);
            self.remap[p as usize * n + su as usize] = u32::MAX;
        }
        next
    }
}
