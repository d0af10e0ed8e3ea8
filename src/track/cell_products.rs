//! The Bayesian level of a group that leaves out only a few of the model's features, without
//! numbering its state tuples: every cell of a tuple has the tuple's product (the same factors in
//! the same member order, so the same bits), and a cell repeats an earlier tuple exactly when it
//! differs from an earlier cell only in features left out. Those pairs of cells are listed once
//! per model, by the features they differ in, so a group's repeated cells are a few look-ups.
//! The sum over the other cells, ascending, is the sum over the tuples in order of first
//! occurrence that [`super::tuples::TupleStack`] takes: the levels are bit-identical.
//!
//! The splitting policy asks for thousands of groups of nearly every feature a frame (one or two
//! at fault split it into many alternatives); numbering their tuples was most of its time.

use super::group_search::{members, GroupMask, MaskMap};
use super::tracker::{Tracker, Usable};
use super::tuples::is_prefix;
use crate::evidence::Refining;
use crate::simd::with_avx;

/// Most features a group may leave out to take this path (a group's repeated cells are the union
/// over the subsets of those left out: up to 2^5 look-ups).
pub(super) const MAX_LEFT_OUT: u32 = 5;

/// Fewest features of a model for this path: with few features a group leaving out a few has
/// few tuples, which numbering finds faster than a pass over the cells (the 8 × 400 faulty frame
/// of `benches/track.rs` took 1.5× longer).
const MIN_FEATURES: usize = 16;

/// Most cells for which the pairs of cells are compared (once per model; quadratic).
const MAX_CELLS: usize = 4096;

/// Per set of features (at most [`MAX_LEFT_OUT`]), the cells whose states equal an earlier
/// cell's in every other feature.
#[derive(Clone, Debug)]
pub(super) struct NearRepeats {
    by_difference: MaskMap<Vec<u32>>,
    features: usize,
}

impl NearRepeats {
    /// The pairs of cells of `to_cells` that differ in at most [`MAX_LEFT_OUT`] features; `None`
    /// below [`MIN_FEATURES`] or beyond 64 features, or beyond [`MAX_CELLS`] cells.
    pub(super) fn new(to_cells: &[Refining]) -> Option<Self> {
        let features = to_cells.len();
        let cells = to_cells.first().map_or(0, |r| r.assignment().len());
        if !(MIN_FEATURES..=64).contains(&features) || cells > MAX_CELLS {
            return None;
        }
        // Each cell's states, feature by feature, in one row.
        let rows: Vec<u32> = (0..cells)
            .flat_map(|u| to_cells.iter().map(move |r| r.assignment()[u] as u32))
            .collect();
        let row = |u: usize| &rows[u * features..(u + 1) * features];
        let mut by_difference: MaskMap<Vec<u32>> = MaskMap::default();
        for u in 1..cells {
            for v in 0..u {
                let mut differ: GroupMask = 0;
                for (i, (a, b)) in row(u).iter().zip(row(v)).enumerate() {
                    if a != b {
                        differ |= 1 << i;
                        if differ.count_ones() > MAX_LEFT_OUT {
                            break;
                        }
                    }
                }
                if differ.count_ones() <= MAX_LEFT_OUT {
                    let list = by_difference.entry(differ).or_default();
                    if list.last() != Some(&(u as u32)) {
                        list.push(u as u32);
                    }
                }
            }
        }
        Some(NearRepeats {
            by_difference,
            features,
        })
    }

    /// The model's features `group` leaves out, when there are at most [`MAX_LEFT_OUT`].
    fn left_out(&self, group: GroupMask) -> Option<GroupMask> {
        let all = if self.features == 64 {
            GroupMask::MAX
        } else {
            (1 << self.features) - 1
        };
        let out = all & !group;
        (out.count_ones() <= MAX_LEFT_OUT).then_some(out)
    }

    /// Calls `repeat` with each cell whose states on every feature but those `left_out` are
    /// an earlier cell's (a cell may come more than once).
    fn for_each_repeat(&self, left_out: GroupMask, mut repeat: impl FnMut(usize)) {
        // Every non-empty subset of the features left out.
        let mut differ = left_out;
        while differ != 0 {
            if let Some(cells) = self.by_difference.get(&differ) {
                for &u in cells {
                    repeat(u as usize);
                }
            }
            differ = (differ - 1) & left_out;
        }
    }
}

