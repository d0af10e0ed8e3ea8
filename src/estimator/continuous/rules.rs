//! Fusion rules of the continuous trackers (issue 30): the rules that make sense for consonant
//! contours pl_i(q) = exp(−½ z_i(q)²), and Shafer's discounting before them.
//!
//! **Discounting** by α_i keeps a function consonant, with contour 1 − α_i + α_i pl_i(q): its
//! χ² term is t_i = −2 ln(1 − α_i + α_i e^{−z_i²/2}) ([`discounted_term`]), z_i² when α_i = 1,
//! bounded by −2 ln(1 − α_i) (a robust loss). `learned`: α_i = e_min / e_i with
//! e_i = σ_i / RMS_samples |∇f_i|, the pose error (mm) feature i leaves across its level curves,
//! from the validation residual σ_i: nothing new is fitted or stored.
//!
//! **Dempster's rule** multiplies contours, so the combined χ² is Σ t_i and the level
//! K_G = ½ min_q Σ_{i∈G} t_i. Undiscounted, that is [`Frame::sum_level`] (the Gauss–Newton cell
//! model, unchanged); discounted, the terms are not squares of linear functions, so the level is
//! the minimum over a fixed sub-grid (each node and the 8 points at ±h/3 around it, the maps'
//! linear model at the node), found by branch and bound on each feature's own bound per block
//! and per node (t_i grows with |z_i|). Every point's Σ only grows as features are added, so
//! levels grow exactly (up to rounding) and the pruned search stays sound. The estimate is
//! Levenberg–Marquardt on the residuals √t_i from the sub-grid's best point; the region's shape
//! is the curvature of those residuals there, its size calibrated as before.
//!
//! **The cautious rule** (Denœux 2008) combines the weights of the canonical decompositions by
//! their minimum. A consonant function's weights sit on its chain of level sets
//! {q : pl_i(q) ≥ s} (and ∅, with weight its height h_i when subnormal), and its contour is
//! pl(q) = Π_{A ∌ q} w(A). The minimum of the contours, which the rule is sometimes said to
//! give on consonant functions, is its result only when one function's weights are all below
//! the others' (then it returns that function); in general product ≤ cautious ≤ minimum
//! (`rules_tests.rs` checks all three against `evidence::rules`). Distinct features' level sets
//! never coincide on a continuous pose space (generic position), so the chains share only ∅
//! and the cautious contour is min_i h_i · Π_i pl_i/h_i: Dempster's shape, hence its estimate,
//! with level K_c(G) = K(G) − Σ_{i∈G} K_i + max_{i∈G} K_i (K Dempster's level of the group,
//! discounted or not, K_i each feature's own). Adding j raises it: K(G+j) ≥ K(G) + K_j on any
//! fixed set of points, and the max does not fall. Over time the carried belief joins by
//! Dempster's rule (its term is in K, not in the sums).
//!
//! Yager's, Dubois–Prade's, PCR6, the disjunctive rule and Murphy's are refused: they act on
//! focal sets and masses that a contour on the poses does not keep.

use super::file::ContinuousFile;
use super::frame::Frame;
use super::grid_levels::{with_slack, GridLevel, BLOCK};
use super::surrogate::Surrogate;
use super::{ContinuousSettings, EstimatorError};
use crate::evidence::Rule;
use crate::model::ModelError;
use crate::track::{members, Combine, Discount, GroupMask, SelectionPolicy};

/// The rules the continuous trackers take.
pub const CONTINUOUS_RULES: [Rule; 2] = [Rule::Dempster, Rule::Cautious];

/// Sub-grid offsets in a node's cell, as fractions of the spacing.
const SUB: [f64; 3] = [-1.0 / 3.0, 0.0, 1.0 / 3.0];

/// Default fields are left out of model files, so files of the defaults read as before.
pub(super) fn is_default<T: Default + PartialEq>(value: &T) -> bool {
    *value == T::default()
}

