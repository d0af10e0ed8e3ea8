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
use super::group_search::{members, present_mask, select_group, GroupLevels, GroupMask};
use super::settings::{Combine, SelectionPolicy};
use super::tracker::{FrameEstimate, Tracker, Usable};
use super::TrackError;
use crate::evidence::dempster_all;
use crate::evidence::{ConflictLevel, Constructor};

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
    /// The cells of the largest `cell_max`, where [`PastLevels::proven_within`] looks for a
    /// witness of agreement with the past.
    peaks: [usize; PEAKS],
    /// Σ_s contour(s) of every usable feature (0 for the others), for
    /// [`PastLevels::proven_within`].
    contour_sums: Vec<f64>,
    /// Whether the carried belief is at most 1 on every cell (where [`PastLevels::proof_bound`]
    /// needs no group level).
    past_at_most_one: bool,
}

/// How many of the carried belief's highest cells witness a group's agreement with it.
const PEAKS: usize = 4;

/// The [`PEAKS`] cells of the largest values (ties: the first), padded with the last found.
fn peak_cells(cell_max: &[f64]) -> [usize; PEAKS] {
    let mut peaks = [0usize; PEAKS];
    let mut count = 0;
    for (k, &c) in cell_max.iter().enumerate() {
        // Insertion into the short sorted list, largest first.
        let mut at = count.min(PEAKS);
        while at > 0 && cell_max[peaks[at - 1]] < c {
            at -= 1;
        }
        if at < PEAKS {
            let end = (count + 1).min(PEAKS);
            peaks.copy_within(at..end - 1, at + 1);
            peaks[at] = k;
            count = end;
        }
    }
    if count > 0 {
        let last = peaks[count - 1];
        peaks[count..].fill(last);
    }
    peaks
}

impl<'a> PastLevels<'a> {
    /// The levels of a frame's `usable` features with the past as bit `past`, whose contour has
    /// maximum `cell_max` on each cell.
    fn new(
        tracker: &'a Tracker,
        usable: &'a [Option<Usable>],
        past: usize,
        cell_max: Vec<f64>,
    ) -> Self {
        PastLevels {
            cells: tracker.cell_levels(usable),
            past,
            peaks: peak_cells(&cell_max),
            past_at_most_one: cell_max.iter().all(|&c| c <= 1.0),
            cell_max,
            memo: HashMap::new(),
            contour_sums: (usable.iter())
                .map(|u| u.as_ref().map_or(0.0, |u| u.contour.iter().sum::<f64>()))
                .collect(),
        }
    }
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
    /// Whether the level of a Bayesian `group` of one or two features with the past is proven
    /// within `threshold` without computing it (`false`: not proven either way): its
    /// [`PastLevels::proof_bound`], with a margin that covers the rounding of the tuple sums.
    /// The selection's graph asks this of every pair.
    fn proven_within(&mut self, group: GroupMask, threshold: ConflictLevel) -> bool {
        self.proof_bound(group)
            .is_some_and(|bound| threshold.admits(bound + 1e-9 * (1.0 + bound)))
    }

    /// An upper bound of the level of a Bayesian `group` of one or two features with the past,
    /// from the carried belief's highest cells, without the group's own level (`None` when
    /// there is none to give). Over the group's state tuples t, with p(t) the product of the
    /// members' scaled contours, P = Σ_t p(t), A = Σ_t p(t)·max_t c and λ the sum of the
    /// members' ln(scale), the level is max(0, −ln P − λ) + max(0, ln P − ln A) (one feature:
    /// the second term alone). A single cell k of tuple t witnesses A ≥ W = c(k)·p(t), and
    /// P ≤ S = Π_i Σ_s contour_i(s) (every tuple's product is one term of it), so the second
    /// term is at most max(0, ln S − ln W). With c ≤ 1, A ≤ P, and when the first term is
    /// positive the level is −ln A − λ ≤ −ln W − λ. Where the carried belief exceeds 1, the
    /// group's own level stands in for the first term. The sums stay far from underflow
    /// (W ≥ 1e-150), so the level computed is that of the tuple sums.
    fn proof_bound(&mut self, group: GroupMask) -> Option<f64> {
        let tracker = self.cells.tracker;
        if tracker.settings.constructor != Constructor::Bayesian || group.count_ones() > 2 {
            return None;
        }
        let mut witness = 0.0f64;
        let mut sums = 1.0;
        let mut log_scale = 0.0;
        for i in members(group) {
            let usable = self.cells.usable[i].as_ref()?;
            sums *= self.contour_sums[i];
            log_scale += usable.scale.ln();
        }
        for &k in &self.peaks {
            let mut p = *self.cell_max.get(k)?;
            for i in members(group) {
                let feature = self.cells.usable[i].as_ref().map(|u| &u.contour);
                let state = tracker.to_cells[i].assignment()[k];
                p *= feature.map_or(0.0, |c| c[state]);
            }
            witness = witness.max(p);
        }
        if !(witness >= 1e-150 && sums.is_finite()) {
            return None;
        }
        let beside = (sums / witness).ln().max(0.0);
        if group.count_ones() == 1 {
            return Some(beside);
        }
        let first = if self.past_at_most_one {
            -witness.ln() - log_scale
        } else {
            let own = self.cells.group_level(group);
            if !own.is_finite() {
                return None;
            }
            own + beside
        };
        Some(first.max(beside))
    }

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
        // The past's level first: a large group's agreement grows its tuples, whose sum then
        // gives its own level (bit-identical to the direct sum, which would walk the cells again).
        let past = self.past_level(features);
        let own = if features.count_ones() >= 2 {
            self.cells.group_level(features)
        } else {
            0.0
        };
        if own.is_finite() {
            own + past
        } else {
            f64::INFINITY
        }
    }

    fn fallback_feature(&self) -> Option<usize> {
        self.cells.fallback_feature()
    }
}