/// One group's product of the members' scaled contours on every cell.
#[derive(Default)]
struct Prefix {
    group: GroupMask,
    product: Vec<f64>,
    /// Σ ln(scale) of the members, summed in member order.
    log_scale: f64,
}

/// Levels summed side by side by [`CellProducts::levels`]: each sum's adds wait for the one
/// before (about four cycles each), independent sums do not wait for each other.
const LANES: usize = 8;

/// Most products of upper parts of groups kept a frame for bounds (8 KB each on the bench's
/// 985 cells): beyond, they are dropped and built again.
const MAX_TAILS: usize = 128;

/// The chain of prefixes of the last group asked for, products per cell, and buffers for reuse.
#[derive(Default)]
pub(super) struct CellProducts {
    chain: Vec<Prefix>,
    spare: Vec<Prefix>,
    /// The frame's scaled contour of each usable feature on every cell (`cells` values per
    /// feature, in feature order; empty until first asked for and for unusable features).
    contour: Vec<f64>,
    cells: usize,
    /// Per cell, the features whose scaled contour is not positive there.
    not_positive: Vec<GroupMask>,
    /// Whether every usable feature's contour is ≥ 0 on every cell (what the bounds assume).
    nonnegative: bool,
    /// Whether `contour` holds this frame's values.
    ready: bool,
    repeat: Vec<bool>,
    /// Per cell, 1, or 0 for a repeat of the last group asked for (`marked`: those cells).
    keep: Vec<f64>,
    marked: Vec<u32>,
    /// `cells` times 1.
    ones: Vec<f64>,
    /// ln(scale) of each feature (NaN when not usable).
    scale_ln: Vec<f64>,
    /// For bounds: products of sets of features (the part of a group above its longest built
    /// prefix), in any order, by set; `tails_used` of `tail_store` hold this frame's.
    tails: MaskMap<usize>,
    tail_store: Vec<Prefix>,
    tails_used: usize,
    /// [`CellProducts::levels`]: the terms of [`LANES`] groups (+0 for a repeat), group by group.
    terms: Vec<f64>,
}

/// Lane and ln-scale of the groups waiting in [`CellProducts::levels`], by their index.
type Waiting = Vec<(usize, f64)>;

impl CellProducts {
    /// The Bayesian level of `group` (at least two usable features) as
    /// `TupleStack::level` gives it: `Some(None)` when the sum underflows; `None` when the group
    /// leaves out too many features, the model has no [`NearRepeats`] or a member is not usable.
    pub(super) fn level(
        &mut self,
        tracker: &Tracker,
        usable: &[Option<Usable>],
        group: GroupMask,
    ) -> Option<Option<f64>> {
        let near = tracker.pair_tuples.near_repeats(&tracker.to_cells)?;
        let left_out = near.left_out(group)?;
        if members(group).any(|i| usable.get(i).is_none_or(Option::is_none)) {
            return None;
        }
        self.prepare(tracker, usable);
        let k = self.products_of(usable, group)?;
        let prefix = &self.chain[k];
        // A tuple's factors are its cells' factors.
        if self.not_positive.iter().all(|&m| m & group != 0) {
            return Some(Some(f64::INFINITY));
        }
        self.repeat.clear();
        self.repeat.resize(prefix.product.len(), false);
        near.for_each_repeat(left_out, |u| self.repeat[u] = true);
        let mut s = 0.0;
        for (&p, &repeat) in prefix.product.iter().zip(&self.repeat) {
            if !repeat {
                s += p;
            }
        }
        Some(level_of_sum(s, prefix.log_scale))
    }