/// The rule, discounting and combined group fit the continuous trackers.
///
/// # Errors
/// [`ModelError::Settings`] naming the field and what is accepted.
pub(super) fn check(settings: &ContinuousSettings) -> Result<(), EstimatorError> {
    let bad = |field, reason: String| Err(ModelError::Settings { field, reason }.into());
    if !CONTINUOUS_RULES.contains(&settings.rule) {
        return bad(
            "continuous.rule",
            format!(
                "`{}` does not apply to the continuous trackers' consonant contours: use \
                 \"dempster\" or \"cautious\" (the other rules act on focal sets and masses a \
                 contour on the poses does not keep)",
                settings.rule.name()
            ),
        );
    }
    if let Discount::Fixed(a) = settings.discount {
        if !(a > 0.0 && a <= 1.0) {
            return bad(
                "continuous.discount",
                format!(
                    "{a} is not a reliability here: use a number in (0, 1] (0 ignores every \
                     feature), \"learned\" or \"none\""
                ),
            );
        }
    }
    if settings.combine == Combine::All && settings.selection != SelectionPolicy::LargestSubset {
        return bad(
            "continuous.selection",
            "`combine = \"all\"` combines every usable feature: it takes no selection policy"
                .into(),
        );
    }
    Ok(())
}

/// The rule of a fitted tracker and each feature's reliability.
#[derive(Debug, Clone)]
pub(super) struct Fusion {
    pub rule: Rule,
    /// Each feature's α; empty when none is below 1 (Dempster's path then runs unchanged).
    pub alpha: Vec<f64>,
}

impl Fusion {
    pub(super) fn new(file: &ContinuousFile, surrogate: &Surrogate) -> Self {
        let dim = file.residual_scales.len();
        let alpha = match file.settings.discount {
            Discount::None => Vec::new(),
            Discount::Fixed(a) => vec![a; dim],
            Discount::Learned => learned_reliabilities(file, surrogate),
        };
        Self {
            rule: file.settings.rule,
            alpha: if alpha.iter().all(|&a| a >= 1.0) {
                Vec::new()
            } else {
                alpha
            },
        }
    }

    /// Dempster's rule undiscounted: the path of the paper's tables.
    pub(super) fn plain(&self) -> bool {
        self.rule != Rule::Cautious && self.alpha.is_empty()
    }

    /// Feature `i`'s α (1 past the features: the carried belief has its own).
    pub(super) fn reliability(&self, i: usize) -> f64 {
        self.alpha.get(i).copied().unwrap_or(1.0)
    }
}

/// α_i = e_min / e_i, e_i = σ_i / RMS over the sample poses of |∇f_i|.
fn learned_reliabilities(file: &ContinuousFile, surrogate: &Surrogate) -> Vec<f64> {
    let dim = file.residual_scales.len();
    let (mut values, mut slopes) = (vec![0.0; dim], vec![[0.0; 2]; dim]);
    let mut sums = vec![0.0; dim];
    for &p in &file.sample_poses {
        surrogate.eval(p, &mut values, Some(&mut slopes[..]));
        for (s, g) in sums.iter_mut().zip(&slopes) {
            *s += g[0] * g[0] + g[1] * g[1];
        }
    }
    let n = file.sample_poses.len().max(1) as f64;
    let errors: Vec<f64> = (sums.iter().zip(&file.residual_scales))
        .map(|(s, sigma)| sigma / (s / n).sqrt())
        .collect();
    let best = (errors.iter().copied())
        .filter(|e| *e > 0.0)
        .fold(f64::INFINITY, f64::min);
    (errors.iter())
        .map(|&e| {
            // A flat map (e = ∞) says nothing of the pose: α = 0.
            if e.is_nan() || e <= 0.0 || !best.is_finite() {
                1.0
            } else {
                (best / e).min(1.0)
            }
        })
        .collect()
}

