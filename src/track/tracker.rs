//! The per-frame tracker: the frame types, the [`Tracker`] and its public entry points
//! ([`Tracker::track`], [`Tracker::pairwise_conflicts`], [`Tracker::full_conflict_level`]).
//! Sibling rooms hold the steps: `cells` (cells and state co-occurrences, built once per model),
//! `conflict` (levels of conflict of pairs and groups), `select` (conflict graph and group
//! selection) and `estimate` (plausibility, estimate and uncertainty).
//!
//! Work is done on the *cells* of the model: the classes of sample poses that share the same state
//! in every feature. Every extended measurement function has focal sets that are unions of cells,
//! so the cells discern all relevant interactions (Definition 2.6): conflicts and combinations on
//! the cells equal those on the sample poses. Three exact shortcuts avoid combining at all:
//!
//! - pairwise conflicts are computed on the features' own frames through precomputed state
//!   co-occurrences;
//! - a group's level of conflict is, for Bayesian functions, a sum over the state tuples that
//!   occur on the cells, and for consonant functions Dempster's rule on the Pareto-minimal level
//!   vectors of the cells (nested focal sets meet the cells iff they meet those);
//! - the relative plausibility of the sample poses is the normalised product of the members'
//!   contour functions, for both constructors.
//!
//! Dempster's rule on the cells remains the reference (tests) and the fallback on underflow, and
//! gives the combined function the pignistic estimator needs.

use std::collections::HashMap;

use serde::{Deserialize, Serialize};

use super::cells::Cells;
use super::estimate::Weighed;
use super::select::{lex, GroupMask, Selection};
use super::settings::{CheckedTrackSettings, TrackSettings};
use super::tracker_model::TrackerModel;
use super::TrackError;
use crate::evidence::{
    from_likelihoods, Constructor, LikelihoodIssue, MassFunction, Refining, Subset,
};

/// Why a feature did not take part in a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FeatureIssue {
    /// No likelihoods were given (feature missing in this frame).
    Missing,
    /// The likelihoods were unusable (NaN, infinite, negative or all zero).
    Likelihood(LikelihoodIssue),
    /// The likelihood vector does not have one value per state.
    WrongLength {
        /// Number of states of the feature.
        expected: usize,
        /// Number of values given.
        found: usize,
    },
}

/// Flags of one frame.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct FrameFlags {
    /// Features that took no part, with the reason (ascending feature index).
    pub unusable: Vec<(usize, FeatureIssue)>,
    /// Usable features left out of the chosen group by the conflict threshold (normal operation;
    /// on fallback, every usable feature but the fallback one).
    pub excluded: Vec<usize>,
    /// No eligible group existed (e.g. every pair conflicts beyond the threshold), so the single
    /// usable feature with the lowest validation error was used (no validation errors: lowest
    /// index; features with a validation error come before those without).
    pub fallback: bool,
    /// No feature was usable: there is no estimate.
    pub no_usable_feature: bool,
    /// The chosen group's combination gave no usable plausibility (every sample pose's product
    /// underflowed to zero): there is no estimate.
    pub combination_failed: bool,
}

impl FrameFlags {
    /// Whether the frame deserves attention: an unusable feature, a fallback or no estimate.
    pub fn any(&self) -> bool {
        !self.unusable.is_empty()
            || self.fallback
            || self.no_usable_feature
            || self.combination_failed
    }

    /// Features with no likelihoods in this frame.
    pub fn missing(&self) -> impl Iterator<Item = usize> + '_ {
        self.unusable
            .iter()
            .filter(|(_, i)| *i == FeatureIssue::Missing)
            .map(|(f, _)| *f)
    }
}

/// Spread of the weights behind an estimate (the same weights the estimator used: relative
/// plausibility, or pignistic probability for [`PoseRule::Pignistic`](super::PoseRule::Pignistic)).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Uncertainty {
    /// RMS distance of the sample poses from the estimate, weighted (mm).
    pub spread: f64,
    /// Smallest radius around the estimate holding `uncertainty_mass` of the weight (mm).
    pub radius: f64,
}