    /// [`CellProducts::level`] of each of `groups` (of three features or more; `None` for
    /// pairs), [`LANES`] sums side by side: each still adds its cells in order, skipped cells
    /// adding +0 (a sum that starts at +0 and adds no −0 is never −0, and s + (+0) is s), so
    /// the bits are the same. Asked in lexicographic order, consecutive groups share most of
    /// their chain.
    pub(super) fn levels(
        &mut self,
        tracker: &Tracker,
        usable: &[Option<Usable>],
        groups: &[GroupMask],
    ) -> Vec<Option<Option<f64>>> {
        let mut out = vec![None; groups.len()];
        let Some(near) = tracker.pair_tuples.near_repeats(&tracker.to_cells) else {
            return out;
        };
        let mut waiting: Waiting = Vec::with_capacity(LANES);
        for (index, &group) in groups.iter().enumerate() {
            let Some(left_out) = near.left_out(group) else {
                continue;
            };
            if group.count_ones() < 3
                || members(group).any(|i| usable.get(i).is_none_or(Option::is_none))
            {
                continue;
            }
            self.prepare(tracker, usable);
            let Some(k) = self.products_of(usable, group) else {
                continue;
            };
            if self.not_positive.iter().all(|&m| m & group != 0) {
                out[index] = Some(Some(f64::INFINITY));
                continue;
            }
            let cells = self.cells;
            self.keep_cells(near, left_out);
            self.terms.resize(cells * LANES, 0.0);
            let lane = waiting.len();
            let prefix = &self.chain[k];
            let terms = &mut self.terms[lane * cells..(lane + 1) * cells];
            mask(terms, &prefix.product, &self.keep);
            waiting.push((index, prefix.log_scale));
            if waiting.len() == LANES {
                self.sum_waiting(&mut waiting, &mut out);
            }
        }
        self.sum_waiting(&mut waiting, &mut out);
        out
    }

    /// The levels of the `waiting` groups from their lanes of `rows` (other lanes ignored).
    fn sum_waiting(&self, waiting: &mut Waiting, out: &mut [Option<Option<f64>>]) {
        if waiting.is_empty() {
            return;
        }
        let sums = lane_sums(&self.terms, self.cells);
        for (&(index, log_scale), &s) in waiting.iter().zip(&sums) {
            out[index] = Some(level_of_sum(s, log_scale));
        }
        waiting.clear();
    }

    /// Bounds (floor, ceiling) on the Bayesian level of `group` (at least two features, all
    /// usable), from its products on the cells taken in any order and summed in eight lanes
    /// (a relative ~1e-13 from the level's sum on the bench's cells). A group leaving out a
    /// few features skips its repeated cells as the level does: both bounds are that estimate.
    /// Otherwise the sum over every cell, not every tuple (each cell of a tuple has its
    /// product: the sum can only grow, the level only fall), is a floor, and the ceiling +∞.
    /// The chain is grown to `walked` (a prefix of `group`; 0: the group itself), the rest of
    /// the group taken from products of upper parts kept a frame. `None` where the sum may underflow, a contour
    /// is negative or NaN, or the model has no [`NearRepeats`] (few features: numbering costs
    /// less).
    pub(super) fn bounds(
        &mut self,
        tracker: &Tracker,
        usable: &[Option<Usable>],
        group: GroupMask,
        walked: GroupMask,
    ) -> Option<(f64, f64)> {
        let near = tracker.pair_tuples.near_repeats(&tracker.to_cells)?;
        if group.count_ones() < 2
            || members(group).any(|i| usable.get(i).is_none_or(Option::is_none))
        {
            return None;
        }
        self.prepare(tracker, usable);
        if !self.nonnegative {
            return None;
        }
        // Without a walk (a maximal clique), the group's own products: its level, if asked
        // next, takes them as they are.
        let walked = if walked == 0 { group } else { walked };
        if is_prefix(walked, group) {
            self.products_of(usable, walked)?;
        }
        let longest = self.chain.iter().rposition(|t| is_prefix(t.group, group));
        let rest = longest.map_or(group, |k| group & !self.chain[k].group);
        let tail = if rest == 0 {
            None
        } else {
            Some(self.tail_of(rest)?)
        };
        let left_out = near.left_out(group);
        if let Some(out) = left_out {
            self.keep_cells(near, out);
        }
        let head = longest.map_or(&self.ones, |k| &self.chain[k].product);
        let tail = tail.map_or(&self.ones, |k| &self.tail_store[k].product);
        let keep = if left_out.is_some() {
            &self.keep
        } else {
            &self.ones
        };
        let s = sum_of_products(head, tail, keep);
        let log_scale = members(group).fold(0.0, |sum, i| sum + self.scale_ln[i]);
        if !(s.is_finite() && s > 1e-250) {
            return None;
        }
        let estimate = (-(s.ln() + log_scale)).max(0.0);
        let ceiling = if left_out.is_some() {
            estimate
        } else {
            f64::INFINITY
        };
        Some((estimate, ceiling))
    }

