//! The paper's tracker seen by the generic group search: its cells' pairwise and group levels,
//! and the fallback feature.

use super::group_search::{
    members, select_group, select_group_keeping, GroupLevels, GroupMask, LevelBounds, Selection,
};
use super::tracker::{Tracker, Usable};
use super::tuples::TupleStack;
use crate::evidence::Constructor;

/// The paper's tracker seen by the selection: its cells, pairwise and group levels.
pub(super) struct CellLevels<'a> {
    pub(super) tracker: &'a Tracker,
    pub(super) usable: &'a [Option<Usable>],
    /// Bayesian levels grown along the search's walk.
    tuples: TupleStack,
}

impl Drop for CellLevels<'_> {
    fn drop(&mut self) {
        std::mem::take(&mut self.tuples).recycle();
    }
}

impl GroupLevels for CellLevels<'_> {
    fn pair_level(&mut self, i: usize, j: usize) -> f64 {
        match (&self.usable[i], &self.usable[j]) {
            (Some(a), Some(b)) => self.tracker.pair_level(i, j, a, b),
            _ => f64::INFINITY,
        }
    }

    fn group_level(&mut self, group: GroupMask) -> f64 {
        match self.tracker.settings.constructor {
            Constructor::Bayesian if group.count_ones() == 2 => self
                .pair_level_bayesian(group)
                .unwrap_or_else(|| self.tracker.general_level(group, self.usable)),
            Constructor::Bayesian => self
                .tuples
                .level(self.tracker, self.usable, group)
                .unwrap_or_else(|| self.tracker.general_level(group, self.usable)),
            Constructor::Consonant => self.tracker.raw_level(group, self.usable),
        }
    }

    fn fallback_feature(&self) -> Option<usize> {
        self.tracker.fallback_feature(self.usable)
    }

    fn cheap_pairs(&self) -> bool {
        self.tracker.settings.constructor == Constructor::Bayesian
    }

    fn look_ahead_first(&mut self) -> bool {
        self.tracker.settings.constructor == Constructor::Bayesian
            && (self.tracker.pair_tuples)
                .near_repeats(&self.tracker.to_cells)
                .is_some()
    }

    fn level_bounds(&mut self, group: GroupMask, walked: GroupMask) -> Option<LevelBounds> {
        match self.tracker.settings.constructor {
            Constructor::Bayesian => (self.tuples).bounds(self.tracker, self.usable, group, walked),
            Constructor::Consonant => None,
        }
    }

    fn group_levels(&mut self, groups: &[GroupMask]) -> Vec<f64> {
        let on_cells = match self.tracker.settings.constructor {
            Constructor::Bayesian => {
                (self.tuples).levels_on_cells(self.tracker, self.usable, groups)
            }
            Constructor::Consonant => vec![None; groups.len()],
        };
        // As `group_level` takes each: the general path where the sum underflows.
        (groups.iter().zip(on_cells))
            .map(|(&g, level)| match level {
                Some(Some(k)) => k,
                Some(None) => self.tracker.general_level(g, self.usable),
                None => self.group_level(g),
            })
            .collect()
    }

    fn floors_without_one(&mut self, group: GroupMask) -> Option<Vec<f64>> {
        match self.tracker.settings.constructor {
            Constructor::Bayesian => self.bayesian_floors(group),
            Constructor::Consonant => None,
        }
    }
}

impl CellLevels<'_> {
    /// Bayesian floors of `group` without each member: the level's sum over the state tuples
    /// taken over the cells instead (every tuple lies on a cell, with the same product, so the
    /// sum can only grow and the level only fall), each cell's product the members' before the
    /// one left out times those after it.
    fn bayesian_floors(&self, group: GroupMask) -> Option<Vec<f64>> {
        let cells = self.tracker.cell_count();
        let ms: Vec<(&[usize], &Usable)> = members(group)
            .map(|i| {
                Some((
                    self.tracker.to_cells[i].assignment(),
                    self.usable[i].as_ref()?,
                ))
            })
            .collect::<Option<_>>()?;
        let q = ms.len();
        // after[k * cells + u]: the product of members k.. on cell u.
        let mut after = vec![1.0; (q + 1) * cells];
        for (k, (states, m)) in ms.iter().enumerate().rev() {
            let (head, tail) = after.split_at_mut((k + 1) * cells);
            for ((a, &b), &su) in head[k * cells..]
                .iter_mut()
                .zip(&tail[..cells])
                .zip(*states)
            {
                *a = b * m.contour[su];
            }
        }
        let mut before = vec![1.0; cells];
        let mut floors = Vec::with_capacity(q);
        for (k, (states, m)) in ms.iter().enumerate() {
            let rest = &after[(k + 1) * cells..(k + 2) * cells];
            let sum: f64 = before.iter().zip(rest).map(|(a, b)| a * b).sum();
            let log_scale: f64 = (ms.iter().enumerate())
                .filter(|&(j, _)| j != k)
                .map(|(_, (_, m))| m.scale.ln())
                .sum();
            // No floor where the sum may have underflowed.
            let floor = if sum.is_finite() && sum > 1e-250 {
                (-(sum.ln() + log_scale)).max(0.0)
            } else {
                0.0
            };
            floors.push(floor);
            for (b, &su) in before.iter_mut().zip(*states) {
                *b *= m.contour[su];
            }
        }
        Some(floors)
    }
}