/// One alternative estimate of the splitting policy.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Alternative {
    /// Features of the group (ascending).
    pub group: Vec<usize>,
    /// The group's level of conflict.
    pub conflict_level: f64,
    /// Its estimate.
    pub estimate: [f64; 2],
    /// Its uncertainty.
    pub uncertainty: Uncertainty,
    /// Its weight in the final estimate, in (0, 1] (1 for the most reliable alternative); `None`
    /// when the alternatives were not weighed (one alternative, or no validation errors).
    pub reliability: Option<f64>,
}

/// The tracker's output for one frame.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FrameEstimate {
    /// Estimated pose (mm); `None` when no feature was usable.
    pub estimate: Option<[f64; 2]>,
    /// Features combined for the estimate (ascending): with weighed splitting alternatives, every
    /// feature of any alternative.
    pub group: Vec<usize>,
    /// Level of conflict of the chosen group (0 for a single feature; with weighed splitting
    /// alternatives, the most reliable one's); `None` without estimate.
    pub conflict_level: Option<f64>,
    /// Level of conflict of every usable feature together (+∞ on total conflict, 0 with one
    /// usable feature): how incoherent the frame's measurements are, whatever was chosen.
    /// `None` without a usable feature.
    pub full_conflict_level: Option<f64>,
    /// Uncertainty of the estimate.
    pub uncertainty: Option<Uncertainty>,
    /// Relative plausibility of every sample pose under the chosen group (empty without estimate).
    pub plausibility: Vec<f64>,
    /// Alternatives of the splitting policy, the chosen one first (empty for other policies).
    pub alternatives: Vec<Alternative>,
    /// Flags.
    pub flags: FrameFlags,
}

/// Measurement functions of a frame (`None` for unusable features) and the issues found.
pub(super) type Measured = (Vec<Option<Usable>>, Vec<(usize, FeatureIssue)>);

/// A usable feature of one frame.
pub(super) struct Usable {
    /// Contour on the feature's own frame, scaled to max 1.
    pub(super) contour: Vec<f64>,
    /// The factor the contour was divided by (its maximum).
    pub(super) scale: f64,
    /// Consonant functions: level of every state (number of focal sets not containing it), so
    /// that the focal sets are {state : level ≤ k}.
    pub(super) level: Vec<u32>,
    /// Measurement function on the feature's own frame.
    pub(super) mass: MassFunction,
}

impl FrameEstimate {
    /// A frame with no estimate and no combined group; `flags` say why.
    pub(super) fn without_estimate(flags: FrameFlags) -> Self {
        Self {
            estimate: None,
            group: Vec::new(),
            conflict_level: None,
            full_conflict_level: None,
            uncertainty: None,
            plausibility: Vec::new(),
            alternatives: Vec::new(),
            flags,
        }
    }
}

/// The evidential tracker: a validated model and settings, with per-model precomputations.
#[derive(Clone, Debug)]
pub struct Tracker {
    pub(super) model: TrackerModel,
    pub(super) settings: TrackSettings,
    /// Cell of every sample pose.
    pub(super) cell_of: Vec<usize>,
    /// Number of sample poses of every cell.
    pub(super) cell_size: Vec<usize>,
    /// Per feature, the refining of its frame onto the cells.
    pub(super) to_cells: Vec<Refining>,
    /// `co[i][j][a]` for i < j: the states of feature j that occur together with state a of i.
    pub(super) co: Vec<Vec<Vec<Subset>>>,
}

impl Tracker {
    /// Build a tracker (precomputes the cells and the state co-occurrences).
    ///
    /// # Errors
    /// [`TrackError::Evidence`] if a refining onto the cells cannot be built (not expected for a
    /// validated model).
    pub fn new(model: TrackerModel, settings: CheckedTrackSettings) -> Result<Self, TrackError> {
        let Cells {
            cell_of,
            cell_size,
            to_cells,
            co,
        } = Cells::new(&model)?;
        Ok(Tracker {
            model,
            settings: settings.get().clone(),
            cell_of,
            cell_size,
            to_cells,
            co,
        })
    }

    /// The model.
    pub fn model(&self) -> &TrackerModel {
        &self.model
    }

