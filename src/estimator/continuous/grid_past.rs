//! The carried belief's terms on the grid ([`super::grid_levels`]), block by block: its
//! residual and slopes at a node are computed when a node first needs them, in a slot of
//! BLOCK × BLOCK nodes given to the block on its first use (memory grows with the blocks a
//! frame visits, not with the grid), and each block has a lower bound of the past's l(n) over
//! its nodes, so that a group with the past drops the block before any node of it is visited.
//!
//! **The block bound.** The past's residual r = √(−2 ln c) depends on the distance ρ from the
//! centre only and grows with it; its slope in ρ is at most 1/scale (dr/dz =
//! αz e^{−z²/2}/(c r) ≤ √α at z → 0 and below it beyond). A node's reach is
//! ½(|∂ₓr| h_x + |∂ᵧr| h_y) ≤ |∇r| · ½√(h_x² + h_y²), so at every node of a block
//! l = max(0, r − reach)² ≥ max(0, r(ρ_min) − ½√(h_x² + h_y²)/scale)², ρ_min the distance from
//! the centre to the box of the block's nodes. The margins below keep it under the node's own
//! rounded value (the pruning must drop only nodes the node test drops).

use super::frame::{Frame, PastTerm};
use super::grid_levels::BLOCK;
use crate::track::GroupMask;

/// No slot given yet.
const NONE: u32 = u32::MAX;

/// One frame's past terms on the grid.
#[derive(Default)]
pub(super) struct PastGrid {
    /// Per block, the lower bound of the past's l over its nodes (NaN until computed; empty
    /// until first needed).
    bounds: Vec<f64>,
    /// Per block, its slot in `pool` (`NONE`: not given yet).
    slots: Vec<u32>,
    /// BLOCK² (residual, slopes) per slot, node-major within the block, NaN until computed.
    pool: Vec<[f64; 3]>,
    /// Every block bound 0 (the tests' full computation).
    #[cfg(test)]
    pub(super) unbounded: bool,
}

impl PastGrid {
    pub(super) fn clear(&mut self) {
        self.bounds.clear();
        self.slots.clear();
        self.pool.clear();
    }

    /// Nodes whose terms have room now.
    #[cfg(test)]
    pub(super) fn room(&self) -> usize {
        self.pool.len()
    }
}

/// Residual, slopes of the past at node pose `q` (residual +∞ where c is 0).
fn node_terms(past: &PastTerm, q: [f64; 2]) -> [f64; 3] {
    let (chi2, gradient) = past.chi2(q);
    if chi2.is_finite() {
        let r = chi2.sqrt();
        let half = if r > 0.0 { 0.5 / r } else { 0.0 };
        [r, gradient[0] * half, gradient[1] * half]
    } else {
        [f64::INFINITY, 0.0, 0.0]
    }
}

/// The past's residual √(−2 ln c) at distance `distance` from its centre, as
/// [`PastTerm::chi2`] computes it (+∞ where c is 0).
fn residual_at(past: &PastTerm, distance: f64) -> f64 {
    let over = (distance - past.reach).max(0.0);
    if over <= 0.0 {
        return 0.0;
    }
    let z = over / past.scale;
    let e = (-0.5 * z * z).exp();
    let c = 1.0 - past.reliability + past.reliability * e;
    if c <= 0.0 {
        return f64::INFINITY;
    }
    (-2.0 * c.ln()).max(0.0).sqrt()
}

/// The lower bound of the past's l over the nodes in `x` × `y` (closed ranges of node
/// coordinates) on a grid of `step`.
pub(super) fn past_block_bound(past: &PastTerm, x: [f64; 2], y: [f64; 2], step: [f64; 2]) -> f64 {
    let gap = |c: f64, [lo, hi]: [f64; 2]| (lo - c).max(c - hi).max(0.0);
    let nearest = gap(past.centre[0], x).hypot(gap(past.centre[1], y));
    // Room for the nodes' own rounding: a nanometre nearer, a millionth lower.
    let r = residual_at(past, (nearest * (1.0 - 1e-12) - 1e-9).max(0.0));
    if r == f64::INFINITY {
        return f64::INFINITY;
    }
    let reach = 0.5 * step[0].hypot(step[1]) / past.scale;
    let b = (r * (1.0 - 1e-6) - reach * (1.0 + 1e-6) - 1e-9).max(0.0);
    b * b * (1.0 - 1e-6)
}

