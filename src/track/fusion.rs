//! The rule seam (issue 30): which features are combined ([`Combine`]), Shafer's discounting of
//! each before the rule ([`Discount`]) and the relative plausibility of the sample poses under any
//! [`Rule`].
//!
//! Exact shortcuts on the cells, from each member's plausibility p'ᵢ = αᵢ pᵢ + 1 − αᵢ of the cell
//! (pᵢ its measurement's contour, αᵢ its reliability):
//!
//! - Dempster's and the conjunctive rule: Π p'ᵢ (the conjunctive contour; normalising does not
//!   change the relative plausibility, nor the pignistic probability);
//! - Murphy's: (Σ p'ᵢ / n)ⁿ (the mean's contour, combined with itself n − 1 times);
//! - the disjunctive rule: 1 − Π (1 − p'ᵢ) (implicabilities multiply);
//! - Yager's, undiscounted: Π pᵢ + κ, with κ = 1 − e^(−K) from the group's exact level K.
//!
//! Dubois and Prade's, PCR6, the cautious rule, Yager's after discounting and the pignistic
//! estimator of any rule but Dempster's run the general combination on the cells
//! ([`combine_all_within`]); their cost is bounded when the tracker is built
//! ([`MAX_RULE_TUPLES`], [`MAX_CAUTIOUS_FRAME`]), so a run is refused rather than slow.
//!
//! Levels of conflict (the selection's, `conflict_level`, `full_conflict_level`) stay those of
//! the undiscounted measurements for every rule: detection and threshold mean the same thing
//! whatever rule combines the features.

use std::collections::HashMap;

use serde::{Deserialize, Serialize};

use super::group_search::{members, GroupMask};
use super::settings::{PoseRule, TrackSettings};
use super::tracker::{Tracker, Usable};
use super::tracker_model::TrackerModel;
use super::TrackError;
use crate::evidence::{combine_all_within, Rule, WorkLimits, MAX_CAUTIOUS_FRAME};

/// Most focal-set tuples per frame the rules that enumerate them (Dubois and Prade's, PCR6) may
/// meet: the product over the features of their state count plus one (Ω after discounting).
pub const MAX_RULE_TUPLES: u64 = 1 << 16;

/// Which features a frame combines.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Combine {
    /// The group the selection policy chooses on the conflict graph (the paper's).
    #[default]
    Selected,
    /// Every usable feature, whatever its conflict: the rule must cope with it.
    All,
}

impl Combine {
    pub(super) fn is_default(&self) -> bool {
        *self == Combine::Selected
    }
}

/// Shafer's discounting of each feature before the rule: m'(A) = α m(A), m'(Ω) += 1 − α.
#[derive(Clone, Copy, Debug, PartialEq, Default, Serialize, Deserialize)]
#[serde(try_from = "RawDiscount", into = "RawDiscount")]
pub enum Discount {
    /// No discounting (α = 1).
    #[default]
    None,
    /// α_f = (lowest validation error of any feature) / (feature f's own): each feature tracked
    /// alone on the validation motion; the most precise keeps its full say.
    Learned,
    /// One reliability for every feature, in [0, 1].
    Fixed(f64),
}

impl Discount {
    pub(super) fn is_none(&self) -> bool {
        *self == Discount::None
    }
}

/// Serde form: `"none"`, `"learned"` or a number.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(untagged)]
enum RawDiscount {
    Value(f64),
    Name(String),
}

impl TryFrom<RawDiscount> for Discount {
    type Error = String;
    fn try_from(raw: RawDiscount) -> Result<Self, String> {
        match raw {
            RawDiscount::Value(v) => Ok(Discount::Fixed(v)),
            RawDiscount::Name(n) if n == "none" => Ok(Discount::None),
            RawDiscount::Name(n) if n == "learned" => Ok(Discount::Learned),
            RawDiscount::Name(n) => Err(format!(
                "unknown discount `{n}`: use \"none\", \"learned\" or a reliability in [0, 1]"
            )),
        }
    }
}