    /// The settings.
    pub fn settings(&self) -> &TrackSettings {
        &self.settings
    }

    /// Number of cells (classes of sample poses with the same state in every feature).
    pub fn cell_count(&self) -> usize {
        self.cell_size.len()
    }

    /// Measurement functions of one frame; issues for the unusable features.
    pub(super) fn measure(&self, likelihoods: &[Option<Vec<f64>>]) -> Result<Measured, TrackError> {
        let features = self.model.features();
        if likelihoods.len() != features.len() {
            return Err(TrackError::FeatureInputCount {
                expected: features.len(),
                found: likelihoods.len(),
            });
        }
        let mut usable = Vec::with_capacity(features.len());
        let mut issues = Vec::new();
        for (i, (l, f)) in likelihoods.iter().zip(features).enumerate() {
            let n = f.refining.coarse_size();
            let Some(g) = l else {
                issues.push((i, FeatureIssue::Missing));
                usable.push(None);
                continue;
            };
            if g.len() != n {
                issues.push((
                    i,
                    FeatureIssue::WrongLength {
                        expected: n,
                        found: g.len(),
                    },
                ));
                usable.push(None);
                continue;
            }
            let m = from_likelihoods(self.settings.constructor, g).map_err(|source| {
                TrackError::Evidence {
                    feature: Some(i),
                    source,
                }
            })?;
            if let Some(issue) = m.issue {
                issues.push((i, FeatureIssue::Likelihood(issue)));
                usable.push(None);
                continue;
            }
            let mut contour = m.mass.contour();
            let max = contour.iter().fold(0.0f64, |a, &b| a.max(b));
            if max > 0.0 {
                for c in &mut contour {
                    *c /= max;
                }
            }
            let level = match self.settings.constructor {
                Constructor::Consonant => (0..n)
                    .map(|a| {
                        m.mass
                            .focal_sets()
                            .iter()
                            .filter(|f| !f.contains(a))
                            .count() as u32
                    })
                    .collect(),
                Constructor::Bayesian => Vec::new(),
            };
            usable.push(Some(Usable {
                scale: max,
                level,
                contour,
                mass: m.mass,
            }));
        }
        Ok((usable, issues))
    }

    /// Pairwise levels of conflict of a frame's features (`None` when either feature is unusable;
    /// the diagonal is 0 for usable features).
    ///
    /// # Errors
    /// [`TrackError::FeatureInputCount`].
    pub fn pairwise_conflicts(
        &self,
        likelihoods: &[Option<Vec<f64>>],
    ) -> Result<Vec<Vec<Option<f64>>>, TrackError> {
        let (usable, _) = self.measure(likelihoods)?;
        let f = usable.len();
        let mut k = vec![vec![None; f]; f];
        for i in 0..f {
            let Some(a) = &usable[i] else { continue };
            k[i][i] = Some(0.0);
            for j in i + 1..f {
                let Some(b) = &usable[j] else { continue };
                let level = self.pair_level(i, j, a, b);
                k[i][j] = Some(level);
                k[j][i] = Some(level);
            }
        }
        Ok(k)
    }

    /// Level of conflict of the combination of every usable feature (a frame's detection score):
    /// +∞ on total conflict, 0 with fewer than two usable features.
    ///
    /// # Errors
    /// [`TrackError::FeatureInputCount`].
    pub fn full_conflict_level(&self, likelihoods: &[Option<Vec<f64>>]) -> Result<f64, TrackError> {
        let (usable, _) = self.measure(likelihoods)?;
        let all = usable
            .iter()
            .enumerate()
            .filter(|(_, u)| u.is_some())
            .fold(0, |m: GroupMask, (i, _)| m | 1 << i);
        Ok(self.level(all, &usable, &mut HashMap::new(), f64::INFINITY))
    }