/// −2 ln(1 − a + a e^{−z²/2}), the χ² term of a contour discounted by `a`, and its slope in z.
pub(super) fn discounted_term(z: f64, a: f64) -> (f64, f64) {
    if a >= 1.0 {
        return (z * z, 2.0 * z);
    }
    let half = -0.5 * z * z;
    // ln(1 − a(1 − e)) with 1 − e from expm1: exact for small z.
    let t = -2.0 * (a * half.exp_m1()).ln_1p();
    let e = half.exp();
    (t, 2.0 * a * z * e / (1.0 - a + a * e))
}

/// A discounted group's members: (feature, value, 1/σ, α).
type Members = Vec<(usize, f64, f64, f64)>;

impl Frame<'_> {
    /// The level of `group` under the model's rule, with the threshold `limit` (+∞: exact):
    /// exact when at most `limit`, else some value above it.
    pub(super) fn grid_level(&mut self, group: GroupMask, limit: f64) -> GridLevel {
        if self.model.fusion.plain() {
            return self.sum_level(group, limit);
        }
        if self.model.fusion.rule == Rule::Cautious {
            return self.cautious_level(group, limit);
        }
        self.discounted_level(group, limit)
    }

    /// Dempster's level of the (discounted) functions.
    fn product_level(&mut self, group: GroupMask, limit: f64) -> GridLevel {
        if self.model.fusion.alpha.is_empty() {
            self.sum_level(group, limit)
        } else {
            self.discounted_level(group, limit)
        }
    }

    /// K(G) − Σ K_i + max K_i (module documentation). With a threshold T, Dempster's level is
    /// asked up to T + Σ of every usable feature's K_i: one limit for the frame (so a group's
    /// kept nodes extend to its children) above every group's T + Σ K_i − max K_i.
    fn cautious_level(&mut self, group: GroupMask, limit: f64) -> GridLevel {
        let own = |frame: &mut Self, mask: GroupMask| {
            members(mask & !frame.past_bit())
                .map(|i| frame.product_level(1 << i, f64::INFINITY).value)
                .fold((0.0, 0.0f64), |(sum, max), k| (sum + k, max.max(k)))
        };
        let (sum, max) = own(self, group);
        let widened = if limit.is_finite() {
            limit + own(self, self.usable_mask).0
        } else {
            f64::INFINITY
        };
        let product = self.product_level(group, widened);
        let value = if sum.is_finite() && product.value.is_finite() {
            (product.value - sum + max).max(max)
        } else {
            f64::INFINITY
        };
        GridLevel {
            value,
            point: product.point,
        }
    }

    /// ½ min over the sub-grid of Σ t_i (and the carried belief's term): module documentation.
    pub(super) fn discounted_level(&mut self, group: GroupMask, limit: f64) -> GridLevel {
        let none = GridLevel {
            value: if group == 0 { 0.0 } else { f64::INFINITY },
            point: None,
        };
        if group == 0 {
            return none;
        }
        if let Some(&(level, used)) = self.grid.discounted.get(&group) {
            if used == f64::INFINITY || level.value <= used || used == limit {
                return level;
            }
        }
        let Some(list) = self.members_of(group) else {
            return none;
        };
        let d = self.values.len();
        let counts = self.model.blocks.counts;
        let mut blocks: Vec<(f64, usize)> = {
            let bounds = self.block_bounds();
            (0..counts[0] * counts[1])
                .map(|b| {
                    let row = &bounds[b * d..(b + 1) * d];
                    let bound = (list.iter())
                        .map(|&(i, _, _, a)| discounted_term(row[i].sqrt(), a).0)
                        .sum::<f64>();
                    (bound, b)
                })
                .collect()
        };
        blocks.sort_by(|a, b| a.0.total_cmp(&b.0));
        let (origin, step, nodes, _) = self.model.surrogate.grid();
        let mut cut = with_slack(if limit.is_finite() {
            2.0 * limit
        } else {
            let pose = self.best_sample(group).0;
            let index = |k: usize| {
                let x = ((pose[k] - origin[k]) / step[k]).round();
                (x.max(0.0) as usize).min(nodes[k] - 1)
            };
            self.sub_grid_value(
                &list,
                group,
                index(1) * nodes[0] + index(0),
                [0.0; 2],
                f64::INFINITY,
            )
        });
        let mut best = (f64::INFINITY, None);
        for (bound, b) in blocks {
            if bound > cut {
                break;
            }
            let (bc, br) = (b % counts[0], b / counts[0]);
            for r in br * BLOCK..((br + 1) * BLOCK).min(nodes[1]) {
                for c in bc * BLOCK..((bc + 1) * BLOCK).min(nodes[0]) {
                    let n = r * nodes[0] + c;
                    if self.node_bound(&list, n, cut) > cut {
                        continue;
                    }
                    for dy in SUB {
                        for dx in SUB {
                            let offset = [dx * step[0], dy * step[1]];
                            // A sum that reaches the best so far is not kept: stop it there.
                            let v = self.sub_grid_value(&list, group, n, offset, best.0);
                            if v < best.0 {
                                let p = self.node_pose(n);
                                best = (v, Some([p[0] + offset[0], p[1] + offset[1]]));
                                cut = cut.min(with_slack(v));
                            }
                        }
                    }
                }
            }
        }
        let level = GridLevel {
            value: 0.5 * best.0,
            point: best.1,
        };
        self.grid.discounted.insert(group, (level, limit));
        level
    }

    /// The group's features with their value, 1/σ and α; `None` when one has no value.
    fn members_of(&self, group: GroupMask) -> Option<Members> {
        let d = self.values.len();
        (members(group).filter(|&i| i < d))
            .map(|i| {
                let y = self.values[i]?;
                let inv = 1.0 / self.model.file.residual_scales[i];
                Some((i, y, inv, self.model.fusion.reliability(i)))
            })
            .collect()
    }

    /// Σ t_i over node `n`'s cell (each feature's own lower bound from its reach), stopping
    /// once beyond `cut`; the carried belief adds nothing.
    fn node_bound(&self, list: &Members, n: usize, cut: f64) -> f64 {
        let (_, step, _, table) = self.model.surrogate.grid();
        let d = self.values.len();
        let mut lower = 0.0;
        for &(i, y, inv, a) in list {
            let [f, fx, fy, _] = table[n * d + i];
            let reach = 0.5 * (fx.abs() * step[0] + fy.abs() * step[1]) * inv;
            lower += discounted_term((((y - f) * inv).abs() - reach).max(0.0), a).0 * (1.0 - 1e-12);
            if lower > cut {
                break;
            }
        }
        lower
    }

    /// Σ t_i (maps linear from node `n`) plus the carried belief's term at node + `offset`, or
    /// a partial sum at least `stop` once one reaches it: every term is ≥ 0 and rounding is
    /// monotone, so the whole sum is not below `stop` either.
    pub(super) fn sub_grid_value(
        &self,
        list: &Members,
        group: GroupMask,
        n: usize,
        offset: [f64; 2],
        stop: f64,
    ) -> f64 {
        let (_, _, _, table) = self.model.surrogate.grid();
        let d = self.values.len();
        let mut v = 0.0;
        for &(i, y, inv, a) in list {
            let [f, fx, fy, _] = table[n * d + i];
            v += discounted_term((y - f - fx * offset[0] - fy * offset[1]) * inv, a).0;
            if v >= stop {
                return v;
            }
        }
        if let (Some(past), true) = (&self.past, group & self.past_bit() != 0) {
            let p = self.node_pose(n);
            v += past.chi2([p[0] + offset[0], p[1] + offset[1]]).0;
        }
        v
    }

    /// The group's members for the exhaustive check in the tests.
    #[cfg(test)]
    pub(super) fn test_members(&self, group: GroupMask) -> Option<Members> {
        self.members_of(group)
    }
}

#[cfg(test)]
#[path = "rules_tests.rs"]
mod tests;