impl From<Discount> for RawDiscount {
    fn from(d: Discount) -> Self {
        match d {
            Discount::None => RawDiscount::Name("none".into()),
            Discount::Learned => RawDiscount::Name("learned".into()),
            Discount::Fixed(v) => RawDiscount::Value(v),
        }
    }
}

/// Each feature's reliability under `settings`, and the check that the rule's general
/// combination stays within its bounds on this model.
///
/// # Errors
/// [`TrackError::InvalidSetting`] for learned reliabilities without validation errors, and for
/// a rule whose general combination would exceed [`MAX_RULE_TUPLES`] or [`MAX_CAUTIOUS_FRAME`].
pub(super) fn reliabilities(
    model: &TrackerModel,
    settings: &TrackSettings,
    cells: usize,
) -> Result<Vec<f64>, TrackError> {
    let features = model.features();
    let bad = |field, reason: String| Err(TrackError::InvalidSetting { field, reason });
    match settings.rule {
        Rule::DuboisPrade | Rule::Pcr6 => {
            let tuples = features.iter().try_fold(1u64, |t, f| {
                t.checked_mul(f.refining.coarse_size() as u64 + 1)
                    .filter(|&t| t <= MAX_RULE_TUPLES)
            });
            if tuples.is_none() {
                return bad(
                    "rule",
                    format!(
                        "rule `{}` enumerates every tuple of focal sets, and these {} features' \
                         state counts give more than {MAX_RULE_TUPLES} per frame: use fewer states \
                         or another rule",
                        settings.rule.name(),
                        features.len()
                    ),
                );
            }
        }
        Rule::Cautious if cells > MAX_CAUTIOUS_FRAME => {
            return bad(
                "rule",
                format!(
                    "the cautious rule works on all 2ⁿ subsets of the cells, so at most \
                     {MAX_CAUTIOUS_FRAME} cells; this model has {cells}: use fewer states or \
                     another rule"
                ),
            );
        }
        _ => {}
    }
    match settings.discount {
        Discount::None => Ok(vec![1.0; features.len()]),
        Discount::Fixed(a) => Ok(vec![a; features.len()]),
        Discount::Learned => {
            let errors: Option<Vec<f64>> = features.iter().map(|f| f.validation_error).collect();
            let Some(errors) = errors else {
                return bad(
                    "discount",
                    "`learned` reliabilities come from each feature's validation error, and \
                     this model has none: give the scenario a [validation] motion"
                        .into(),
                );
            };
            let best = errors.iter().copied().fold(f64::INFINITY, f64::min);
            Ok(errors
                .iter()
                .map(|&e| if e > 0.0 { (best / e).min(1.0) } else { 1.0 })
                .collect())
        }
    }
}

impl Tracker {
    /// Whether the paper's path applies: Dempster's (or the conjunctive) rule, undiscounted.
    pub(super) fn plain(&self) -> bool {
        matches!(self.settings.rule, Rule::Dempster | Rule::Conjunctive)
            && self.alpha.iter().all(|&a| a == 1.0)
    }

    /// Relative plausibility of the sample poses under the group combined by the rule.
    pub(super) fn fused_plausibility(
        &self,
        group: GroupMask,
        usable: &[Option<Usable>],
    ) -> Option<Vec<f64>> {
        if self.plain() {
            return self.plausibility(group, usable);
        }
        let w = match self.shortcut_weights(group, usable) {
            Some(w) => w,
            None => self.general_weights(group, usable, false)?,
        };
        self.on_poses(&w)
    }

    /// The pignistic probability of the sample poses under any rule (the general combination).
    pub(super) fn fused_pignistic(
        &self,
        group: GroupMask,
        usable: &[Option<Usable>],
    ) -> Option<Vec<f64>> {
        self.on_poses(&self.general_weights(group, usable, true)?)
    }

    /// Cell weights w(u) ≥ 0 → poses, normalised to sum 1 (`None` when every weight is 0).
    fn on_poses(&self, w: &[f64]) -> Option<Vec<f64>> {
        let z: f64 = w
            .iter()
            .zip(&self.cell_size)
            .map(|(x, &c)| x * c as f64)
            .sum();
        (z > 0.0 && z.is_finite()).then(|| self.cell_of.iter().map(|&u| w[u] / z).collect())
    }

