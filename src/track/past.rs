//! Tracking with the past (issue 17): the belief carried from the last frames takes part in a
//! frame's conflict graph as one more node, after the features (bit `features` of a mask).
//!
//! The carried belief `C` is consonant, given by its contour `c` on the sample poses. Its level
//! of conflict with a group A of features is exact and additive: 1 − K(A ∪ {C}) =
//! (1 − K(A))·(1 − K(m_A, C)) for the normalised combination m_A of A, so
//! level(A ∪ {C}) = level(A) + level(m_A, C); and a consonant C has Pl_C(F) = max of c over F, so
//! 1 − K(m_A, C) = Σ_F m_A(F)·max_F c, with m_A combined on the cells (c enters through its
//! maximum on each cell). Adding C to a group can only raise its level, so the pruned search
//! stays exact.

use std::collections::HashMap;

use super::cell_levels::CellLevels;
use super::group_search::{members, select_group, GroupLevels, GroupMask};
use super::settings::{Combine, SelectionPolicy};
use super::tracker::{FrameEstimate, Tracker, Usable};
use super::TrackError;
use crate::evidence::dempster_all;
use crate::evidence::ConflictLevel;

/// What the past did in one frame.
#[derive(Clone, Debug, PartialEq)]
pub struct PastFrame {
    /// The frame's estimate; its `plausibility` is that of the chosen combination (with the
    /// carried belief when it joined).
    pub frame: FrameEstimate,
    /// Whether the carried belief was combined.
    pub past_joined: bool,
}

/// The selection's view of a frame's features plus the carried belief.
struct PastLevels<'a> {
    cells: CellLevels<'a>,
    /// The bit of the carried belief.
    past: usize,
    /// Max of the carried contour over each cell.
    cell_max: Vec<f64>,
    /// level(m_A, C) per feature group A.
    memo: HashMap<GroupMask, f64>,
}

impl PastLevels<'_> {
    /// level(m_A, C) of a non-empty feature group A: +∞ when A does not combine.
    fn past_level(&mut self, group: GroupMask) -> f64 {
        if let Some(&level) = self.memo.get(&group) {
            return level;
        }
        // Bayesian functions: sums over the state tuples (exact, as the combination's, up to
        // the order of the additions); otherwise Dempster's rule on the cells.
        let agree = self
            .cells
            .bayesian_agreement(group, &self.cell_max)
            .or_else(|| self.combined_agreement(group));
        let level = match agree {
            Some(agree) if agree > 0.0 => (-agree.ln()).max(0.0),
            _ => f64::INFINITY,
        };
        self.memo.insert(group, level);
        level
    }
}

impl PastLevels<'_> {
    /// Σ_F m(F)·max_F c for the combination m of `group` on the cells; `None` when the group
    /// does not combine.
    fn combined_agreement(&self, group: GroupMask) -> Option<f64> {
        let (tracker, usable) = (self.cells.tracker, self.cells.usable);
        let combined = tracker
            .on_cells(group, usable)
            .and_then(|fs| dempster_all(&fs).ok())
            .and_then(|c| c.mass)?;
        Some(
            combined
                .focal()
                .map(|(set, mass)| {
                    mass * set.iter().map(|u| self.cell_max[u]).fold(0.0f64, f64::max)
                })
                .sum(),
        )
    }
}

impl GroupLevels for PastLevels<'_> {
    fn pair_level(&mut self, i: usize, j: usize) -> f64 {
        if j == self.past {
            self.past_level(1 << i)
        } else {
            self.cells.pair_level(i, j)
        }
    }

    fn group_level(&mut self, group: GroupMask) -> f64 {
        if group >> self.past & 1 == 0 {
            return self.cells.group_level(group);
        }
        let features = group & !(1 << self.past);
        let own = if features.count_ones() >= 2 {
            self.cells.group_level(features)
        } else {
            0.0
        };
        if own.is_finite() {
            own + self.past_level(features)
        } else {
            f64::INFINITY
        }
    }

    fn fallback_feature(&self) -> Option<usize> {
        self.cells.fallback_feature()
    }
}

/// Groups that hold the carried belief (bit `past`), seen as groups of the features beside it.
struct BesidePast<'l, L> {
    levels: &'l mut L,
    past: GroupMask,
}

