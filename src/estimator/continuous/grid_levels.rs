//! Group levels of conflict on the grid the feature maps are tabulated on: exact in the sense
//! the pruned group search needs (they only grow as features are added) and global over the
//! workspace, so no local minimum of a fit enters a level.
//!
//! **Definition.** K_G = ½ min over the grid nodes n of
//! m_G(n) = min_{|d_x| ≤ h_x/2, |d_y| ≤ h_y/2} Σ_{i∈G} (z_i(n) + ∇z_i(n)·d)²,
//! the Gauss–Newton model of χ²_G in the cell around each node (the cells cover the grid's box
//! and reach half a cell beyond its edge; the carried belief of the tracker over time enters as
//! its residual √(−2 ln c) and that residual's slope, as in the fits). Every term is a square, so
//! adding a feature raises m_G(n) at every node, hence K_G: Theorem 4.3 holds exactly and the
//! search's pruning is sound. Within a cell (0.125 mm from its node at the default spacing) the
//! linear model is within O(h²) of the maps, so K_G is the height of the contour product up to
//! that, wherever its maximum lies.
//!
//! **Computing it.** Feature i alone has the cell minimum l_i(n) = max(0, |z_i| − r_i(n))², its
//! reach r_i = |∂_x z_i| h_x/2 + |∂_y z_i| h_y/2, and L_G(n) = Σ l_i(n) ≤ m_G(n); over a block of
//! 8 × 8 nodes the range of f_i ± σ_i r_i bounds l_i from below. Blocks, then nodes, whose bound
//! is beyond the cut are dropped, and the cell minimum (a box-constrained 2-D quadratic, closed
//! form) is solved only at nodes whose bound is below the best node's own χ². With a finite
//! threshold T the cut is 2T: a level is exact when at most T and otherwise only shown to be
//! beyond T, which is all the selection asks, and a group's kept nodes (their sums) extend to the
//! group with one more feature above its highest (the search's next step) by one add per node
//! and sum. Without a threshold the cut starts at the group's χ² at one node (an upper bound of
//! 2K_G) and falls to the least node χ² found, blocks taken in increasing order of their bound.

use std::cell::RefCell;
use std::collections::HashMap;

use super::frame::Frame;
use super::grid_past::PastGrid;
use super::surrogate::GridView;
use crate::track::{members, GroupMask};

/// Nodes per side of a block.
pub(super) const BLOCK: usize = 8;
/// Most groups whose kept nodes are held at once (beyond, the cache starts again).
const MAX_KEPT: usize = 16_384;

/// Per block of nodes and feature, the range of f_i ± its reach over the block's cells: built
/// with the model, it bounds every node's l_i in the block from below.
#[derive(Debug, Clone)]
pub(super) struct Blocks {
    /// Blocks per axis.
    pub(super) counts: [usize; 2],
    /// Block-major, one (lowest, highest) per feature.
    ranges: Vec<[f64; 2]>,
}

impl Blocks {
    /// The blocks of a grid (`origin`, `step`, `nodes`, `table` as `Surrogate::grid`).
    pub(super) fn new(grid: GridView<'_>, dim: usize) -> Self {
        let (_, step, nodes, table) = grid;
        let half = [0.5 * step[0], 0.5 * step[1]];
        let counts = nodes.map(|n| n.div_ceil(BLOCK));
        let mut ranges = vec![[f64::INFINITY, f64::NEG_INFINITY]; counts[0] * counts[1] * dim];
        for r in 0..nodes[1] {
            for c in 0..nodes[0] {
                let b = (r / BLOCK) * counts[0] + c / BLOCK;
                let at = (r * nodes[0] + c) * dim;
                for (i, &[f, fx, fy, _]) in table[at..at + dim].iter().enumerate() {
                    let reach = fx.abs() * half[0] + fy.abs() * half[1];
                    let range = &mut ranges[b * dim + i];
                    range[0] = range[0].min(f - reach);
                    range[1] = range[1].max(f + reach);
                }
            }
        }
        Self { counts, ranges }
    }

    fn count(&self) -> usize {
        self.counts[0] * self.counts[1]
    }
}

/// A group's level on the grid and the pose of its minimum (node plus step), `None` when no
/// node was kept (the level is then +∞).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct GridLevel {
    pub value: f64,
    pub point: Option<[f64; 2]>,
}

