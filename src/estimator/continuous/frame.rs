//! One frame of the continuous evidential tracker: each usable feature's likelihood-based
//! consonant function on the poses (contour pl_i(q) = exp(−½ z_i(q)²), z_i = (y_i − f_i(q))/σ_i),
//! group levels of conflict from the height of the contour product,
//! K_G = −log sup_q Π_{i∈G} pl_i(q) = ½ min_q Σ_{i∈G} z_i(q)², taken over the grid the maps are
//! tabulated on ([`super::grid_levels`]: exactly monotone, so the selection's pruned search is
//! sound), the paper's selection policies on top ([`select_group`]), and the chosen group's
//! estimate refined by Levenberg–Marquardt from the grid's minimum.

use std::collections::HashMap;

use super::grid_levels::GridCache;
use super::Continuous;
pub(super) use crate::track::members;
use crate::track::{select_group, Combine, GroupLevels, GroupMask, Selection};

/// Most Levenberg–Marquardt iterations per group.
const MAX_ITERATIONS: usize = 40;
/// A step shorter than this (mm) ends the iteration.
const STEP_TOLERANCE: f64 = 1e-7;

/// The minimum of one group's χ² = Σ z_i² and what the plausibility region needs there.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct GroupFit {
    /// The pose of highest combined plausibility (mm).
    pub pose: [f64; 2],
    /// Σ z_i² there (twice the level of conflict).
    pub chi2: f64,
    /// JᵀJ there (J: ∂z_i/∂q), the curvature of ½χ² in mm⁻².
    pub curvature: [[f64; 2]; 2],
}

/// The belief carried from the past frames as one more term of a group's χ² (bit
/// `features` of a mask): the consonant function with contour c(q) = 1 − α + α·exp(−½ z²),
/// z = max(0, |q − centre| − reach)/scale, whose χ² term is −2 ln c.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct PastTerm {
    pub centre: [f64; 2],
    pub reach: f64,
    pub scale: f64,
    pub reliability: f64,
}

impl PastTerm {
    /// −2 ln c(q) and its gradient.
    pub(super) fn chi2(&self, q: [f64; 2]) -> (f64, [f64; 2]) {
        let d = [q[0] - self.centre[0], q[1] - self.centre[1]];
        // Clearly inside the flat top (hypot cannot round beyond the reach): the same zero
        // without the hypot.
        let reach2 = self.reach * self.reach;
        if d[0] * d[0] + d[1] * d[1] < reach2 * (1.0 - 1e-9) {
            return (0.0, [0.0; 2]);
        }
        let distance = d[0].hypot(d[1]);
        let over = (distance - self.reach).max(0.0);
        if over <= 0.0 {
            return (0.0, [0.0; 2]);
        }
        let z = over / self.scale;
        // exp(x) is exactly 0 for x < −745.2; far from the centre that skips libm's slow
        // underflow path.
        let e = if z * z > UNDERFLOW_Z2 {
            0.0
        } else {
            (-0.5 * z * z).exp()
        };
        let c = 1.0 - self.reliability + self.reliability * e;
        if c <= 0.0 {
            return (f64::INFINITY, [0.0; 2]);
        }
        let slope = 2.0 * self.reliability * z * e / c / self.scale / distance;
        (-2.0 * c.ln(), [slope * d[0], slope * d[1]])
    }
}

/// z² beyond which exp(−½ z²) underflows to exactly 0 (−½ z² < −750).
const UNDERFLOW_Z2: f64 = 1500.0;

/// One frame's measurements against the model, with every group fit memoised.
pub(super) struct Frame<'a> {
    pub(super) model: &'a Continuous,
    /// Each feature's value; `None` when it is not usable.
    pub(super) values: Vec<Option<f64>>,
    pub(super) usable_mask: GroupMask,
    fits: HashMap<GroupMask, GroupFit>,
    /// z_i² at every sample pose for the usable features (sample-major, one per feature).
    sample_z2: Vec<f64>,
    /// The carried belief, when tracking over time.
    pub(super) past: Option<PastTerm>,
    /// Group levels on the grid computed so far.
    pub(super) grid: GridCache,
}