    /// `keep` for a group leaving out `left_out`: 0 on its repeated cells.
    fn keep_cells(&mut self, near: &NearRepeats, left_out: GroupMask) {
        for &u in &self.marked {
            self.keep[u as usize] = 1.0;
        }
        self.marked.clear();
        let (keep, marked) = (&mut self.keep, &mut self.marked);
        near.for_each_repeat(left_out, |u| {
            keep[u] = 0.0;
            marked.push(u as u32);
        });
    }

    /// The index in `tail_store` of the products of `set` (not empty), built on the longest
    /// upper part of it already kept, one member at a time downwards.
    fn tail_of(&mut self, set: GroupMask) -> Option<usize> {
        if let Some(&k) = self.tails.get(&set) {
            return Some(k);
        }
        if self.tails_used >= MAX_TAILS {
            self.tails.clear();
            self.tails_used = 0;
        }
        let mut pending = [0 as GroupMask; 64];
        let mut count = 0;
        let mut upper = set;
        let mut base = None;
        while upper != 0 {
            if let Some(&k) = self.tails.get(&upper) {
                base = Some(k);
                break;
            }
            pending[count] = upper;
            count += 1;
            upper &= upper - 1;
        }
        for &part in pending[..count].iter().rev() {
            let low = part.trailing_zeros() as usize;
            let slot = self.tails_used;
            self.tails_used += 1;
            if self.tail_store.len() <= slot {
                self.tail_store.push(Prefix::default());
            }
            let mut tail = std::mem::take(&mut self.tail_store[slot]);
            tail.group = part;
            tail.product.resize(self.cells, 0.0);
            let contour = &self.contour[low * self.cells..(low + 1) * self.cells];
            let above = base.map_or(&self.ones, |k| &self.tail_store[k].product);
            multiply(&mut tail.product, contour, above);
            self.tail_store[slot] = tail;
            self.tails.insert(part, slot);
            base = Some(slot);
        }
        base
    }

    /// Drops every prefix and the frame's values (the next frame's differ), keeping the buffers.
    pub(super) fn recycle(&mut self) {
        let chain = std::mem::take(&mut self.chain);
        self.spare.extend(chain);
        self.ready = false;
    }

    /// The frame's contours on the cells, once a frame.
    fn prepare(&mut self, tracker: &Tracker, usable: &[Option<Usable>]) {
        if self.ready {
            return;
        }
        self.ready = true;
        self.cells = tracker.cell_count();
        self.tails.clear();
        self.tails_used = 0;
        self.ones.clear();
        self.ones.resize(self.cells, 1.0);
        self.keep.clear();
        self.keep.resize(self.cells, 1.0);
        self.marked.clear();
        self.terms.clear();
        self.scale_ln.clear();
        (self.scale_ln).extend(
            usable
                .iter()
                .map(|f| f.as_ref().map_or(f64::NAN, |f| f.scale.ln())),
        );
        self.contour.clear();
        self.not_positive.clear();
        self.not_positive.resize(self.cells, 0);
        self.nonnegative = true;
        for (i, feature) in usable.iter().enumerate() {
            let states = tracker.to_cells[i].assignment();
            match feature {
                Some(f) => {
                    for (u, &su) in states.iter().enumerate() {
                        let c = f.contour[su];
                        self.contour.push(c);
                        // NaN is not positive either.
                        if c.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
                            self.not_positive[u] |= 1 << i;
                            self.nonnegative &= c == 0.0;
                        }
                    }
                }
                None => self
                    .contour
                    .extend(std::iter::repeat_n(f64::NAN, self.cells)),
            }
        }
    }

    /// The products of `group` (usable members): a prefix of the chain's last group as it is
    /// (the search asks for a group after its look-ahead), or the chain grown to it.
    fn products_of(&mut self, usable: &[Option<Usable>], group: GroupMask) -> Option<usize> {
        let k = self.chain.iter().rposition(|t| t.group == group);
        k.or_else(|| {
            self.grow(usable, group);
            self.chain.len().checked_sub(1)
        })
    }

    /// Builds the chain up to `group` (usable members) from its longest prefix already built.
    fn grow(&mut self, usable: &[Option<Usable>], group: GroupMask) {
        while self
            .chain
            .last()
            .is_some_and(|t| !is_prefix(t.group, group))
        {
            self.spare.extend(self.chain.pop());
        }
        let mut built = self.chain.last().map_or(0, |t| t.group);
        for i in members(group & !built) {
            built |= 1 << i;
            let scale = usable[i].as_ref().map_or(f64::NAN, |f| f.scale);
            let contour = &self.contour[i * self.cells..(i + 1) * self.cells];
            let mut next = self.spare.pop().unwrap_or_default();
            next.group = built;
            next.product.resize(self.cells, 0.0);
            match self.chain.last() {
                Some(t) => {
                    next.log_scale = t.log_scale + scale.ln();
                    multiply(&mut next.product, &t.product, contour);
                }
                None => {
                    // 0 + ln(scale) and 1·c, as the tuples' first member is taken.
                    next.log_scale = 0.0 + scale.ln();
                    multiply(&mut next.product, &self.ones, contour);
                }
            }
            self.chain.push(next);
        }
    }
}