/// Groups that hold the carried belief (bit `past`), seen as groups of the features beside it.
struct BesidePast<'l, L, P> {
    levels: &'l mut L,
    past: GroupMask,
    /// Whether a group of features is proven within the threshold with the past, without its
    /// level.
    proven: P,
}

impl<L: GroupLevels, P: FnMut(&mut L, GroupMask) -> bool> GroupLevels for BesidePast<'_, L, P> {
    /// A pair proven within the threshold reports 0, a lower bound of its level: the conflict
    /// graph only asks whether a pair is admitted.
    fn pair_level(&mut self, i: usize, j: usize) -> f64 {
        if (self.proven)(self.levels, 1 << i | 1 << j) {
            return 0.0;
        }
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
    group_beside_past_with(levels, usable, past, policy, threshold, |_, _| false)
}

/// [`group_beside_past`], with `proven` telling which groups of one or two features are within
/// the threshold with the past without their level (it must never say so of one that is not;
/// the evidential tracker's peak cells, the continuous tracker's own choice, issue 32).
pub fn group_beside_past_with<L: GroupLevels>(
    levels: &mut L,
    usable: GroupMask,
    past: usize,
    policy: SelectionPolicy,
    threshold: ConflictLevel,
    mut proven: impl FnMut(&mut L, GroupMask) -> bool,
) -> (GroupMask, f64) {
    let past_bit: GroupMask = 1 << past;
    let beside = members(usable)
        .filter(|&i| {
            proven(levels, 1 << i) || threshold.admits(levels.group_level(1 << i | past_bit))
        })
        .fold(0, |m: GroupMask, i| m | 1 << i);
    let features = match beside.count_ones() {
        0 => return (0, 0.0),
        1 => beside,
        _ => {
            let mut view = BesidePast {
                levels: &mut *levels,
                past: past_bit,
                proven,
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
    /// A `doubtful` past (carried from a frame whose features disagreed beyond the threshold)
    /// joins a frame whose usable features all agree only beside every one of them: such a past
    /// may not outweigh a feature of a coherent frame.
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
        doubtful: bool,
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
        let (usable, issues) = self.measure(likelihoods)?;
        let alone = self.track_measured(&usable, issues);
        let frame_alone = PastFrame {
            frame: alone.clone(),
            past_joined: false,
        };
        if alone.flags.no_usable_feature {
            return Ok(frame_alone);
        }
        let f = usable.len();
        let usable_mask = present_mask(&usable);
        let mut cell_max = vec![0.0f64; self.cell_count()];
        for (&u, &c) in self.cell_of.iter().zip(carried) {
            cell_max[u] = cell_max[u].max(c);
        }
        let mut levels = PastLevels::new(self, &usable, f, cell_max);
        let (features, level) = if self.settings.combine == Combine::All {
            // Every usable feature and the past, whatever their conflict.
            (usable_mask, levels.group_level(usable_mask | 1 << f))
        } else {
            let threshold = self.settings.conflict_threshold;
            let (features, level) = group_beside_past_with(
                &mut levels,
                usable_mask,
                f,
                self.settings.selection,
                threshold,
                |levels, group| levels.proven_within(group, threshold),
            );
            let own = alone.group.iter().fold(0, |m: GroupMask, &i| m | 1 << i);
            let coherent = own == usable_mask
                && !alone.flags.fallback
                && (alone.full_conflict_level).is_some_and(|level| threshold.admits(level));
            if doubtful && coherent && features != usable_mask {
                return Ok(frame_alone);
            }
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
                alternatives_found: 0,
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
#[path = "past_tests.rs"]
mod tests;