impl<'a> Frame<'a> {
    /// The frame of `values` (one per feature, non-finite already `None`).
    pub(super) fn new(model: &'a Continuous, values: Vec<Option<f64>>) -> Self {
        let d = values.len();
        let usable_mask = crate::track::present_mask(&values);
        let inv_sigma: Vec<f64> = model.file.residual_scales.iter().map(|s| 1.0 / s).collect();
        let mut sample_z2 = vec![0.0; model.sample_values.len()];
        for (z2, f) in sample_z2
            .chunks_exact_mut(d)
            .zip(model.sample_values.chunks_exact(d))
        {
            for i in 0..d {
                if let Some(y) = values[i] {
                    let z = (y - f[i]) * inv_sigma[i];
                    z2[i] = z * z;
                }
            }
        }
        Self {
            model,
            values,
            usable_mask,
            fits: HashMap::new(),
            sample_z2,
            past: None,
            grid: GridCache::default(),
        }
    }

    /// The same frame with the carried belief as bit [`Frame::past_bit`] (no fit made yet).
    pub(super) fn with_past(mut self, past: PastTerm) -> Self {
        self.fits.clear();
        self.grid.clear();
        self.past = Some(past);
        self
    }

    /// The mask bit of the carried belief.
    pub(super) fn past_bit(&self) -> GroupMask {
        // No bit is left beside 64 features; the tracker over time takes at most 63.
        (1 as GroupMask)
            .checked_shl(self.values.len() as u32)
            .unwrap_or(0)
    }

    /// Σ_{i∈group} z_i² at pose `q`, with the Jacobian rows of the z_i when asked.
    fn chi2_at(
        &self,
        group: GroupMask,
        q: [f64; 2],
        rows: Option<&mut Vec<[f64; 2]>>,
    ) -> (f64, Vec<f64>) {
        let d = self.values.len();
        let mut f = vec![0.0; d];
        let mut jac = vec![[0.0; 2]; d];
        let want_jacobian = rows.is_some();
        self.model
            .surrogate
            .eval(q, &mut f, want_jacobian.then_some(&mut jac[..]));
        let mut chi2 = 0.0;
        let mut residuals = Vec::with_capacity(group.count_ones() as usize);
        let mut jac_rows = Vec::new();
        for i in members(group & !self.past_bit()) {
            let Some(y) = self.values[i] else { continue };
            let s = self.model.file.residual_scales[i];
            let z = (y - f[i]) / s;
            let a = self.model.fusion.reliability(i);
            if a < 1.0 {
                // Discounted: the residual √t of its χ² term (module `rules`).
                let (t, slope) = super::rules::discounted_term(z, a);
                let r = t.sqrt();
                chi2 += t;
                residuals.push(r);
                if want_jacobian {
                    let k = if r > 0.0 { slope / (2.0 * r) } else { a.sqrt() };
                    jac_rows.push([-jac[i][0] / s * k, -jac[i][1] / s * k]);
                }
                continue;
            }
            chi2 += z * z;
            residuals.push(z);
            if want_jacobian {
                jac_rows.push([-jac[i][0] / s, -jac[i][1] / s]);
            }
        }
        if let (Some(past), true) = (&self.past, group & self.past_bit() != 0) {
            let (term, gradient) = past.chi2(q);
            let r = term.sqrt();
            chi2 += term;
            residuals.push(r);
            if want_jacobian {
                let half = if r > 0.0 { 0.5 / r } else { 0.0 };
                jac_rows.push([gradient[0] * half, gradient[1] * half]);
            }
        }
        if let Some(rows) = rows {
            *rows = jac_rows;
        }
        (chi2, residuals)
    }

    /// Σ_{i∈group} z_i² at pose `q`.
    pub(super) fn chi2_of(&self, group: GroupMask, q: [f64; 2]) -> f64 {
        self.chi2_at(group, q, None).0
    }

    /// The sample pose with the lowest χ² of `group`, and that χ².
    pub(super) fn best_sample(&self, group: GroupMask) -> ([f64; 2], f64) {
        let d = self.values.len();
        let past = self.past.filter(|_| group & self.past_bit() != 0);
        let poses = self.model.sample_poses();
        let mut past_chi2 = self.grid.past_samples.borrow_mut();
        if let (Some(past), true) = (&past, past_chi2.is_empty()) {
            // The same for every group with the past: computed once per frame.
            past_chi2.extend(poses.iter().map(|&q| past.chi2(q).0));
        }
        let mut best = (0, f64::INFINITY);
        for (k, z2) in self.sample_z2.chunks_exact(d).enumerate() {
            let mut chi2: f64 = members(group & !self.past_bit()).map(|i| z2[i]).sum();
            if past.is_some() {
                chi2 += past_chi2[k];
            }
            if chi2 < best.1 {
                best = (k, chi2);
            }
        }
        (self.model.sample_poses()[best.0], best.1)
    }