impl<L: GroupLevels> GroupLevels for BesidePast<'_, L> {
    fn pair_level(&mut self, i: usize, j: usize) -> f64 {
        self.levels.group_level(1 << i | 1 << j | self.past)
    }

    fn group_level(&mut self, group: GroupMask) -> f64 {
        self.levels.group_level(group | self.past)
    }

    fn levels_grow_exactly(&self) -> bool {
        self.levels.levels_grow_exactly()
    }

    fn narrow_candidates(&self) -> bool {
        self.levels.narrow_candidates()
    }

    /// Never asked: every node was admitted beside the past, so each alone is eligible.
    fn fallback_feature(&self) -> Option<usize> {
        None
    }
}

/// The past's side of a frame with the carried belief as bit `past` of `levels`' masks (the
/// features are the bits below): the largest group of `usable` features that combines with it
/// within `threshold` under `policy` (when no pair does, the single feature closest to it), and
/// that group's level with the past; `(0, 0)` when no feature combines with the past.
pub fn group_beside_past(
    levels: &mut impl GroupLevels,
    usable: GroupMask,
    past: usize,
    policy: SelectionPolicy,
    threshold: ConflictLevel,
) -> (GroupMask, f64) {
    let past_bit: GroupMask = 1 << past;
    let beside = members(usable)
        .filter(|&i| threshold.admits(levels.group_level(1 << i | past_bit)))
        .fold(0, |m: GroupMask, i| m | 1 << i);
    let features = match beside.count_ones() {
        0 => return (0, 0.0),
        1 => beside,
        _ => {
            let mut view = BesidePast {
                levels: &mut *levels,
                past: past_bit,
            };
            let choice = select_group(&mut view, past, beside, policy, threshold);
            match choice.chosen {
                Some((level, group)) if !choice.fallback => return (group, level),
                _ => members(beside)
                    .min_by(|&a, &b| {
                        let (ka, kb) = (
                            levels.group_level(1 << a | past_bit),
                            levels.group_level(1 << b | past_bit),
                        );
                        ka.total_cmp(&kb).then(a.cmp(&b))
                    })
                    .map_or(0, |i| 1 << i),
            }
        }
    };
    (features, levels.group_level(features | past_bit))
}

/// Whether the past, worth `past_weight` features, and the `beside` features combined with it
/// outweigh the frame's own choice (its group and whether it was the fallback, which counts as
/// one feature).
pub fn past_outweighs(
    frame: Option<(GroupMask, bool)>,
    beside: GroupMask,
    past_weight: f64,
) -> bool {
    let worth = match frame {
        Some((group, false)) => group.count_ones() as f64,
        Some((_, true)) => 1.0,
        None => 0.0,
    };
    beside.count_ones() as f64 + past_weight > worth
}

impl Tracker {
    /// Tracks one frame with `carried`, the contour of the belief carried from the past over
    /// the sample poses (positive, max at most 1), as one more node of the conflict graph that
    /// counts as `past_weight` features.
    ///
    /// Two candidates compete: the frame's own choice (the per-frame selection, worth its number
    /// of features) and the past with the largest group of features it can be combined with
    /// within the threshold (worth that number plus `past_weight`); the past joins when it is
    /// worth more. With weight 1 the carried belief counts exactly as a feature; with half the
    /// features, a frame whose best coherent group holds fewer than half of them is outweighed
    /// by the past, and a frame whose features agree beyond that drops a past that contradicts
    /// them. The chosen group's features are reported in `group` (the carried belief never is);
    /// when the past wins alone, every usable feature is excluded and the estimate is the carried
    /// belief's. Without usable features there is no estimate (the caller predicts).
    ///
    /// # Errors
    /// [`TrackError::FeatureInputCount`]; [`TrackError::InvalidSetting`] for the splitting
    /// policy (its alternatives are not weighed against the past) or a carried contour of the
    /// wrong length.
    pub fn track_with_past(
        &self,
        likelihoods: &[Option<Vec<f64>>],
        carried: &[f64],
        past_weight: f64,
    ) -> Result<PastFrame, TrackError> {
        if let SelectionPolicy::Splitting { .. } = self.settings.selection {
            return Err(TrackError::InvalidSetting {
                field: "selection",
                reason: "tracking with the past takes `largest_subset` or `lowest_conflict`, not \
                         `splitting`"
                    .into(),
            });
        }
        let poses = self.model.poses().len();
        if carried.len() != poses {
            return Err(TrackError::InvalidSetting {
                field: "carried",
                reason: format!(
                    "{} values for {poses} sample poses: carry one value per sample pose",
                    carried.len()
                ),
            });
        }
        let alone = self.track(likelihoods)?;
        let frame_alone = PastFrame {
            frame: alone.clone(),
            past_joined: false,
        };
        if alone.flags.no_usable_feature {
            return Ok(frame_alone);
        }
        let (usable, _) = self.measure(likelihoods)?;
        let f = usable.len();
        let usable_mask = (0..f)
            .filter(|&i| usable[i].is_some())
            .fold(0, |m: GroupMask, i| m | 1 << i);
        let mut cell_max = vec![0.0f64; self.cell_count()];
        for (&u, &c) in self.cell_of.iter().zip(carried) {
            cell_max[u] = cell_max[u].max(c);
        }
        let mut levels = PastLevels {
            cells: self.cell_levels(&usable),
            past: f,
            cell_max,
            memo: HashMap::new(),
        };
        let (features, level) = if self.settings.combine == Combine::All {
            // Every usable feature and the past, whatever their conflict.
            (usable_mask, levels.group_level(usable_mask | 1 << f))
        } else {
            let (features, level) = group_beside_past(
                &mut levels,
                usable_mask,
                f,
                self.settings.selection,
                self.settings.conflict_threshold,
            );
            let own = alone.group.iter().fold(0, |m: GroupMask, &i| m | 1 << i);
            if !past_outweighs(Some((own, alone.flags.fallback)), features, past_weight) {
                return Ok(frame_alone);
            }
            (features, level)
        };
        let Some((estimate, plausibility, uncertainty)) =
            self.estimate_with_past(features, &usable, carried)
        else {
            return Ok(frame_alone);
        };
        let mut flags = alone.flags;
        flags.fallback = false;
        flags.excluded = members(usable_mask & !features).collect();
        Ok(PastFrame {
            frame: FrameEstimate {
                estimate: Some(estimate),
                group: members(features).collect(),
                conflict_level: Some(level),
                full_conflict_level: alone.full_conflict_level,
                uncertainty: Some(uncertainty),
                plausibility,
                alternatives: Vec::new(),
                flags,
            },
            past_joined: true,
        })
    }