    /// Track one frame: one entry per feature, `Some(likelihoods over its states)` or `None` when
    /// the feature is missing. Bad likelihoods never fail: the feature is left out and flagged.
    ///
    /// # Errors
    /// [`TrackError::FeatureInputCount`] when the number of entries is not the number of features.
    pub fn track(&self, likelihoods: &[Option<Vec<f64>>]) -> Result<FrameEstimate, TrackError> {
        let (usable, issues) = self.measure(likelihoods)?;
        let f = usable.len();
        let mut flags = FrameFlags {
            unusable: issues,
            ..FrameFlags::default()
        };
        let usable_mask = (0..f)
            .filter(|&i| usable[i].is_some())
            .fold(0, |m: GroupMask, i| m | 1 << i);
        if usable_mask == 0 {
            flags.no_usable_feature = true;
            return Ok(FrameEstimate::without_estimate(flags));
        }
        let Selection {
            chosen,
            alternatives,
            fallback,
        } = self.select(&usable, usable_mask);
        flags.fallback = fallback;
        let Some((level, group)) = chosen else {
            flags.no_usable_feature = true;
            return Ok(FrameEstimate::without_estimate(flags));
        };
        let mut alts = Vec::with_capacity(alternatives.len());
        let mut alt_plausibility = Vec::with_capacity(alternatives.len());
        for &(k, g) in &alternatives {
            if let Some((estimate, pl, uncertainty)) = self.estimate_group(g, &usable) {
                alts.push(Alternative {
                    group: lex(g),
                    conflict_level: k,
                    estimate,
                    uncertainty,
                    reliability: None,
                });
                alt_plausibility.push((g, pl));
            }
        }
        let full_level = if group == usable_mask && !fallback {
            level
        } else {
            self.level(usable_mask, &usable, &mut HashMap::new(), f64::INFINITY)
        };
        let (result, group, level) = match self.weigh_alternatives(&alt_plausibility) {
            Some(Weighed {
                reliability,
                estimate,
                plausibility: pl,
                uncertainty,
            }) => {
                let most = (0..alts.len())
                    .max_by(|&a, &b| reliability[a].total_cmp(&reliability[b]).then(b.cmp(&a)))
                    .unwrap_or(0);
                let level = alts[most].conflict_level;
                for (a, r) in alts.iter_mut().zip(reliability) {
                    a.reliability = Some(r);
                }
                let union = alt_plausibility
                    .iter()
                    .fold(0, |m: GroupMask, (g, _)| m | g);
                (Some((estimate, pl, uncertainty)), union, level)
            }
            // The chosen group is the first alternative when there are any: estimated already.
            None => match (alts.first(), alt_plausibility.first()) {
                (Some(a), Some((g, pl))) if *g == group => {
                    (Some((a.estimate, pl.clone(), a.uncertainty)), group, level)
                }
                _ => (self.estimate_group(group, &usable), group, level),
            },
        };
        flags.excluded = lex(usable_mask & !group);
        flags.combination_failed = result.is_none();
        Ok(FrameEstimate {
            estimate: result.as_ref().map(|r| r.0),
            group: lex(group),
            conflict_level: Some(level),
            full_conflict_level: Some(full_level),
            uncertainty: result.as_ref().map(|r| r.2),
            plausibility: result.map(|r| r.1).unwrap_or_default(),
            alternatives: alts,
            flags,
        })
    }
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;
    use crate::track::{PoseRule, SelectionPolicy, TrackedFeature};

    pub(in crate::track) fn tiny_tracker(constructor: crate::evidence::Constructor) -> Tracker {
        // 6 poses on a line; three features with different partitions.
        let poses: Vec<[f64; 2]> = (0..6).map(|i| [i as f64, 0.0]).collect();
        let feats = [
            vec![0, 0, 0, 1, 1, 1],
            vec![0, 0, 1, 1, 2, 2],
            vec![0, 1, 1, 0, 0, 1],
        ];
        let features = feats
            .iter()
            .map(|a| TrackedFeature {
                refining: Refining::from_assignment(a.iter().max().unwrap() + 1, a).unwrap(),
                validation_error: None,
            })
            .collect();
        let model = TrackerModel::new(poses, features).unwrap();
        let settings = TrackSettings {
            constructor,
            ..TrackSettings::default()
        };
        Tracker::new(model, settings.check().unwrap()).unwrap()
    }

