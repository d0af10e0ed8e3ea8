//! Levels of conflict on the cells: pairwise on the features' own frames through the state
//! co-occurrences, and for a group through the exact Bayesian and consonant shortcuts, with
//! Dempster's rule on the cells as the reference and the fallback on underflow; memoised per frame.

use std::collections::HashMap;

use super::group_search::{members, memoised_level, GroupMask};
use super::tracker::{Tracker, Usable};
use crate::evidence::{conflict_level_all, Constructor, MassFunction, Subset};

impl Tracker {
    /// Pairwise level of conflict of two usable features (i < j), on their own frames: focal sets
    /// A ⊆ Θᵢ and B ⊆ Θⱼ have intersecting extensions iff B meets the states co-occurring with A.
    pub(super) fn pair_level(&self, i: usize, j: usize, a: &Usable, b: &Usable) -> f64 {
        let rows = &self.co[i][j];
        let s = match self.settings.constructor {
            // Singletons: s = Σ_a p_i(a) Σ_{b co-occurring with a} p_j(b).
            Constructor::Bayesian => {
                let mut s = 0.0;
                for (st, &ca) in a.contour.iter().enumerate() {
                    if ca > 0.0 {
                        let pl: f64 = rows[st].iter().map(|x| b.contour[x]).sum();
                        s += ca * pl;
                    }
                }
                s * a.scale * b.scale
            }
            // Consonant j: Pl_j(X) = max of its contour over X, so
            // Pl_j(N(A)) = max over states a ∈ A of the best contour co-occurring with a.
            Constructor::Consonant => {
                let row_max: Vec<f64> = rows
                    .iter()
                    .map(|r| r.iter().map(|x| b.contour[x]).fold(0.0f64, f64::max))
                    .collect();
                let mut s = 0.0;
                for (set, m) in a.mass.focal() {
                    let pl = set.iter().map(|st| row_max[st]).fold(0.0f64, f64::max);
                    s += m * pl;
                }
                s * b.scale
            }
        };
        if s > 0.0 {
            (-s.ln()).max(0.0)
        } else {
            f64::INFINITY
        }
    }

    /// Level of conflict of a group on the cells (0 for one feature, +∞ when not combinable),
    /// memoised, with the prefix pruning of [`memoised_level`] under a finite `bound`.
    pub(super) fn level(
        &self,
        group: GroupMask,
        usable: &[Option<Usable>],
        memo: &mut HashMap<GroupMask, f64>,
        bound: f64,
    ) -> f64 {
        memoised_level(memo, group, bound, || self.raw_level(group, usable))
    }

    /// Level of conflict of a group of at least two features on the cells, not memoised.
    pub(super) fn raw_level(&self, group: GroupMask, usable: &[Option<Usable>]) -> f64 {
        self.fast_level(group, usable)
            .unwrap_or_else(|| self.general_level(group, usable))
    }

    /// The group's measurement functions extended onto the cells (only the general path and the
    /// pignistic estimator need them).
    pub(super) fn on_cells(
        &self,
        group: GroupMask,
        usable: &[Option<Usable>],
    ) -> Option<Vec<MassFunction>> {
        members(group)
            .filter_map(|i| {
                usable[i]
                    .as_ref()
                    .map(|u| self.to_cells[i].extend(&u.mass).ok())
            })
            .collect()
    }

    /// Reference: Dempster's rule on the cells.
    pub(super) fn general_level(&self, group: GroupMask, usable: &[Option<Usable>]) -> f64 {
        self.on_cells(group, usable)
            .and_then(|fs| conflict_level_all(&fs).ok())
            .unwrap_or(f64::INFINITY)
    }

    /// The Bayesian shortcut's level of a group of usable features (`None`: use the general path).
    pub(super) fn bayesian_group_level(
        &self,
        group: GroupMask,
        usable: &[Option<Usable>],
    ) -> Option<f64> {
        self.bayesian_level(&usable_members(group, usable))
    }

    /// Fast exact level of conflict of a group; `None` when the general path must be used.
    fn fast_level(&self, group: GroupMask, usable: &[Option<Usable>]) -> Option<f64> {
        let ms = usable_members(group, usable);
        match self.settings.constructor {
            Constructor::Bayesian => self.bayesian_level(&ms),
            Constructor::Consonant => self.consonant_level(&ms),
        }
    }