    /// The estimate of `features` (possibly none) combined with the carried belief: its
    /// relative plausibility is the normalised product of the contours. The pignistic
    /// estimator reads it as well (the combination with the past is not built on the cells).
    fn estimate_with_past(
        &self,
        features: GroupMask,
        usable: &[Option<Usable>],
        carried: &[f64],
    ) -> Option<([f64; 2], Vec<f64>, super::Uncertainty)> {
        let mut weights = if features == 0 {
            carried.to_vec()
        } else {
            let mut pl = self.fused_plausibility(features, usable)?;
            let max = pl.iter().copied().fold(0.0f64, f64::max);
            for (p, &c) in pl.iter_mut().zip(carried) {
                *p = *p / max * c;
            }
            pl
        };
        let total: f64 = weights.iter().sum();
        if !(total > 0.0 && total.is_finite()) {
            return None;
        }
        weights.iter_mut().for_each(|w| *w /= total);
        let (estimate, uncertainty) = self.estimate_with_weights(&weights)?;
        Some((estimate, weights, uncertainty))
    }

    /// The estimate and uncertainty of weights over the sample poses, as the tracker's
    /// estimator reads them (the pignistic estimator as the weighted mean).
    pub fn estimate_with_weights(&self, weights: &[f64]) -> Option<([f64; 2], super::Uncertainty)> {
        (weights.len() == self.model.poses().len()).then_some(())?;
        self.estimate_from(weights)
    }
}

#[cfg(test)]
mod tests {
    use crate::evidence::Constructor;
    use crate::track::tracking::tests::tiny_tracker;

    fn frame() -> Vec<Option<Vec<f64>>> {
        vec![
            Some(vec![0.3, 0.7]),
            Some(vec![0.2, 0.5, 0.3]),
            Some(vec![0.6, 0.4]),
        ]
    }

    #[test]
    fn a_vacuous_past_joins_and_changes_nothing() {
        for constructor in [Constructor::Bayesian, Constructor::Consonant] {
            let tracker = tiny_tracker(constructor);
            let alone = tracker.track(&frame()).unwrap();
            let with = tracker.track_with_past(&frame(), &[1.0; 6], 1.0).unwrap();
            assert!(with.past_joined, "{constructor:?}");
            assert_eq!(with.frame.group, alone.group);
            assert!(
                (with.frame.conflict_level.unwrap() - alone.conflict_level.unwrap()).abs() < 1e-12
            );
            let (a, b) = (alone.estimate.unwrap(), with.frame.estimate.unwrap());
            assert!(
                (a[0] - b[0]).abs() < 1e-12 && (a[1] - b[1]).abs() < 1e-12,
                "{a:?} {b:?}"
            );
        }
    }