/// Per kept node: Σz², Σz∂ₓz, Σz∂ᵧz, Σ(∂ₓz)², Σ∂ₓz∂ᵧz, Σ(∂ᵧz)², Σl.
type Sums = [f64; 7];

/// One member of a group at a node: a feature's value and 1/σ, a missing feature, the past.
#[derive(Clone, Copy)]
enum Term {
    Feature { i: usize, y: f64, inv: f64 },
    Missing,
    Past,
}

/// A group's kept nodes (those whose bound is within the cut 2T) and their sums.
struct Kept {
    nodes: Vec<u32>,
    sums: Vec<Sums>,
    /// The cut they were kept within.
    cut: f64,
}

/// One frame's grid levels so far.
#[derive(Default)]
pub(super) struct GridCache {
    /// Per block and feature, the lower bound of l_i over the block (built on first use).
    block_bounds: Vec<f64>,
    /// With a finite threshold: each group's kept nodes, extended to its children.
    kept: HashMap<GroupMask, Kept>,
    /// Each group's level and the limit it was computed with.
    levels: HashMap<GroupMask, (GridLevel, f64)>,
    /// The same for the discounted levels of [`super::rules`].
    pub(super) discounted: HashMap<GroupMask, (GridLevel, f64)>,
    /// The carried belief's terms and block bounds, block by block as groups with the past
    /// visit them: every group with the past reads the same terms.
    pub(super) past: RefCell<PastGrid>,
    /// The carried belief's χ² term at each sample pose (empty until first needed).
    pub(super) past_samples: RefCell<Vec<f64>>,
}

impl GridCache {
    pub(super) fn clear(&mut self) {
        self.kept.clear();
        self.levels.clear();
        self.discounted.clear();
        self.past.get_mut().clear();
        self.past_samples.get_mut().clear();
    }
}

/// The cut above `x` with room for rounding (bounds and sums add in different orders).
pub(super) fn with_slack(x: f64) -> f64 {
    x * (1.0 + 1e-9) + 1e-9
}