    /// The memoised fit of `group` (usable features only, at least one), from the minimum of
    /// its grid level (global over the workspace), else from its best sample pose.
    pub(super) fn fit(&mut self, group: GroupMask) -> GroupFit {
        if let Some(fit) = self.fits.get(&group) {
            return *fit;
        }
        let start = match self.grid_level(group, f64::INFINITY).point {
            Some(point) if point.iter().all(|v| v.is_finite()) => point,
            _ => self.best_sample(group).0,
        };
        let fit = self.levenberg_marquardt(group, start);
        self.fits.insert(group, fit);
        fit
    }

    /// Minimises Σ z_i² from `start`, kept inside the sample poses' bounding box.
    fn levenberg_marquardt(&self, group: GroupMask, start: [f64; 2]) -> GroupFit {
        let (lo, hi) = self.model.bounds;
        let clamp = |q: [f64; 2]| [q[0].clamp(lo[0], hi[0]), q[1].clamp(lo[1], hi[1])];
        let mut q = clamp(start);
        let mut rows = Vec::new();
        let (mut chi2, mut r) = self.chi2_at(group, q, Some(&mut rows));
        let mut lambda = 1e-3;
        for _ in 0..MAX_ITERATIONS {
            let (a, g) = normal_equations(&rows, &r);
            let damped = [
                [a[0][0] * (1.0 + lambda) + 1e-300, a[0][1]],
                [a[1][0], a[1][1] * (1.0 + lambda) + 1e-300],
            ];
            let Some(step) = solve2(damped, [-g[0], -g[1]]) else {
                break;
            };
            let trial = clamp([q[0] + step[0], q[1] + step[1]]);
            let moved = (trial[0] - q[0]).hypot(trial[1] - q[1]);
            let mut trial_rows = Vec::new();
            let (trial_chi2, trial_r) = self.chi2_at(group, trial, Some(&mut trial_rows));
            if trial_chi2 < chi2 {
                (q, chi2, r, rows) = (trial, trial_chi2, trial_r, trial_rows);
                lambda = (lambda * 0.1).max(1e-12);
                if moved < STEP_TOLERANCE {
                    break;
                }
            } else {
                lambda *= 10.0;
                if lambda > 1e12 || moved < STEP_TOLERANCE {
                    break;
                }
            }
        }
        let (curvature, _) = normal_equations(&rows, &r);
        GroupFit {
            pose: q,
            chi2,
            curvature,
        }
    }

    /// A feature's level alone: ½ z² of its distance from the range of its map over the sample
    /// poses (0 when some sample pose explains the value), a lower bound of every group's level
    /// it takes part in.
    fn own_level(&self, i: usize) -> f64 {
        if i == self.values.len() {
            return 0.0;
        }
        let Some(y) = self.values[i] else {
            return f64::INFINITY;
        };
        let (lo, hi) = self.model.ranges[i];
        let gap = (lo - y).max(y - hi).max(0.0) / self.model.file.residual_scales[i];
        let a = self.model.fusion.reliability(i);
        if a < 1.0 {
            return 0.5 * super::rules::discounted_term(gap, a).0;
        }
        0.5 * gap * gap
    }

    /// The paper's selection on this frame (every usable feature under `combine = "all"`).
    pub(super) fn select(&mut self) -> Selection {
        let (policy, threshold) = (self.model.file.settings.selection, self.model.threshold());
        let usable = self.usable_mask;
        if self.model.file.settings.combine == Combine::All {
            let level = self.grid_level(usable, f64::INFINITY).value;
            return Selection {
                chosen: Some((level, usable)),
                alternatives: Vec::new(),
                fallback: false,
            };
        }
        let features = self.values.len();
        select_group(self, features, usable, policy, threshold)
    }
}

impl GroupLevels for Frame<'_> {
    /// max(K_i, K_j): a necessary condition only (two level curves in a 2-D pose space usually
    /// cross, so pairs rarely conflict; the group levels decide).
    fn pair_level(&mut self, i: usize, j: usize) -> f64 {
        self.own_level(i).max(self.own_level(j))
    }

    /// The grid level: exact up to the threshold, beyond it only known to be beyond.
    fn group_level(&mut self, group: GroupMask) -> f64 {
        let limit = self.model.threshold().value();
        self.grid_level(group, limit).value
    }

    /// A level is a scan of kept grid nodes: costly next to the discrete tracker's, and a stuck
    /// feature conflicts with every group that fixes the pose.
    fn narrow_candidates(&self) -> bool {
        true
    }

    fn fallback_feature(&self) -> Option<usize> {
        members(self.usable_mask).min_by(|&a, &b| {
            self.own_level(a)
                .total_cmp(&self.own_level(b))
                .then(a.cmp(&b))
        })
    }
}