    /// Bayesian functions: the extended focal sets are blocks, so the non-conflicting mass is the
    /// sum, over the distinct state tuples of the group that occur on the cells, of the product of
    /// the singleton masses. Tuples are numbered feature by feature with a dense table.
    fn bayesian_level(&self, ms: &[(usize, &Usable)]) -> Option<f64> {
        let cells = self.cell_count();
        let mut id = vec![0u32; cells];
        let mut count = 1usize;
        let mut remap: Vec<u32> = Vec::new();
        // With every feature of the model, the tuples are the cells themselves.
        let every = ms.len() == self.to_cells.len();
        if every {
            for (u, idu) in id.iter_mut().enumerate() {
                *idu = u as u32;
            }
            count = cells;
        }
        for &(i, _) in ms.iter().filter(|_| !every) {
            let st = self.to_cells[i].assignment();
            let n = self.to_cells[i].coarse_size();
            remap.clear();
            remap.resize(count * n, u32::MAX);
            let mut next = 0u32;
            for (idu, &su) in id.iter_mut().zip(st) {
                let key = *idu as usize * n + su;
                if remap[key] == u32::MAX {
                    remap[key] = next;
                    next += 1;
                }
                *idu = remap[key];
            }
            count = next as usize;
        }
        let mut seen = vec![false; count];
        let mut s = 0.0;
        let mut possible = false;
        for (u, &idu) in id.iter().enumerate() {
            if !std::mem::replace(&mut seen[idu as usize], true) {
                let mut prod = 1.0;
                let mut positive = true;
                for &(i, m) in ms {
                    let c = m.contour[self.to_cells[i].assignment()[u]];
                    positive &= c > 0.0;
                    prod *= c;
                }
                possible |= positive;
                s += prod;
            }
        }
        if !possible {
            return Some(f64::INFINITY);
        }
        // Scaled contours keep the sum away from underflow; if it still underflows, let the
        // general path (which renormalises at every step) decide.
        if s.is_nan() || s <= 1e-280 {
            return None;
        }
        let log_scale: f64 = ms.iter().map(|(_, m)| m.scale.ln()).sum();
        Some((-(s.ln() + log_scale)).max(0.0))
    }

    /// Consonant functions: focal sets are down-sets in level space, and a product of down-sets
    /// (one focal set per feature) meets the cells iff it meets the Pareto-minimal level vectors
    /// of the cells. Dempster's rule therefore runs on that (small) set of minimal points.
    fn consonant_level(&self, ms: &[(usize, &Usable)]) -> Option<f64> {
        let d = ms.len();
        let cells = self.cell_count();
        let mut levels = vec![0u32; cells * d];
        for (u, row) in levels.chunks_exact_mut(d).enumerate() {
            for (l, &(i, m)) in row.iter_mut().zip(ms) {
                *l = m.level[self.to_cells[i].assignment()[u]];
            }
        }
        let mut order: Vec<(u32, u32)> = levels
            .chunks_exact(d)
            .enumerate()
            .map(|(u, row)| (row.iter().sum::<u32>(), u as u32))
            .collect();
        order.sort_unstable();
        let mut minimal: Vec<usize> = Vec::new();
        for &(_, u) in &order {
            let p = &levels[u as usize * d..(u as usize + 1) * d];
            let dominated = minimal.iter().any(|&q| {
                levels[q * d..(q + 1) * d]
                    .iter()
                    .zip(p)
                    .all(|(a, b)| a <= b)
            });
            if !dominated {
                minimal.push(u as usize);
            }
        }
        let frame = minimal.len();
        let mut fs = Vec::with_capacity(d);
        for &(i, m) in ms {
            let st = self.to_cells[i].assignment();
            let pairs = m
                .mass
                .focal()
                .map(|(a, x)| {
                    let mut set = Subset::empty(frame);
                    for (p, &u) in minimal.iter().enumerate() {
                        if a.contains(st[u]) {
                            set.insert(p);
                        }
                    }
                    (set, x)
                })
                .collect();
            fs.push(MassFunction::unnormalised(frame, pairs).ok()?);
        }
        conflict_level_all(&fs).ok()
    }
}