impl Frame<'_> {
    /// The carried belief's residual √(−2 ln c) and its slopes at node `n` (residual +∞ where
    /// c is 0), computed once per frame; `None` without a past.
    pub(super) fn past_node(&self, n: usize) -> Option<[f64; 3]> {
        let past = self.past.as_ref()?;
        let (_, _, nodes, _) = self.model.surrogate.grid();
        let counts = self.model.blocks.counts;
        let (c, r) = (n % nodes[0], n / nodes[0]);
        let b = (r / BLOCK) * counts[0] + c / BLOCK;
        let within = (r % BLOCK) * BLOCK + c % BLOCK;
        let mut cache = self.grid.past.borrow_mut();
        let cache = &mut *cache;
        if cache.slots.is_empty() {
            cache.slots.resize(counts[0] * counts[1], NONE);
        }
        if cache.slots[b] == NONE {
            cache.slots[b] = (cache.pool.len() / (BLOCK * BLOCK)) as u32;
            let len = cache.pool.len();
            cache.pool.resize(len + BLOCK * BLOCK, [f64::NAN; 3]);
        }
        let at = cache.slots[b] as usize * BLOCK * BLOCK + within;
        if cache.pool[at][0].is_nan() {
            cache.pool[at] = node_terms(past, self.node_pose(n));
        }
        Some(cache.pool[at])
    }

    /// The lower bound of the past's l over the nodes of block `b` (0 without a past).
    pub(super) fn past_bound(&self, b: usize) -> f64 {
        let Some(past) = self.past.as_ref() else {
            return 0.0;
        };
        let mut cache = self.grid.past.borrow_mut();
        #[cfg(test)]
        if cache.unbounded {
            return 0.0;
        }
        let counts = self.model.blocks.counts;
        if cache.bounds.is_empty() {
            cache.bounds.resize(counts[0] * counts[1], f64::NAN);
        }
        if cache.bounds[b].is_nan() {
            let (origin, step, nodes, _) = self.model.surrogate.grid();
            let (bc, br) = (b % counts[0], b / counts[0]);
            let span = |k: usize, first: usize| {
                let last = ((first + 1) * BLOCK).min(nodes[k]) - 1;
                [
                    origin[k] + (first * BLOCK) as f64 * step[k],
                    origin[k] + last as f64 * step[k],
                ]
            };
            cache.bounds[b] = past_block_bound(past, span(0, bc), span(1, br), step);
        }
        cache.bounds[b]
    }

    /// The frame's own chosen group `chosen` (not the fallback) when its level proves every
    /// group of its features within the threshold with the past, else 0, so that the search
    /// beside the past computes none of those levels (issue 32: 36 of them a clean frame).
    ///
    /// Where the group's minimum lies well inside the past's flat top, the past adds exactly
    /// nothing at that node, so each sub-group S with the past has m_{S+past} ≤ m_G there and its
    /// level is at most G's own (up to rounding, against which the margin below guards). Sums
    /// only: discounted and cautious levels are left alone.
    pub(super) fn within_beside_past(&mut self, chosen: Option<(f64, GroupMask)>) -> GroupMask {
        let (Some(past), Some((_, group))) = (self.past, chosen) else {
            return 0;
        };
        if group.count_ones() < 2 || group & self.past_bit() != 0 || !self.model.fusion.plain() {
            return 0;
        }
        let threshold = self.model.threshold().value();
        let level = self.grid_level(group, threshold);
        if !(level.value.is_finite() && level.value <= threshold * (1.0 - 1e-6) - 1e-9) {
            return 0;
        }
        let Some(point) = level.point else {
            return 0;
        };
        let (_, step, _, _) = self.model.surrogate.grid();
        // The node of the minimum is within half a cell's diagonal of its point.
        let node = (point[0] - past.centre[0]).hypot(point[1] - past.centre[1])
            + 0.5 * step[0].hypot(step[1]);
        if node < 0.999 * past.reach {
            group
        } else {
            0
        }
    }

    /// The block of node `n`.
    pub(super) fn block_of(&self, n: usize) -> usize {
        let (_, _, nodes, _) = self.model.surrogate.grid();
        let (c, r) = (n % nodes[0], n / nodes[0]);
        (r / BLOCK) * self.model.blocks.counts[0] + c / BLOCK
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn a_blocks_bound_is_below_each_nodes_own_term() {
        // Random pasts and blocks of an 8 × 8 node box near them, each node's l as the grid
        // levels compute it (add_term) against the block's bound.
        let mut rng = ChaCha8Rng::seed_from_u64(12);
        let mut positive = 0;
        for k in 0..4000 {
            let past = PastTerm {
                centre: [rng.random_range(-10.0..10.0), rng.random_range(40.0..55.0)],
                reach: if k % 5 == 0 {
                    0.0
                } else {
                    rng.random_range(0.0..4.0)
                },
                scale: 10f64.powf(rng.random_range(-3.0..1.3)),
                reliability: match k % 3 {
                    0 => 1.0,
                    1 => 1.0 - 10f64.powf(rng.random_range(-12.0..-1.0)),
                    _ => rng.random_range(1e-6..1.0),
                },
            };
            let step = [rng.random_range(0.02..1.0), rng.random_range(0.02..1.0)];
            let corner = [
                past.centre[0] + rng.random_range(-8.0..8.0) * (past.reach + 8.0 * step[0]),
                past.centre[1] + rng.random_range(-8.0..8.0) * (past.reach + 8.0 * step[1]),
            ];
            let x = [corner[0], corner[0] + 7.0 * step[0]];
            let y = [corner[1], corner[1] + 7.0 * step[1]];
            let bound = past_block_bound(&past, x, y, step);
            positive += usize::from(bound > 0.0 && bound.is_finite());
            for r in 0..8 {
                for c in 0..8 {
                    let q = [
                        corner[0] + c as f64 * step[0],
                        corner[1] + r as f64 * step[1],
                    ];
                    let [z, gx, gy] = node_terms(&past, q);
                    let l = if z == f64::INFINITY {
                        f64::INFINITY
                    } else {
                        let reach = 0.5 * (gx.abs() * step[0] + gy.abs() * step[1]);
                        let alone = (z.abs() - reach).max(0.0);
                        alone * alone
                    };
                    assert!(bound <= l, "{past:?} {step:?} at {q:?}: {bound} > {l}");
                }
            }
        }
        // Most blocks lie beyond the flat top: the bound prunes.
        assert!(positive > 1500, "{positive}");
    }
}