    #[test]
    fn a_kept_mass_of_e_minus_712_still_gives_every_estimator_its_estimate() {
        // Only poses 4 and 5 survive, with combined weight e^-712 (subnormal): every
        // estimator must still read them, and the level must be the exact 712.
        let tiny = (-712.0f64).exp();
        let lik = vec![
            Some(vec![1.0, tiny]),
            Some(vec![0.0, 0.0, 1.0]),
            Some(vec![1.0, 1.0]),
        ];
        for constructor in [
            crate::evidence::Constructor::Bayesian,
            crate::evidence::Constructor::Consonant,
        ] {
            for (estimator, expected) in [
                (PoseRule::WeightedMean, 4.5),
                (PoseRule::Pignistic, 4.5),
                (PoseRule::Map, 4.0),
            ] {
                let settings = TrackSettings {
                    constructor,
                    estimator,
                    ..TrackSettings::default()
                };
                let model = tiny_tracker(constructor).model().clone();
                let t = Tracker::new(model, settings.check().unwrap()).unwrap();
                let est = t.track(&lik).unwrap();
                let what = format!("{constructor:?} {estimator:?}: {est:?}");
                assert!(!est.flags.combination_failed, "{what}");
                assert_eq!(est.estimate, Some([expected, 0.0]), "{what}");
                assert_eq!(est.group, vec![0, 1, 2], "{what}");
                assert!((est.conflict_level.unwrap() - 712.0).abs() < 1e-9, "{what}");
            }
        }
    }

    use proptest::prelude::*;

    fn arb_entry(n: usize) -> impl Strategy<Value = Option<Vec<f64>>> {
        let value = prop_oneof![
            4 => 0.0f64..2.0,
            1 => Just(0.0),
            1 => Just(f64::NAN),
            1 => Just(f64::INFINITY),
            1 => Just(-1.0),
        ];
        prop_oneof![
            6 => proptest::collection::vec(value.clone(), n..=n).prop_map(Some),
            1 => Just(None),
            1 => proptest::collection::vec(value, 0..5).prop_map(Some),
        ]
    }

    proptest! {
        #[test]
        fn any_input_gives_a_consistent_estimate_or_flags(
            lik in (arb_entry(2), arb_entry(3), arb_entry(2)).prop_map(|(a, b, c)| vec![a, b, c]),
            consonant in any::<bool>(),
            threshold in prop_oneof![Just(f64::INFINITY), 0.0f64..3.0],
            policy in 0usize..3,
        ) {
            let constructor = if consonant { crate::evidence::Constructor::Consonant } else { crate::evidence::Constructor::Bayesian };
            let selection = match policy {
                0 => SelectionPolicy::LargestSubset,
                1 => SelectionPolicy::LowestConflict { min_size: 2 },
                _ => SelectionPolicy::Splitting { min_size: 2 },
            };
            let base = tiny_tracker(constructor);
            let settings = TrackSettings { constructor, conflict_threshold: crate::evidence::ConflictLevel::from_value(threshold), selection, ..TrackSettings::default() };
            let t = Tracker::new(base.model().clone(), settings.check().unwrap()).unwrap();
            let est = t.track(&lik).unwrap();
            let usable = lik.iter().enumerate().filter(|(i, _)| !est.flags.unusable.iter().any(|(f, _)| f == i)).count();
            match est.estimate {
                None => {
                    prop_assert!(est.flags.no_usable_feature);
                    prop_assert_eq!(usable, 0);
                }
                Some(e) => {
                    prop_assert!(usable > 0);
                    prop_assert!(e[0] >= 0.0 && e[0] <= 5.0 && e[1] == 0.0, "{:?}", e);
                    let k = est.conflict_level.unwrap();
                    prop_assert!(k.is_finite() && k >= 0.0);
                    let sum: f64 = est.plausibility.iter().sum();
                    prop_assert!((sum - 1.0).abs() < 1e-12);
                    prop_assert!(!est.group.is_empty());
                    prop_assert_eq!(est.group.len() + est.flags.excluded.len(), usable);
                    let u = est.uncertainty.unwrap();
                    prop_assert!(u.radius >= 0.0 && u.radius <= 5.0 && u.spread <= 5.0);
                }
            }
        }
    }
}