    #[test]
    fn the_past_level_is_the_conflict_of_the_combination_with_the_past() {
        // The carried belief here is Bayesian-free and consonant: contour 1 on poses 4, 5 and
        // 0.25 elsewhere, i.e. mass 0.75 on {4, 5} and 0.25 on Θ. Adding it multiplies the
        // agreeing mass by Σ_F m(F) max_F c, checked against Dempster's rule on the poses.
        let tracker = tiny_tracker(Constructor::Bayesian);
        let carried = [0.25, 0.25, 0.25, 0.25, 1.0, 1.0];
        let with = tracker.track_with_past(&frame(), &carried, 1.0).unwrap();
        assert!(with.past_joined);
        let alone = tracker.track(&frame()).unwrap();
        // Relative plausibility of the frame's combination per pose, times the carried contour.
        let pl = &alone.plausibility;
        let agree: f64 =
            pl.iter().zip(&carried).map(|(p, c)| p * c).sum::<f64>() / pl.iter().sum::<f64>();
        // Every pose is its own cell here only if the features separate them: poses 4 and 5
        // differ in feature 2, and so on; so max over a cell is the pose's own value.
        let expected = alone.conflict_level.unwrap() - agree.ln();
        assert!(
            (with.frame.conflict_level.unwrap() - expected).abs() < 1e-12,
            "{:?} vs {expected}",
            with.frame.conflict_level
        );
        let total: f64 = pl.iter().zip(&carried).map(|(p, c)| p * c).sum();
        for (k, w) in with.frame.plausibility.iter().enumerate() {
            assert!((w - pl[k] * carried[k] / total).abs() < 1e-12);
        }
    }

    #[test]
    fn the_tuple_sums_give_the_combinations_agreement_with_the_past() {
        use super::PastLevels;
        use rand::{Rng, SeedableRng};
        let tracker = tiny_tracker(Constructor::Bayesian);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        for round in 0..50 {
            // Some states impossible now and then, a past from sharp to vacuous.
            let mut draw = |n: usize| -> Option<Vec<f64>> {
                Some((0..n).map(|_| rng.random::<f64>().powi(3)).collect())
            };
            let lik = vec![draw(2), draw(3), draw(2)];
            let carried: Vec<f64> = (0..6).map(|_| rng.random::<f64>().powi(2)).collect();
            let (usable, _) = tracker.measure(&lik).unwrap();
            let mut cell_max = vec![0.0f64; tracker.cell_count()];
            for (&u, &c) in tracker.cell_of.iter().zip(&carried) {
                cell_max[u] = cell_max[u].max(c);
            }
            let mut levels = PastLevels {
                cells: tracker.cell_levels(&usable),
                past: 3,
                cell_max: cell_max.clone(),
                memo: std::collections::HashMap::new(),
            };
            for group in 1..8u64 {
                let fast = levels.cells.bayesian_agreement(group, &cell_max).unwrap();
                let combined = levels.combined_agreement(group).unwrap_or(0.0);
                assert!(
                    (fast - combined).abs() <= 1e-14 * combined.max(1e-300),
                    "round {round}, group {group}: {fast} vs {combined}"
                );
            }
        }
        // Consonant functions take the combination.
        let tracker = tiny_tracker(Constructor::Consonant);
        let (usable, _) = tracker.measure(&frame()).unwrap();
        let mut cells = tracker.cell_levels(&usable);
        assert_eq!(
            cells.bayesian_agreement(0b11, &vec![1.0; tracker.cell_count()]),
            None
        );
    }

    #[test]
    fn a_past_in_total_conflict_is_dropped_and_the_frame_is_followed() {
        let mut tracker = tiny_tracker(Constructor::Bayesian);
        tracker.settings.conflict_threshold = crate::evidence::ConflictLevel::Finite(5.0);
        // Only pose 0 is plausible for the frame; the past says poses 4 and 5, nothing else.
        let lik = vec![
            Some(vec![1.0, 0.0]),
            Some(vec![1.0, 0.0, 0.0]),
            Some(vec![1.0, 0.0]),
        ];
        let with = tracker
            .track_with_past(&lik, &[0.0, 0.0, 0.0, 0.0, 1.0, 1.0], 1.0)
            .unwrap();
        assert!(!with.past_joined);
        assert_eq!(with.frame.group, vec![0, 1, 2]);
        assert_eq!(with.frame.estimate, tracker.track(&lik).unwrap().estimate);
        // The wrong length and the splitting policy are refused with a message.
        let short = tracker.track_with_past(&lik, &[1.0; 3], 1.0).unwrap_err();
        assert!(
            short.to_string().contains("one value per sample pose"),
            "{short}"
        );
    }
}