impl Frame<'_> {
    /// The level of `group` (usable features and perhaps the carried belief) under Dempster's
    /// rule, undiscounted, with the threshold `limit` (+∞: exact): exact when at most `limit`,
    /// else some value above it.
    pub(super) fn sum_level(&mut self, group: GroupMask, limit: f64) -> GridLevel {
        if group == 0 {
            return GridLevel {
                value: 0.0,
                point: None,
            };
        }
        if let Some(&(level, used)) = self.grid.levels.get(&group) {
            if used == f64::INFINITY || level.value <= used || used == limit {
                return level;
            }
        }
        let finite = limit.is_finite();
        let cut = with_slack(if finite {
            2.0 * limit
        } else {
            self.node_chi2_bound(group)
        });
        let top = 63 - group.leading_zeros() as usize;
        let parent = group & !(1 << top);
        let kept = match self
            .grid
            .kept
            .get(&parent)
            .filter(|_| finite && parent != 0)
        {
            Some(p) => self.extend(p, top, cut),
            None => match self.with_past_subgroup(group, cut).filter(|_| finite) {
                Some((sub, i)) => self.refine(sub, i, group, cut),
                None => self.scan(group, cut, !finite),
            },
        };
        let level = self.minimum(&kept);
        if finite {
            if self.grid.kept.len() >= MAX_KEPT {
                self.grid.kept.clear();
            }
            self.grid.kept.insert(group, kept);
        }
        self.grid.levels.insert(group, (level, limit));
        level
    }

    /// χ²_G of the linear model at the node nearest the best sample pose: ≥ 2K_G.
    fn node_chi2_bound(&self, group: GroupMask) -> f64 {
        let (origin, step, nodes, _) = self.model.surrogate.grid();
        let (pose, _) = self.best_sample(group);
        let index = |k: usize| {
            let x = ((pose[k] - origin[k]) / step[k]).round();
            (x.max(0.0) as usize).min(nodes[k] - 1)
        };
        let n = index(1) * nodes[0] + index(0);
        let mut sums = [0.0; 7];
        for i in members(group) {
            self.add_term(&mut sums, i, n);
        }
        sums[0]
    }

    /// The pose of node `n`.
    pub(super) fn node_pose(&self, n: usize) -> [f64; 2] {
        let (origin, step, nodes, _) = self.model.surrogate.grid();
        let (c, r) = (n % nodes[0], n / nodes[0]);
        [
            origin[0] + c as f64 * step[0],
            origin[1] + r as f64 * step[1],
        ]
    }

    /// Adds member `i`'s terms at node `n` to `sums` (the carried belief is bit `features`).
    fn add_term(&self, sums: &mut Sums, i: usize, n: usize) {
        self.add(sums, self.term(i), n);
    }

    /// What member `i` adds at a node, read once per group.
    fn term(&self, i: usize) -> Term {
        if i >= self.values.len() {
            return Term::Past;
        }
        match self.values[i] {
            Some(y) => Term::Feature {
                i,
                y,
                inv: 1.0 / self.model.file.residual_scales[i],
            },
            None => Term::Missing,
        }
    }

    /// Adds `term` at node `n` to `sums`.
    // Inlined into the node loops (a call per node and term was a third of a temporal frame).
    #[inline(always)]
    fn add(&self, sums: &mut Sums, term: Term, n: usize) {
        let (_, step, _, table) = self.model.surrogate.grid();
        let d = self.values.len();
        let (z, gx, gy) = match term {
            Term::Feature { i, y, inv } => {
                let [f, fx, fy, _] = table[n * d + i];
                ((y - f) * inv, -fx * inv, -fy * inv)
            }
            Term::Missing => {
                sums[6] = f64::INFINITY;
                return;
            }
            Term::Past => {
                let Some([r, gx, gy]) = self.past_node(n) else {
                    return;
                };
                if r == f64::INFINITY {
                    sums[6] = f64::INFINITY;
                    return;
                }
                (r, gx, gy)
            }
        };
        let reach = 0.5 * (gx.abs() * step[0] + gy.abs() * step[1]);
        let alone = (z.abs() - reach).max(0.0);
        sums[0] += z * z;
        sums[1] += z * gx;
        sums[2] += z * gy;
        sums[3] += gx * gx;
        sums[4] += gx * gy;
        sums[5] += gy * gy;
        sums[6] += alone * alone;
    }

    /// Per block and feature, the lower bound of l_i over the block (0 for a missing value).
    pub(super) fn block_bounds(&mut self) -> &[f64] {
        if self.grid.block_bounds.is_empty() {
            let blocks = &self.model.blocks;
            let d = self.values.len();
            let mut bounds = vec![0.0; blocks.count() * d];
            for (b, out) in bounds.chunks_exact_mut(d).enumerate() {
                for (i, o) in out.iter_mut().enumerate() {
                    if let Some(y) = self.values[i] {
                        let [lo, hi] = blocks.ranges[b * d + i];
                        let gap =
                            (lo - y).max(y - hi).max(0.0) / self.model.file.residual_scales[i];
                        // Slightly under, so that rounding never drops a node its own sum keeps.
                        *o = gap * gap * (1.0 - 1e-12);
                    }
                }
            }
            self.grid.block_bounds = bounds;
        }
        &self.grid.block_bounds
    }

    /// The nodes of `group` whose bound is within `cut`, from the whole grid; with `tighten`
    /// (the nodes serve this group's level only), blocks in increasing order of their bound and
    /// the cut lowered to the least node χ² kept so far (an upper bound of 2K_G).
    fn scan(&mut self, group: GroupMask, mut cut: f64, tighten: bool) -> Kept {
        let d = self.values.len();
        let (_, _, nodes, _) = self.model.surrogate.grid();
        let counts = self.model.blocks.counts;
        let features: Vec<usize> = members(group).filter(|&i| i < d).collect();
        let mut passing: Vec<(f64, usize)> = {
            let bounds = self.block_bounds();
            (0..counts[0] * counts[1])
                .map(|b| {
                    let row = &bounds[b * d..(b + 1) * d];
                    (features.iter().map(|&i| row[i]).sum::<f64>(), b)
                })
                .filter(|&(bound, _)| bound <= cut)
                .collect()
        };
        if tighten {
            passing.sort_by(|a, b| a.0.total_cmp(&b.0));
        }
        let mut kept = Kept {
            nodes: Vec::new(),
            sums: Vec::new(),
            cut,
        };
        let with_past = members(group).any(|i| i >= d) && self.past.is_some();
        let terms: Vec<Term> = members(group).map(|i| self.term(i)).collect();
        for (bound, b) in passing {
            if bound > cut {
                break;
            }
            // The past's bound after the features', as a node adds them: a block it drops
            // keeps no node.
            if with_past && bound + self.past_bound(b) > cut {
                continue;
            }
            let (bc, br) = (b % counts[0], b / counts[0]);
            for r in br * BLOCK..((br + 1) * BLOCK).min(nodes[1]) {
                for c in bc * BLOCK..((bc + 1) * BLOCK).min(nodes[0]) {
                    let n = r * nodes[0] + c;
                    let mut sums = [0.0; 7];
                    let within = terms.iter().all(|&term| {
                        self.add(&mut sums, term, n);
                        sums[6] <= cut
                    });
                    if within {
                        if tighten {
                            cut = cut.min(with_slack(sums[0]));
                        }
                        kept.nodes.push(n as u32);
                        kept.sums.push(sums);
                    }
                }
            }
        }
        kept
    }

    /// The fewest kept nodes (within `cut` or a wider cut) of a group with the past that is
    /// `group` less one feature `i`, and `i`, when `group` has the past and such a group is
    /// kept. Its nodes hold every node `group` keeps: a node's sum only grows as a term is
    /// added.
    fn with_past_subgroup(&self, group: GroupMask, cut: f64) -> Option<(&Kept, usize)> {
        let past = 1 << self.values.len();
        if self.past.is_none() || group & past == 0 || self.grid.kept.is_empty() {
            return None;
        }
        members(group & !past)
            .filter_map(|i| Some((self.grid.kept.get(&(group & !(1 << i)))?, i)))
            .filter(|(k, _)| k.cut >= cut)
            .min_by_key(|(k, _)| k.nodes.len())
    }

    /// The nodes of `sub` (`group` less feature `i`, nodes in the grid scan's order) that
    /// `group` keeps within `cut`, with their sums: what [`Self::scan`] keeps, in the same
    /// order, from fewer nodes.
    fn refine(&self, sub: &Kept, i: usize, group: GroupMask, cut: f64) -> Kept {
        let terms: Vec<Term> = members(group).map(|i| self.term(i)).collect();
        let added = self.term(i);
        // The sub-group's Σl plus l_i is the node's own Σl up to rounding in another order
        // (below 1e-13 relative for 64 terms): beyond this, the node's own sum is beyond `cut`.
        let beyond = cut * (1.0 + 1e-12);
        let mut out = Kept {
            nodes: Vec::new(),
            sums: Vec::new(),
            cut,
        };
        for (&n, s) in sub.nodes.iter().zip(&sub.sums) {
            let mut one = [0.0; 7];
            self.add(&mut one, added, n as usize);
            if s[6] + one[6] > beyond {
                continue;
            }
            // The sums in the group's own order, as the scan adds them.
            let mut sums = [0.0; 7];
            let within = terms.iter().all(|&term| {
                self.add(&mut sums, term, n as usize);
                sums[6] <= cut
            });
            if within {
                out.nodes.push(n);
                out.sums.push(sums);
            }
        }
        out
    }

    /// The kept nodes of the parent `kept` with member `i` added, within `cut`.
    fn extend(&self, kept: &Kept, i: usize, cut: f64) -> Kept {
        let mut out = Kept {
            nodes: Vec::new(),
            sums: Vec::new(),
            cut,
        };
        let past = i >= self.values.len() && self.past.is_some();
        let term = self.term(i);
        for (&n, s) in kept.nodes.iter().zip(&kept.sums) {
            // The past's block bound first: the past's terms only where a node may stay.
            if past && s[6] + self.past_bound(self.block_of(n as usize)) > cut {
                continue;
            }
            let mut sums = *s;
            self.add(&mut sums, term, n as usize);
            if sums[6] <= cut {
                out.nodes.push(n);
                out.sums.push(sums);
            }
        }
        out
    }

    /// ½ min over the kept nodes of their cell minimum, and where it lies.
    fn minimum(&self, kept: &Kept) -> GridLevel {
        let (_, step, _, _) = self.model.surrogate.grid();
        let half = [0.5 * step[0], 0.5 * step[1]];
        // A node's own χ² bounds its cell minimum from above: nodes bounded below beyond the
        // best of those cannot hold the minimum.
        let best = kept.sums.iter().map(|s| s[0]).fold(f64::INFINITY, f64::min);
        let mut found = (f64::INFINITY, None);
        for (&n, s) in kept.nodes.iter().zip(&kept.sums) {
            if s[6] <= best {
                let (m, step) = cell_minimum(s, half);
                // Overflowing sums (a feature read at 1e300) give NaN: that cell holds nothing.
                let m = if m.is_nan() || !step.iter().all(|d| d.is_finite()) {
                    f64::INFINITY
                } else {
                    m
                };
                if m < found.0 {
                    found = (m, Some((n as usize, step)));
                }
            }
        }
        GridLevel {
            value: 0.5 * found.0,
            point: found.1.map(|(n, d)| {
                let p = self.node_pose(n);
                [p[0] + d[0], p[1] + d[1]]
            }),
        }
    }
}

