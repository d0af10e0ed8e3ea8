//! From a chosen group to a pose estimate: the relative plausibility of the sample poses (or
//! their pignistic probability), the estimator (weighted mean or MAP) and the uncertainty
//! (weighted spread and quantile radius).

use super::group_search::GroupMask;
use super::settings::PoseRule;
use super::tracker::{Tracker, Uncertainty, Usable};
use crate::evidence::{dempster_all, MassFunction};

impl Tracker {
    /// Relative plausibility of the sample poses under a group: the normalised product of the
    /// members' contours (the fast path; equal to the relative plausibility of the combination).
    pub(super) fn plausibility(
        &self,
        group: GroupMask,
        usable: &[Option<Usable>],
    ) -> Option<Vec<f64>> {
        let cells = self.cell_count();
        let mut w = vec![1.0; cells];
        // Member by member over the cells: each cell's product still takes its factors in
        // member order, so the same bits as cell by cell, without a test per cell and member.
        for (i, m) in usable.iter().enumerate() {
            if let (true, Some(m)) = (group >> i & 1 == 1, m) {
                for (wu, &s) in w.iter_mut().zip(self.to_cells[i].assignment()) {
                    *wu *= m.contour[s];
                }
            }
        }
        let mut z: f64 = w
            .iter()
            .zip(&self.cell_size)
            .map(|(x, &c)| x * c as f64)
            .sum();
        if !(z > 0.0 && z.is_finite()) {
            // Underflow with many small factors: redo in the log domain.
            let mut logs = vec![0.0f64; cells];
            for (u, lu) in logs.iter_mut().enumerate() {
                for (i, m) in usable.iter().enumerate() {
                    if group >> i & 1 == 1 {
                        if let Some(m) = m {
                            *lu += m.contour[self.to_cells[i].assignment()[u]].ln();
                        }
                    }
                }
            }
            let max = logs.iter().fold(f64::NEG_INFINITY, |a, &b| a.max(b));
            if !max.is_finite() {
                return None;
            }
            for (x, l) in w.iter_mut().zip(&logs) {
                *x = (l - max).exp();
            }
            z = w
                .iter()
                .zip(&self.cell_size)
                .map(|(x, &c)| x * c as f64)
                .sum();
        }
        Some(self.cell_of.iter().map(|&u| w[u] / z).collect())
    }

    /// Pignistic probability of the sample poses under a combined function on the cells.
    fn pignistic(&self, on_cells: &MassFunction) -> Vec<f64> {
        let mut bet = vec![0.0; self.cell_count()];
        for (set, m) in on_cells.focal() {
            let size: usize = set.iter().map(|u| self.cell_size[u]).sum();
            if size == 0 {
                continue;
            }
            for u in set.iter() {
                bet[u] += m / size as f64;
            }
        }
        self.cell_of.iter().map(|&u| bet[u]).collect()
    }

    /// Estimate, weights and uncertainty of one group.
    pub(super) fn estimate_group(
        &self,
        group: GroupMask,
        usable: &[Option<Usable>],
    ) -> Option<([f64; 2], Vec<f64>, Uncertainty)> {
        if !self.plain() {
            return self.fused_estimate(group, usable);
        }
        let pl = self.plausibility(group, usable)?;
        let weights = match self.settings.estimator {
            PoseRule::Pignistic => {
                let combined = dempster_all(&self.on_cells(group, usable)?).ok()?.mass?;
                self.pignistic(&combined)
            }
            _ => pl.clone(),
        };
        let (estimate, uncertainty) = self.estimate_from(&weights)?;
        Some((estimate, pl, uncertainty))
    }

    /// The splitting policy's final estimate (§4.2): each alternative's relative plausibility
    /// (scaled to maximum 1) discounted by its reliability r = (lowest validation error among the
    /// alternatives) / (its own), then combined by Dempster's rule, whose contour on the poses is
    /// the product of the discounted contours 1 − r + r·pl. The most reliable alternative is
    /// undiscounted; one that is half as precise keeps half its say. `None` with fewer than two
    /// alternatives, without a validation error for each, or when the discounted alternatives
    /// are in total conflict (the caller then reports the first alternative, as without
    /// reliabilities). The pignistic estimator reads the combined contour as its probability.
    pub(super) fn weigh_alternatives(
        &self,
        alternatives: &[(GroupMask, Vec<f64>)],
    ) -> Option<Weighed> {
        if alternatives.len() < 2 {
            return None;
        }
        let errors: Vec<f64> = alternatives
            .iter()
            .map(|(g, _)| self.model.group_error(*g))
            .collect::<Option<_>>()?;
        let best = errors.iter().copied().fold(f64::INFINITY, f64::min);
        let reliability: Vec<f64> = errors
            .iter()
            .map(|&e| if e > 0.0 { best / e } else { 1.0 })
            .collect();
        let mut combined = vec![1.0; self.model.poses().len()];
        for ((_, pl), &r) in alternatives.iter().zip(&reliability) {
            let max = pl.iter().copied().fold(0.0f64, f64::max);
            if max <= 0.0 {
                return None;
            }
            for (c, &p) in combined.iter_mut().zip(pl) {
                *c *= 1.0 - r + r * p / max;
            }
        }
        let total: f64 = combined.iter().sum();
        if !(total > 0.0 && total.is_finite()) {
            return None;
        }
        combined.iter_mut().for_each(|c| *c /= total);
        let (estimate, uncertainty) = self.estimate_from(&combined)?;
        Some(Weighed {
            reliability,
            estimate,
            plausibility: combined,
            uncertainty,
        })
    }

