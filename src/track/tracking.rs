//! The tracker's public per-frame entry points ([`Tracker::track`],
//! [`Tracker::pairwise_conflicts`], [`Tracker::full_conflict_level`]): measure the frame, select
//! a group through the generic search on the cells' levels, combine and estimate. The steps live
//! below this file (`tracker` the data and measurement, `conflict`, `cell_levels`, `estimate`),
//! and none of them calls back up.

use std::collections::HashMap;

use super::estimate::Weighed;
use super::group_search::{lex, present_mask, GroupMask, Selection};
use super::settings::Combine;
use super::tracker::{Alternative, FeatureIssue, FrameEstimate, FrameFlags, Tracker, Usable};
use super::TrackError;

impl Tracker {
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
        Ok(self.track_measured(&usable, issues))
    }

    /// [`Tracker::track`] of a frame already measured (the tracker with the past measures once
    /// for both of its candidates).
    pub(super) fn track_measured(
        &self,
        usable: &[Option<Usable>],
        issues: Vec<(usize, FeatureIssue)>,
    ) -> FrameEstimate {
        let mut flags = FrameFlags {
            unusable: issues,
            ..FrameFlags::default()
        };
        let usable_mask = present_mask(usable);
        if usable_mask == 0 {
            flags.no_usable_feature = true;
            return FrameEstimate::without_estimate(flags);
        }
        let (
            Selection {
                chosen,
                mut alternatives,
                fallback,
            },
            alternatives_found,
        ) = if self.settings.combine == Combine::All {
            let level = self.level(usable_mask, usable, &mut HashMap::new(), f64::INFINITY);
            let selection = Selection {
                chosen: Some((level, usable_mask)),
                alternatives: Vec::new(),
                fallback: false,
            };
            (selection, 0)
        } else {
            self.select(usable, usable_mask)
        };
        flags.fallback = fallback;
        let Some((mut level, mut group)) = chosen else {
            flags.no_usable_feature = true;
            return FrameEstimate::without_estimate(flags);
        };
        // Only the alternatives the cap keeps are estimated and weighed (without group errors
        // only those were listed); the frame says how many there were. The chosen group is the
        // first kept, as uncapped.
        flags.alternatives_capped = alternatives_found > self.settings.max_alternatives;
        if flags.alternatives_capped {
            self.cap_alternatives(&mut alternatives);
            (level, group) = alternatives[0];
        }
        let mut alts = Vec::with_capacity(alternatives.len());
        let mut alt_plausibility = Vec::with_capacity(alternatives.len());
        for &(k, g) in &alternatives {
            if let Some((estimate, pl, uncertainty)) = self.estimate_group(g, usable) {
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
            self.level(usable_mask, usable, &mut HashMap::new(), f64::INFINITY)
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
                _ => (self.estimate_group(group, usable), group, level),
            },
        };
        flags.excluded = lex(usable_mask & !group);
        flags.combination_failed = result.is_none();
        FrameEstimate {
            estimate: result.as_ref().map(|r| r.0),
            group: lex(group),
            conflict_level: Some(level),
            full_conflict_level: Some(full_level),
            uncertainty: result.as_ref().map(|r| r.2),
            plausibility: result.map(|r| r.1).unwrap_or_default(),
            alternatives: alts,
            alternatives_found,
            flags,
        }
    }

    /// Keeps `max_alternatives` of the splitting policy's `alternatives` (more than that): the
    /// most reliable (lowest validation error of the group, ties in the policy's order) when the
    /// model knows every group's error, since weighing trusts those most; otherwise the first.
    /// The kept ones stay in the policy's order.
    fn cap_alternatives(&self, alternatives: &mut Vec<(f64, GroupMask)>) {
        let cap = self.settings.max_alternatives;
        let errors: Option<Vec<f64>> = alternatives
            .iter()
            .map(|&(_, g)| self.model.group_error(g))
            .collect();
        let Some(errors) = errors else {
            alternatives.truncate(cap);
            return;
        };
        let mut by_error: Vec<usize> = (0..alternatives.len()).collect();
        by_error.sort_by(|&a, &b| errors[a].total_cmp(&errors[b]).then(a.cmp(&b)));
        let mut kept = vec![false; alternatives.len()];
        for &i in &by_error[..cap] {
            kept[i] = true;
        }
        let mut index = 0;
        alternatives.retain(|_| {
            index += 1;
            kept[index - 1]
        });
    }
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;
    use crate::evidence::Refining;
    use crate::track::{PoseRule, SelectionPolicy, TrackSettings, TrackedFeature, TrackerModel};

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
