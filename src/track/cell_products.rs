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

    /// Marks in `repeat` (false on entry, one entry per cell) the cells whose states on every
    /// feature but those `left_out` are an earlier cell's.
    fn mark(&self, left_out: GroupMask, repeat: &mut [bool]) {
        // Every non-empty subset of the features left out.
        let mut differ = left_out;
        while differ != 0 {
            if let Some(cells) = self.by_difference.get(&differ) {
                for &u in cells {
                    repeat[u as usize] = true;
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
    /// Whether `contour` holds this frame's values.
    ready: bool,
    repeat: Vec<bool>,
    /// The frame's usable features.
    usable_mask: GroupMask,
    /// Per feature j (and one past the last), the product on every cell of the usable
    /// features' contours from j on, and the sum of their ln(scale) (floors only: built on
    /// first use in a frame).
    suffix: Vec<f64>,
    suffix_log_scale: Vec<f64>,
    suffix_ready: bool,
    /// ln(scale) of each feature (NaN when not usable).
    scale_ln: Vec<f64>,
}

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
        near.mark(left_out, &mut self.repeat);
        let mut s = 0.0;
        for (&p, &repeat) in prefix.product.iter().zip(&self.repeat) {
            if !repeat {
                s += p;
            }
        }
        if s.is_nan() || s <= 1e-280 {
            return Some(None);
        }
        Some(Some((-(s.ln() + prefix.log_scale)).max(0.0)))
    }

    /// A floor of the Bayesian level of `group` (at least two features, all usable), whatever it
    /// leaves out: the sum over every cell instead of the first of each tuple (each cell of a
    /// tuple has its product: the sum can only grow, the level only fall), in eight lanes (its
    /// rounding differs from the level's by a relative ~2·cells·ε). `None` where the level may
    /// underflow, or the model has no [`NearRepeats`] (few features: numbering costs less).
    pub(super) fn floor(
        &mut self,
        tracker: &Tracker,
        usable: &[Option<Usable>],
        group: GroupMask,
    ) -> Option<f64> {
        tracker.pair_tuples.near_repeats(&tracker.to_cells)?;
        if group.count_ones() < 2
            || members(group).any(|i| usable.get(i).is_none_or(Option::is_none))
        {
            return None;
        }
        self.prepare(tracker, usable);
        // The splitting search's look-ahead is a built group with every usable feature above
        // it: the prefix's products times the suffix's, without growing the chain.
        let longest = self.chain.iter().rposition(|t| is_prefix(t.group, group));
        let rest = longest.map_or(group, |k| group & !self.chain[k].group);
        let from = rest.trailing_zeros();
        let (s, log_scale) = match longest {
            Some(k) if rest != 0 && rest == self.usable_mask & !((1 << from) - 1) => {
                self.prepare_suffix();
                let j = from as usize;
                let suffix = &self.suffix[j * self.cells..(j + 1) * self.cells];
                let prefix = &self.chain[k];
                let s = lanes_dot(&prefix.product, suffix);
                (s, prefix.log_scale + self.suffix_log_scale[j])
            }
            _ => {
                let k = self.products_of(usable, group)?;
                let prefix = &self.chain[k];
                (lanes_dot(&prefix.product, &[]), prefix.log_scale)
            }
        };
        (s.is_finite() && s > 1e-250).then(|| (-(s.ln() + log_scale)).max(0.0))
    }

    /// The suffix products, once a frame (after [`CellProducts::prepare`]).
    fn prepare_suffix(&mut self) {
        if self.suffix_ready {
            return;
        }
        self.suffix_ready = true;
        let (cells, features) = (self.cells, self.contour.len() / self.cells.max(1));
        self.suffix.clear();
        self.suffix.resize((features + 1) * cells, 1.0);
        self.suffix_log_scale.clear();
        self.suffix_log_scale.resize(features + 1, 0.0);
        for j in (0..features).rev() {
            let (head, tail) = self.suffix.split_at_mut((j + 1) * cells);
            let here = &mut head[j * cells..];
            if self.usable_mask >> j & 1 == 1 {
                let contour = &self.contour[j * cells..(j + 1) * cells];
                for ((h, &t), &c) in here.iter_mut().zip(&tail[..cells]).zip(contour) {
                    *h = t * c;
                }
                self.suffix_log_scale[j] = self.suffix_log_scale[j + 1] + self.scale_ln[j];
            } else {
                here.copy_from_slice(&tail[..cells]);
                self.suffix_log_scale[j] = self.suffix_log_scale[j + 1];
            }
        }
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
        self.suffix_ready = false;
        self.cells = tracker.cell_count();
        self.usable_mask = (usable.iter().enumerate())
            .filter(|(_, f)| f.is_some())
            .fold(0, |m, (i, _)| m | 1 << i);
        self.scale_ln.clear();
        (self.scale_ln).extend(
            usable
                .iter()
                .map(|f| f.as_ref().map_or(f64::NAN, |f| f.scale.ln())),
        );
        self.contour.clear();
        self.not_positive.clear();
        self.not_positive.resize(self.cells, 0);
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
            next.product.clear();
            match self.chain.last() {
                Some(t) => {
                    next.log_scale = t.log_scale + scale.ln();
                    (next.product).extend(t.product.iter().zip(contour).map(|(&b, &c)| b * c));
                }
                None => {
                    // 0 + ln(scale) and 1·c, as the tuples' first member is taken.
                    next.log_scale = 0.0 + scale.ln();
                    next.product.extend(contour.iter().map(|&c| 1.0 * c));
                }
            }
            self.chain.push(next);
        }
    }
}

/// Σ a·b over the cells (Σ a when `b` is empty) in eight lanes, which the compiler vectorises:
/// for floors only (the levels' sums are sequential).
fn lanes_dot(a: &[f64], b: &[f64]) -> f64 {
    let mut lanes = [0.0; 8];
    let blocks = a.chunks_exact(8);
    let mut tail: f64 = 0.0;
    if b.is_empty() {
        tail += blocks.remainder().iter().sum::<f64>();
        for block in blocks {
            for (lane, &x) in lanes.iter_mut().zip(block) {
                *lane += x;
            }
        }
    } else {
        let rest = a.len() - a.len() % 8;
        tail += (a[rest..].iter().zip(&b[rest..]))
            .map(|(x, y)| x * y)
            .sum::<f64>();
        for (block, other) in blocks.zip(b.chunks_exact(8)) {
            for ((lane, &x), &y) in lanes.iter_mut().zip(block).zip(other) {
                *lane += x * y;
            }
        }
    }
    lanes.iter().sum::<f64>() + tail
}