    /// The exact shortcuts of the module's documentation on the cells (`None`: no shortcut for
    /// this rule and discounting; `Some` of all zeros when every product vanished).
    pub(super) fn shortcut_weights(
        &self,
        group: GroupMask,
        usable: &[Option<Usable>],
    ) -> Option<Vec<f64>> {
        let rule = self.settings.rule;
        let discounted = self.alpha.iter().any(|&a| a < 1.0);
        if !matches!(
            (rule, discounted),
            (
                Rule::Dempster | Rule::Conjunctive | Rule::Murphy | Rule::Disjunctive,
                _
            ) | (Rule::Yager, false)
        ) {
            return None;
        }
        let list: Vec<(usize, &Usable)> = members(group)
            .filter_map(|i| usable[i].as_ref().map(|u| (i, u)))
            .collect();
        let n = list.len() as f64;
        let p = |u: usize, &(i, m): &(usize, &Usable)| {
            let a = self.alpha[i];
            a * m.contour[self.to_cells[i].assignment()[u]] * m.scale + (1.0 - a)
        };
        let cells = self.cell_count();
        // Logs of the products, so that many small factors do not underflow before scaling.
        let mut logs: Vec<f64> = (0..cells)
            .map(|u| match rule {
                Rule::Murphy => n * (list.iter().map(|f| p(u, f)).sum::<f64>() / n).ln(),
                Rule::Disjunctive => {
                    (1.0 - list.iter().map(|f| 1.0 - p(u, f)).product::<f64>()).ln()
                }
                _ => list.iter().map(|f| p(u, f).ln()).sum(),
            })
            .collect();
        if rule == Rule::Yager {
            let level = self.level(group, usable, &mut HashMap::new(), f64::INFINITY);
            let kappa = -(-level).exp_m1();
            return Some(logs.iter().map(|l| l.exp() + kappa).collect());
        }
        let max = logs.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        if !max.is_finite() {
            return Some(vec![0.0; cells]);
        }
        logs.iter_mut().for_each(|l| *l = (*l - max).exp());
        Some(logs)
    }

    /// The general combination on the cells: the discounted members combined by the rule, read
    /// as its contour (or its pignistic probability). `None` on total conflict under Dempster's
    /// rule or an error of the combination (counted as a failed combination).
    pub(super) fn general_weights(
        &self,
        group: GroupMask,
        usable: &[Option<Usable>],
        pignistic: bool,
    ) -> Option<Vec<f64>> {
        let fs = members(group)
            .filter(|&i| usable[i].is_some())
            .map(|i| {
                let m = usable[i].as_ref()?;
                let on_cells = self.to_cells[i].extend(&m.mass).ok()?;
                on_cells.discount(self.alpha[i]).ok()
            })
            .collect::<Option<Vec<_>>>()?;
        let combined = combine_all_within(self.settings.rule, &fs, &WorkLimits::DEFAULT)
            .ok()?
            .mass?;
        Some(if pignistic {
            let mut bet = vec![0.0; self.cell_count()];
            for (set, m) in combined.focal() {
                // The pose-level BetP: each pose of A takes m(A) / |A| poses.
                let size: usize = set.iter().map(|u| self.cell_size[u]).sum();
                for u in set.iter() {
                    bet[u] += m / size as f64;
                }
            }
            bet
        } else {
            combined.contour()
        })
    }

    /// Estimate, weights and uncertainty of one group under a rule other than the plain one.
    pub(super) fn fused_estimate(
        &self,
        group: GroupMask,
        usable: &[Option<Usable>],
    ) -> Option<([f64; 2], Vec<f64>, super::Uncertainty)> {
        let pl = self.fused_plausibility(group, usable)?;
        let weights = match self.settings.estimator {
            PoseRule::Pignistic => self.fused_pignistic(group, usable)?,
            _ => pl.clone(),
        };
        let (estimate, uncertainty) = self.estimate_from(&weights)?;
        Some((estimate, pl, uncertainty))
    }
}

#[cfg(test)]
#[path = "fusion_tests.rs"]
mod tests;