/// JᵀJ and Jᵀr of residuals `r` with Jacobian rows `rows`.
fn normal_equations(rows: &[[f64; 2]], r: &[f64]) -> ([[f64; 2]; 2], [f64; 2]) {
    let mut a = [[0.0; 2]; 2];
    let mut g = [0.0; 2];
    for (j, &z) in rows.iter().zip(r) {
        a[0][0] += j[0] * j[0];
        a[0][1] += j[0] * j[1];
        a[1][1] += j[1] * j[1];
        g[0] += j[0] * z;
        g[1] += j[1] * z;
    }
    a[1][0] = a[0][1];
    (a, g)
}

/// Solves a 2 × 2 system; `None` when singular.
pub(super) fn solve2(a: [[f64; 2]; 2], b: [f64; 2]) -> Option<[f64; 2]> {
    let det = a[0][0] * a[1][1] - a[0][1] * a[1][0];
    if !(det.is_finite() && det.abs() > 0.0) {
        return None;
    }
    let x = [
        (b[0] * a[1][1] - b[1] * a[0][1]) / det,
        (a[0][0] * b[1] - a[1][0] * b[0]) / det,
    ];
    x.iter().all(|v| v.is_finite()).then_some(x)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// The carried belief's term without the shortcuts: hypot and exp everywhere.
    fn plain(p: &PastTerm, q: [f64; 2]) -> (f64, [f64; 2]) {
        let d = [q[0] - p.centre[0], q[1] - p.centre[1]];
        let distance = d[0].hypot(d[1]);
        let over = (distance - p.reach).max(0.0);
        if over <= 0.0 {
            return (0.0, [0.0; 2]);
        }
        let z = over / p.scale;
        let e = (-0.5 * z * z).exp();
        let c = 1.0 - p.reliability + p.reliability * e;
        if c <= 0.0 {
            return (f64::INFINITY, [0.0; 2]);
        }
        let slope = 2.0 * p.reliability * z * e / c / p.scale / distance;
        (-2.0 * c.ln(), [slope * d[0], slope * d[1]])
    }

    #[test]
    fn the_past_terms_shortcuts_are_bit_identical() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        // Poses inside the flat top, beyond it, and where exp underflows.
        let mut seen = [0usize; 3];
        for k in 0..30_000 {
            let past = PastTerm {
                centre: [rng.random_range(-10.0..10.0), rng.random_range(40.0..55.0)],
                reach: if k % 7 == 0 {
                    0.0
                } else {
                    rng.random_range(0.0..5.0)
                },
                scale: rng.random_range(1e-3..2.0),
                reliability: if k % 3 == 0 {
                    1.0
                } else {
                    rng.random_range(0.0..1.0)
                },
            };
            let angle = rng.random_range(0.0..std::f64::consts::TAU);
            let distance = match k % 4 {
                // On the edge of the flat top, to the last bits.
                0 => past.reach * (1.0 + rng.random_range(-4.0..4.0) * f64::EPSILON),
                _ => rng.random_range(0.0..past.reach + 80.0 * past.scale),
            };
            let q = [
                past.centre[0] + distance * angle.cos(),
                past.centre[1] + distance * angle.sin(),
            ];
            let (chi2, gradient) = past.chi2(q);
            let (want, want_gradient) = plain(&past, q);
            assert_eq!(chi2.to_bits(), want.to_bits(), "{past:?} at {q:?}");
            for (a, b) in gradient.iter().zip(want_gradient) {
                assert_eq!(a.to_bits(), b.to_bits(), "{past:?} at {q:?}");
            }
            let d = [q[0] - past.centre[0], q[1] - past.centre[1]];
            let z = (d[0].hypot(d[1]) - past.reach).max(0.0) / past.scale;
            seen[if d[0] * d[0] + d[1] * d[1] < past.reach * past.reach * (1.0 - 1e-9) {
                0
            } else if z * z > UNDERFLOW_Z2 {
                2
            } else {
                1
            }] += 1;
        }
        assert!(seen.iter().all(|&n| n > 1000), "{seen:?}");
    }
}