/// A Bayesian level from the sum of its tuples' products and Σ ln(scale): `None` when the sum
/// is NaN or may have underflowed.
fn level_of_sum(s: f64, log_scale: f64) -> Option<f64> {
    if s.is_nan() || s <= 1e-280 {
        return None;
    }
    Some((-(s.ln() + log_scale)).max(0.0))
}

with_avx!(
    /// [`multiply_in`], with AVX where the processor has it (a product is the same bits at any
    /// vector width).
    fn multiply(out: &mut [f64], a: &[f64], b: &[f64]) -> () = multiply_in
);

/// out = a·b cell by cell.
#[inline(always)]
fn multiply_in(out: &mut [f64], a: &[f64], b: &[f64]) {
    for ((o, &x), &y) in out.iter_mut().zip(a).zip(b) {
        *o = x * y;
    }
}

with_avx!(
    /// [`sum_of_products_in`], with AVX where the processor has it.
    fn sum_of_products(a: &[f64], b: &[f64], keep: &[f64]) -> f64 = sum_of_products_in
);

/// Σ a·b·keep in eight lanes (bounds only: the levels' sums are sequential). One sum: with
/// two, the compiler paired them instead of vectorising each.
#[inline(always)]
fn sum_of_products_in(a: &[f64], b: &[f64], keep: &[f64]) -> f64 {
    let n = a.len().min(b.len()).min(keep.len());
    let (a, a_rest) = a[..n].as_chunks::<8>();
    let (b, b_rest) = b[..n].as_chunks::<8>();
    let (keep, keep_rest) = keep[..n].as_chunks::<8>();
    let mut sums = [0.0; 8];
    for ((x, y), k) in a.iter().zip(b).zip(keep) {
        for l in 0..8 {
            sums[l] += x[l] * y[l] * k[l];
        }
    }
    let rest: f64 = (a_rest.iter().zip(b_rest).zip(keep_rest))
        .map(|((x, y), k)| x * y * k)
        .sum();
    sums.iter().sum::<f64>() + rest
}

with_avx!(
    /// [`mask_in`], with AVX where the processor has it.
    fn mask(out: &mut [f64], values: &[f64], keep: &[f64]) -> () = mask_in
);

/// out = each value, or +0 where `keep` is 0.
#[inline(always)]
fn mask_in(out: &mut [f64], values: &[f64], keep: &[f64]) {
    for ((o, &v), &k) in out.iter_mut().zip(values).zip(keep) {
        *o = if k == 0.0 { 0.0 } else { v };
    }
}

with_avx!(
    /// [`lane_sums_in`], with AVX where the processor has it.
    fn lane_sums(terms: &[f64], cells: usize) -> [f64; LANES] = lane_sums_in
);

/// Per lane, the sum of its `cells` terms (`terms` holds [`LANES`] groups' terms, group by
/// group), from +0 in cell order: the lanes' adds interleave, each lane's in its own order.
#[inline(always)]
fn lane_sums_in(terms: &[f64], cells: usize) -> [f64; LANES] {
    let mut sums = [0.0; LANES];
    if terms.len() < cells * LANES {
        return [f64::NAN; LANES];
    }
    let lanes: [&[f64]; LANES] = std::array::from_fn(|l| &terms[l * cells..(l + 1) * cells]);
    for u in 0..cells {
        for (s, lane) in sums.iter_mut().zip(&lanes) {
            *s += lane[u];
        }
    }
    sums
}