impl CellLevels<'_> {
    /// The Bayesian level of a pair from its few state tuples, bit-identical to the grown level
    /// of [`TupleStack`] (same products, summed in the same order); `None` as there.
    fn pair_level_bayesian(&self, group: GroupMask) -> Option<f64> {
        let (i, j) = (
            group.trailing_zeros() as usize,
            63 - group.leading_zeros() as usize,
        );
        let (a, b) = (self.usable[i].as_ref()?, self.usable[j].as_ref()?);
        let (mut s, mut possible) = (0.0, false);
        for &(x, y) in self.tracker.pair_tuples.of(i, j) {
            let (ca, cb) = (a.contour[x as usize], b.contour[y as usize]);
            possible |= ca > 0.0 && cb > 0.0;
            s += ca * cb;
        }
        if !possible {
            return Some(f64::INFINITY);
        }
        if s.is_nan() || s <= 1e-280 {
            return None;
        }
        let log_scale: f64 = [a.scale, b.scale].iter().map(|c| c.ln()).sum();
        Some((-(s.ln() + log_scale)).max(0.0))
    }
}

impl CellLevels<'_> {
    /// 1 − K(m_group, C) for the consonant C whose contour has maximum `cell_max` on each cell,
    /// by the Bayesian tuple sums; `None` for consonant functions or on underflow (the caller
    /// combines on the cells instead).
    pub(super) fn bayesian_agreement(&mut self, group: GroupMask, cell_max: &[f64]) -> Option<f64> {
        match self.tracker.settings.constructor {
            Constructor::Bayesian => {
                (self.tuples).agreement(self.tracker, self.usable, group, cell_max)
            }
            Constructor::Consonant => None,
        }
    }
}

impl Tracker {
    /// The selection's view of a frame's usable features.
    pub(super) fn cell_levels<'a>(&'a self, usable: &'a [Option<Usable>]) -> CellLevels<'a> {
        CellLevels {
            tracker: self,
            usable,
            tuples: TupleStack::reused(),
        }
    }

    /// Choose the group to combine among the usable features (`usable_mask`, not empty), and
    /// the number of the splitting policy's alternatives. Without group errors a frame keeps
    /// the first `max_alternatives` in the policy's order, so only those are listed (and their
    /// levels computed).
    pub(super) fn select(
        &self,
        usable: &[Option<Usable>],
        usable_mask: GroupMask,
    ) -> (Selection, usize) {
        let mut levels = self.cell_levels(usable);
        let (features, policy) = (usable.len(), self.settings.selection);
        let threshold = self.settings.conflict_threshold;
        if self.model.knows_group_errors() {
            let selection = select_group(&mut levels, features, usable_mask, policy, threshold);
            let found = selection.alternatives.len();
            return (selection, found);
        }
        let keep = self.settings.max_alternatives;
        select_group_keeping(&mut levels, features, usable_mask, policy, threshold, keep)
    }

    /// The fallback feature: lowest validation error (features without one after those with one),
    /// then lowest index.
    fn fallback_feature(&self, usable: &[Option<Usable>]) -> Option<usize> {
        let features = self.model.features();
        (0..usable.len())
            .filter(|&i| usable[i].is_some())
            .min_by(|&a, &b| {
                let ea = features[a].validation_error.unwrap_or(f64::INFINITY);
                let eb = features[b].validation_error.unwrap_or(f64::INFINITY);
                ea.total_cmp(&eb).then(a.cmp(&b))
            })
    }
}

#[cfg(test)]
#[path = "cell_levels_tests.rs"]
mod tests;