/// The usable members of a group with their measurement functions, ascending.
fn usable_members(group: GroupMask, usable: &[Option<Usable>]) -> Vec<(usize, &Usable)> {
    members(group)
        .filter_map(|i| usable[i].as_ref().map(|u| (i, u)))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::evidence::{conflict, from_likelihoods, level_of_conflict, Refining};
    use crate::track::tracking::tests::tiny_tracker;
    use crate::track::{TrackSettings, TrackedFeature, TrackerModel};

    #[test]
    fn coarse_pairwise_conflict_equals_conflict_on_poses() {
        for c in [
            crate::evidence::Constructor::Bayesian,
            crate::evidence::Constructor::Consonant,
        ] {
            let t = tiny_tracker(c);
            let lik = vec![
                Some(vec![0.9, 0.2]),
                Some(vec![0.1, 0.3, 0.7]),
                Some(vec![0.6, 0.5]),
            ];
            let k = t.pairwise_conflicts(&lik).unwrap();
            for i in 0..3 {
                for j in (0..3).filter(|&j| j != i) {
                    let mi = from_likelihoods(c, lik[i].as_ref().unwrap()).unwrap().mass;
                    let mj = from_likelihoods(c, lik[j].as_ref().unwrap()).unwrap().mass;
                    let f = t.model().features();
                    let ei = f[i].refining.extend(&mi).unwrap();
                    let ej = f[j].refining.extend(&mj).unwrap();
                    let reference = level_of_conflict(conflict(&ei, &ej).unwrap());
                    let got = k[i][j].unwrap();
                    assert!(
                        (got - reference).abs() < 1e-12,
                        "{c:?} {i} {j}: {got} vs {reference}"
                    );
                }
            }
            assert_eq!(t.cell_count(), 6);
        }
    }

    /// The levels grown one feature at a time equal the direct ones bit for bit, in the
    /// search's lexicographic order and in random orders.
    fn grown_levels_are_bit_identical(
        t: &Tracker,
        usable: &[Option<Usable>],
        rng: &mut rand_chacha::ChaCha8Rng,
    ) {
        use rand::seq::SliceRandom;
        let mut groups: Vec<GroupMask> = (1..32)
            .filter(|g: &GroupMask| g.count_ones() >= 2)
            .collect();
        groups.sort_by(|&a, &b| crate::track::group_search::lex_cmp(a, b));
        for round in 0..3 {
            if round > 0 {
                groups.shuffle(rng);
            }
            let mut stack = crate::track::tuples::TupleStack::default();
            for &g in &groups {
                let grown = stack.level(t, usable, g).map(f64::to_bits);
                assert_eq!(
                    grown,
                    t.fast_level(g, usable).map(f64::to_bits),
                    "group {g:b}"
                );
                // A pair's level from its state tuples, as the search reads it.
                if let (2, Some(k)) = (g.count_ones(), grown) {
                    use crate::track::group_search::GroupLevels;
                    let from_tuples = t.cell_levels(usable).group_level(g);
                    assert_eq!(from_tuples.to_bits(), k, "pair {g:b}");
                }
            }
        }
    }

    #[test]
    fn fast_group_levels_equal_the_general_combination() {
        use crate::evidence::Constructor;
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(99);
        let (mut finite, mut infinite) = (0, 0);
        for constructor in [Constructor::Bayesian, Constructor::Consonant] {
            for _model in 0..4 {
                let t_poses = 15;
                let poses: Vec<[f64; 2]> = (0..t_poses).map(|q| [q as f64, 0.0]).collect();
                let states: Vec<usize> = (0..5).map(|_| rng.random_range(2..6)).collect();
                let features = states
                    .iter()
                    .map(|&n| {
                        // First n poses take every state so the refining is valid.
                        let a: Vec<usize> = (0..t_poses)
                            .map(|q| if q < n { q } else { rng.random_range(0..n) })
                            .collect();
                        TrackedFeature {
                            refining: Refining::from_assignment(n, &a).unwrap(),
                            validation_error: None,
                        }
                    })
                    .collect();
                let model = TrackerModel::new(poses, features).unwrap();
                let settings = TrackSettings {
                    constructor,
                    ..TrackSettings::default()
                };
                let t = Tracker::new(model, settings.check().unwrap()).unwrap();
                for _frame in 0..10 {
                    let lik: Vec<Option<Vec<f64>>> = states
                        .iter()
                        .map(|&n| {
                            let mut g: Vec<f64> =
                                (0..n).map(|_| rng.random_range(0.0..1.0)).collect();
                            // Some exact zeros, so that some groups are in total conflict.
                            for x in g.iter_mut() {
                                if rng.random_bool(0.5) {
                                    *x = 0.0;
                                }
                            }
                            g[rng.random_range(0..n)] = 1.0;
                            Some(g)
                        })
                        .collect();
                    let (usable, _) = t.measure(&lik).unwrap();
                    if constructor == Constructor::Bayesian {
                        grown_levels_are_bit_identical(&t, &usable, &mut rng);
                    }
                    for group in 1..32 {
                        let general = t.general_level(group, &usable);
                        let fast = t.fast_level(group, &usable).unwrap();
                        if general.is_finite() {
                            assert!(
                                (fast - general).abs() < 1e-12 * (1.0 + general),
                                "{fast} vs {general}"
                            );
                            finite += 1;
                        } else {
                            assert_eq!(fast, f64::INFINITY);
                            infinite += 1;
                        }
                    }
                }
            }
        }
        assert!(
            finite > 100 && infinite > 100,
            "finite {finite}, infinite {infinite}"
        );
    }
}