/// min over |d_x| ≤ half_x, |d_y| ≤ half_y of S + 2bᵀd + dᵀAd (A positive semi-definite), and
/// the minimising d: the lowest of the interior stationary point (when it lies inside) and the
/// four edges' clamped minima.
pub(super) fn cell_minimum(s: &Sums, half: [f64; 2]) -> (f64, [f64; 2]) {
    let [s0, bx, by, axx, axy, ayy, _] = *s;
    let q = |d: [f64; 2]| {
        let v = s0
            + 2.0 * (bx * d[0] + by * d[1])
            + axx * d[0] * d[0]
            + 2.0 * axy * d[0] * d[1]
            + ayy * d[1] * d[1];
        v.max(0.0)
    };
    let mut best = (f64::INFINITY, [0.0; 2]);
    // Nearly parallel terms make the interior solution inexact: every candidate is a pose of
    // the cell, so the lowest of them all is kept.
    let det = axx * ayy - axy * axy;
    if det > 0.0 {
        let d = [(axy * by - ayy * bx) / det, (axy * bx - axx * by) / det];
        if d[0].abs() <= half[0] && d[1].abs() <= half[1] {
            best = (q(d), d);
        }
    }
    // Along an edge the quadratic is 1-D: its minimum clamped to the edge.
    let along = |linear: f64, curvature: f64, h: f64| {
        if curvature > 0.0 {
            (-linear / curvature).clamp(-h, h)
        } else if linear > 0.0 {
            -h
        } else {
            h
        }
    };
    for sign in [-1.0, 1.0] {
        let dx = sign * half[0];
        let edge_x = [dx, along(by + axy * dx, ayy, half[1])];
        let dy = sign * half[1];
        let edge_y = [along(bx + axy * dy, axx, half[0]), dy];
        for d in [edge_x, edge_y] {
            let v = q(d);
            if v < best.0 {
                best = (v, d);
            }
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn the_cell_minimum_is_the_box_minimum() {
        // Against a fine scan of the box, on random sums of squares of 1 to 4 linear terms.
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let half = [0.125, 0.2];
        for _ in 0..300 {
            let mut s = [0.0; 7];
            for _ in 0..rng.random_range(1..=4) {
                let (z, gx, gy): (f64, f64, f64) = (
                    rng.random_range(-3.0..3.0),
                    rng.random_range(-30.0..30.0),
                    rng.random_range(-30.0..30.0),
                );
                for (k, v) in [z * z, z * gx, z * gy, gx * gx, gx * gy, gy * gy]
                    .into_iter()
                    .enumerate()
                {
                    s[k] += v;
                }
            }
            let (m, d) = cell_minimum(&s, half);
            assert!(d[0].abs() <= half[0] + 1e-15 && d[1].abs() <= half[1] + 1e-15);
            let mut scanned = f64::INFINITY;
            for a in 0..=200 {
                for b in 0..=200 {
                    let d = [
                        half[0] * (a as f64 / 100.0 - 1.0),
                        half[1] * (b as f64 / 100.0 - 1.0),
                    ];
                    let v = s[0]
                        + 2.0 * (s[1] * d[0] + s[2] * d[1])
                        + s[3] * d[0] * d[0]
                        + 2.0 * s[4] * d[0] * d[1]
                        + s[5] * d[1] * d[1];
                    scanned = scanned.min(v);
                }
            }
            assert!(m <= scanned + 1e-9, "{m} above the scan's {scanned}");
            assert!(
                m >= scanned - 0.05 - 1e-3 * scanned,
                "{m} far below {scanned}"
            );
        }
    }
}

#[cfg(test)]
#[path = "grid_levels_tests.rs"]
mod search_tests;

#[cfg(test)]
#[path = "grid_past_tests.rs"]
mod past_tests;