    /// The pose the estimator reads off `weights` over the sample poses (the most weighted pose
    /// for MAP, the weighted mean otherwise), with the uncertainty of the weights around it.
    pub(super) fn estimate_from(&self, weights: &[f64]) -> Option<([f64; 2], Uncertainty)> {
        let poses = self.model.poses();
        let estimate = match self.settings.estimator {
            PoseRule::Map => {
                let mut best = 0;
                for (q, &x) in weights.iter().enumerate() {
                    if x > weights[best] {
                        best = q;
                    }
                }
                poses[best]
            }
            _ => weighted_mean(weights, poses)?,
        };
        let uncertainty = uncertainty(weights, poses, estimate, self.settings.uncertainty_mass);
        Some((estimate, uncertainty))
    }
}

/// The splitting policy's reliability-weighted estimate.
pub(super) struct Weighed {
    /// Each alternative's reliability, in their order.
    pub(super) reliability: Vec<f64>,
    pub(super) estimate: [f64; 2],
    /// Combined relative plausibility of the sample poses.
    pub(super) plausibility: Vec<f64>,
    pub(super) uncertainty: Uncertainty,
}

/// Weighted RMS distance from `centre`, the smallest radius holding `share` of the weight and
/// the weighted second moments about `centre`.
fn uncertainty(weights: &[f64], poses: &[[f64; 2]], centre: [f64; 2], share: f64) -> Uncertainty {
    let mut moments = [[0.0; 2]; 2];
    // Squared distances: the quantile is the same, and no square root per pose.
    let mut items: Vec<(f64, f64)> = weights
        .iter()
        .zip(poses)
        .filter(|(w, _)| **w > 0.0)
        .map(|(&w, p)| {
            let (dx, dy) = (p[0] - centre[0], p[1] - centre[1]);
            moments[0][0] += w * dx * dx;
            moments[0][1] += w * dx * dy;
            moments[1][1] += w * dy * dy;
            (dx * dx + dy * dy, w)
        })
        .collect();
    let total: f64 = items.iter().map(|x| x.1).sum();
    if items.is_empty() || total <= 0.0 {
        return Uncertainty {
            spread: 0.0,
            radius: 0.0,
            covariance: [[0.0; 2]; 2],
        };
    }
    let spread = (items.iter().map(|(d2, w)| d2 * w).sum::<f64>() / total).sqrt();
    let radius = weighted_quantile(&mut items, share * total).sqrt();
    let (xx, xy, yy) = (
        moments[0][0] / total,
        moments[0][1] / total,
        moments[1][1] / total,
    );
    Uncertainty {
        spread,
        radius,
        covariance: [[xx, xy], [xy, yy]],
    }
}

/// Σ w q / Σ w (poses are validated finite, weights are finite and non-negative by construction).
fn weighted_mean(weights: &[f64], poses: &[[f64; 2]]) -> Option<[f64; 2]> {
    let (mut sx, mut sy, mut sw) = (0.0, 0.0, 0.0);
    for (w, p) in weights.iter().zip(poses) {
        sx += w * p[0];
        sy += w * p[1];
        sw += w;
    }
    (sw > 0.0 && sw.is_finite()).then(|| [sx / sw, sy / sw])
}

/// Smallest distance d such that the weight of items with distance ≤ d reaches `target`
/// (expected linear time by repeated selection).
fn weighted_quantile(items: &mut [(f64, f64)], mut target: f64) -> f64 {
    let mut slice = items;
    let mut last = 0.0;
    loop {
        if slice.is_empty() {
            return last;
        }
        let mid = slice.len() / 2;
        slice.select_nth_unstable_by(mid, |a, b| a.0.total_cmp(&b.0));
        let below: f64 = slice[..mid].iter().map(|x| x.1).sum();
        let (d, w) = slice[mid];
        if below >= target && mid > 0 {
            slice = &mut slice[..mid];
        } else if below + w >= target {
            return d;
        } else {
            target -= below + w;
            last = d;
            let rest = std::mem::take(&mut slice);
            slice = &mut rest[mid + 1..];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weighted_quantile_by_hand() {
        let mut items = vec![(3.0, 0.25), (1.0, 0.25), (2.0, 0.25), (4.0, 0.25)];
        assert_eq!(weighted_quantile(&mut items, 0.5), 2.0);
        assert_eq!(weighted_quantile(&mut items, 0.51), 3.0);
        assert_eq!(weighted_quantile(&mut items, 1.0), 4.0);
        assert_eq!(weighted_quantile(&mut items, 1.0 + 1e-9), 4.0);
        assert_eq!(weighted_quantile(&mut items, 0.1), 1.0);
    }
}
