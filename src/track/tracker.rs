//! The per-frame tracker.
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

use super::model::TrackerModel;
use super::settings::{CheckedTrackSettings, Estimator, SelectionPolicy, TrackSettings};
use super::TrackError;
use crate::evidence::{
    conflict_level_all, dempster_all, from_likelihoods, Constructor, LikelihoodIssue, MassFunction,
    Refining, Subset,
};

/// Two levels of conflict closer than this are a tie.
const TIE: f64 = 1e-12;

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
    /// Usable features left out of the chosen group by the conflict graph (normal operation).
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
/// plausibility, or pignistic probability for [`Estimator::Pignistic`]).
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
}

/// The tracker's output for one frame.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FrameEstimate {
    /// Estimated pose (mm); `None` when no feature was usable.
    pub estimate: Option<[f64; 2]>,
    /// Features combined for the estimate (ascending).
    pub group: Vec<usize>,
    /// Level of conflict of the chosen group (0 for a single feature); `None` without estimate.
    pub conflict_level: Option<f64>,
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
type Measured = (Vec<Option<Usable>>, Vec<(usize, FeatureIssue)>);

/// A usable feature of one frame.
struct Usable {
    /// Contour on the feature's own frame, scaled to max 1.
    contour: Vec<f64>,
    /// The factor the contour was divided by (its maximum).
    scale: f64,
    /// Consonant functions: level of every state (number of focal sets not containing it), so
    /// that the focal sets are {state : level ≤ k}.
    level: Vec<u32>,
    /// Measurement function on the feature's own frame.
    mass: MassFunction,
}

impl FrameEstimate {
    /// A frame with no estimate and no combined group; `flags` say why.
    fn without_estimate(flags: FrameFlags) -> Self {
        Self {
            estimate: None,
            group: Vec::new(),
            conflict_level: None,
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
    model: TrackerModel,
    settings: TrackSettings,
    /// Cell of every sample pose.
    cell_of: Vec<usize>,
    /// Number of sample poses of every cell.
    cell_size: Vec<usize>,
    /// Per feature, the refining of its frame onto the cells.
    to_cells: Vec<Refining>,
    /// co[i][j][a] for i < j: the states of feature j that occur together with state a of i.
    co: Vec<Vec<Vec<Subset>>>,
}

impl Tracker {
    /// Build a tracker (precomputes the cells and the state co-occurrences).
    ///
    /// # Errors
    /// [`TrackError::Evidence`] if a refining onto the cells cannot be built (not expected for a
    /// validated model).
    pub fn new(model: TrackerModel, settings: CheckedTrackSettings) -> Result<Self, TrackError> {
        let features = model.features();
        let t = model.poses().len();
        let mut ids: HashMap<Vec<usize>, usize> = HashMap::new();
        let mut cell_of = Vec::with_capacity(t);
        let mut cell_states: Vec<Vec<usize>> = Vec::new();
        let mut cell_size = Vec::new();
        for q in 0..t {
            let key: Vec<usize> = features
                .iter()
                .map(|f| f.refining.assignment()[q])
                .collect();
            let next = cell_states.len();
            let id = *ids.entry(key.clone()).or_insert(next);
            if id == next {
                cell_states.push(key);
                cell_size.push(0);
            }
            cell_size[id] += 1;
            cell_of.push(id);
        }
        let mut to_cells = Vec::with_capacity(features.len());
        for (i, f) in features.iter().enumerate() {
            let assignment: Vec<usize> = cell_states.iter().map(|s| s[i]).collect();
            let r = Refining::from_assignment(f.refining.coarse_size(), &assignment).map_err(
                |source| TrackError::Evidence {
                    feature: Some(i),
                    source,
                },
            )?;
            to_cells.push(r);
        }
        let f = features.len();
        let mut co = vec![Vec::new(); f];
        for i in 0..f {
            co[i] = vec![Vec::new(); f];
            for j in i + 1..f {
                let (ni, nj) = (
                    features[i].refining.coarse_size(),
                    features[j].refining.coarse_size(),
                );
                let mut rows = vec![Subset::empty(nj); ni];
                for s in &cell_states {
                    rows[s[i]].insert(s[j]);
                }
                co[i][j] = rows;
            }
        }
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
    fn measure(&self, likelihoods: &[Option<Vec<f64>>]) -> Result<Measured, TrackError> {
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

    /// Pairwise level of conflict of two usable features (i < j), on their own frames: focal sets
    /// A ⊆ Θᵢ and B ⊆ Θⱼ have intersecting extensions iff B meets the states co-occurring with A.
    fn pair_level(&self, i: usize, j: usize, a: &Usable, b: &Usable) -> f64 {
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

    /// Level of conflict of the combination of every usable feature (the quantity §4.3 learns the
    /// threshold from): +∞ on total conflict, 0 with fewer than two usable features.
    ///
    /// # Errors
    /// [`TrackError::FeatureInputCount`].
    pub fn full_conflict_level(&self, likelihoods: &[Option<Vec<f64>>]) -> Result<f64, TrackError> {
        let (usable, _) = self.measure(likelihoods)?;
        let all = usable
            .iter()
            .enumerate()
            .filter(|(_, u)| u.is_some())
            .fold(0u32, |m, (i, _)| m | 1 << i);
        Ok(self.level(all, &usable, &mut HashMap::new(), f64::INFINITY))
    }

    /// Level of conflict of a group on the cells (0 for one feature, +∞ when not combinable),
    /// memoised. With a finite `bound`, a group whose prefix (the group without its highest
    /// feature) is already known to exceed the bound is not combined: K only grows as features
    /// are added (Theorem 4.3), so it cannot be below the bound; it is recorded as +∞.
    fn level(
        &self,
        group: u32,
        usable: &[Option<Usable>],
        memo: &mut HashMap<u32, f64>,
        bound: f64,
    ) -> f64 {
        if group.count_ones() <= 1 {
            return 0.0;
        }
        if let Some(&k) = memo.get(&group) {
            return k;
        }
        let parent = group & !(1u32 << (31 - group.leading_zeros()));
        let k = match memo.get(&parent) {
            Some(&kp) if kp.is_nan() || kp > bound + TIE => f64::INFINITY,
            _ => self
                .fast_level(group, usable)
                .unwrap_or_else(|| self.general_level(group, usable)),
        };
        memo.insert(group, k);
        k
    }

    /// The group's measurement functions extended onto the cells (only the general path and the
    /// pignistic estimator need them).
    fn on_cells(&self, group: u32, usable: &[Option<Usable>]) -> Option<Vec<MassFunction>> {
        members(group)
            .filter_map(|i| {
                usable[i]
                    .as_ref()
                    .map(|u| self.to_cells[i].extend(&u.mass).ok())
            })
            .collect()
    }

    /// Reference: Dempster's rule on the cells.
    fn general_level(&self, group: u32, usable: &[Option<Usable>]) -> f64 {
        self.on_cells(group, usable)
            .and_then(|fs| conflict_level_all(&fs).ok())
            .unwrap_or(f64::INFINITY)
    }

    /// Fast exact level of conflict of a group; `None` when the general path must be used.
    fn fast_level(&self, group: u32, usable: &[Option<Usable>]) -> Option<f64> {
        let ms: Vec<(usize, &Usable)> = members(group)
            .filter_map(|i| usable[i].as_ref().map(|u| (i, u)))
            .collect();
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

    /// Relative plausibility of the sample poses under a group: the normalised product of the
    /// members' contours (the fast path; equal to the relative plausibility of the combination).
    fn plausibility(&self, group: u32, usable: &[Option<Usable>]) -> Option<Vec<f64>> {
        let cells = self.cell_count();
        let mut w = vec![1.0; cells];
        for (u, wu) in w.iter_mut().enumerate() {
            for (i, m) in usable.iter().enumerate() {
                if group >> i & 1 == 1 {
                    if let Some(m) = m {
                        *wu *= m.contour[self.to_cells[i].assignment()[u]];
                    }
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
    fn estimate_group(
        &self,
        group: u32,
        usable: &[Option<Usable>],
    ) -> Option<([f64; 2], Vec<f64>, Uncertainty)> {
        let pl = self.plausibility(group, usable)?;
        let poses = self.model.poses();
        let weights = match self.settings.estimator {
            Estimator::Pignistic => {
                let combined = dempster_all(&self.on_cells(group, usable)?).ok()?.mass?;
                self.pignistic(&combined)
            }
            _ => pl.clone(),
        };
        let estimate = match self.settings.estimator {
            Estimator::Map => {
                let mut best = 0;
                for (q, &x) in weights.iter().enumerate() {
                    if x > weights[best] {
                        best = q;
                    }
                }
                poses[best]
            }
            _ => weighted_mean(&weights, poses)?,
        };
        let uncertainty = uncertainty(&weights, poses, estimate, self.settings.uncertainty_mass);
        Some((estimate, pl, uncertainty))
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
            .fold(0u32, |m, i| m | 1 << i);
        if usable_mask == 0 {
            flags.no_usable_feature = true;
            return Ok(FrameEstimate::without_estimate(flags));
        }
        // Conflict graph.
        let mut adj = vec![0u32; f];
        for i in 0..f {
            let Some(a) = &usable[i] else { continue };
            for j in i + 1..f {
                let Some(b) = &usable[j] else { continue };
                let k = self.pair_level(i, j, a, b);
                if k.is_finite() && k <= self.settings.conflict_threshold {
                    adj[i] |= 1 << j;
                    adj[j] |= 1 << i;
                }
            }
        }
        let groups = cliques(usable_mask, &adj, f);
        let mut memo: HashMap<u32, f64> = HashMap::new();
        let policy = self.settings.selection;
        let min_size = policy.min_size();
        let mut chosen: Option<(f64, u32)> = None;
        let mut alternatives: Vec<(f64, u32)> = Vec::new();
        match policy {
            SelectionPolicy::LargestSubset => {
                // Groups come by increasing size in lexicographic order: scan from the largest.
                let mut size = groups.last().map_or(0, |g| g.count_ones());
                while size >= 1 && chosen.is_none() {
                    for &g in groups.iter().filter(|g| g.count_ones() == size) {
                        let k = self.level(g, &usable, &mut memo, f64::INFINITY);
                        if k.is_finite() && chosen.is_none_or(|(best, _)| k < best - TIE) {
                            chosen = Some((k, g));
                        }
                    }
                    size -= 1;
                }
                // A single feature while several are usable means no pair is compatible.
                if chosen.is_some_and(|(_, g)| g.count_ones() == 1) && usable_mask.count_ones() > 1
                {
                    chosen = None;
                }
            }
            SelectionPolicy::LowestConflict { .. } => {
                for &g in groups
                    .iter()
                    .filter(|g| g.count_ones() as usize >= min_size)
                {
                    let bound = chosen.map_or(f64::INFINITY, |(k, _)| k);
                    let k = self.level(g, &usable, &mut memo, bound);
                    if k.is_finite() {
                        let better = match chosen {
                            None => true,
                            Some((best, bg)) => {
                                k < best - TIE
                                    || (k <= best + TIE && g.count_ones() > bg.count_ones())
                            }
                        };
                        if better {
                            chosen = Some((k, g));
                        }
                    }
                }
            }
            SelectionPolicy::Splitting { .. } => {
                for &g in groups
                    .iter()
                    .rev()
                    .filter(|g| g.count_ones() as usize >= min_size)
                {
                    if alternatives.iter().any(|&(_, a)| g & a == g) {
                        continue;
                    }
                    let k = self.level(g, &usable, &mut memo, f64::INFINITY);
                    if k.is_finite() {
                        alternatives.push((k, g));
                    }
                }
                alternatives.sort_by(|a, b| {
                    b.1.count_ones()
                        .cmp(&a.1.count_ones())
                        .then(a.0.total_cmp(&b.0))
                        .then(lex(a.1).cmp(&lex(b.1)))
                });
                chosen = alternatives.first().copied();
            }
        }
        if chosen.is_none() {
            flags.fallback = true;
            alternatives.clear();
            chosen = self.fallback_feature(&usable).map(|i| (0.0, 1u32 << i));
        }
        let Some((level, group)) = chosen else {
            flags.no_usable_feature = true;
            return Ok(FrameEstimate::without_estimate(flags));
        };
        flags.excluded = lex(usable_mask & !group);
        let mut alts = Vec::with_capacity(alternatives.len());
        for &(k, g) in &alternatives {
            if let Some((estimate, _, uncertainty)) = self.estimate_group(g, &usable) {
                alts.push(Alternative {
                    group: lex(g),
                    conflict_level: k,
                    estimate,
                    uncertainty,
                });
            }
        }
        let result = self.estimate_group(group, &usable);
        flags.combination_failed = result.is_none();
        Ok(FrameEstimate {
            estimate: result.as_ref().map(|r| r.0),
            group: lex(group),
            conflict_level: Some(level),
            uncertainty: result.as_ref().map(|r| r.2),
            plausibility: result.map(|r| r.1).unwrap_or_default(),
            alternatives: alts,
            flags,
        })
    }
}

/// Feature indices of a group mask, ascending (also its lexicographic key).
fn lex(mask: u32) -> Vec<usize> {
    members(mask).collect()
}

/// Feature indices of a group mask, ascending.
fn members(mask: u32) -> impl Iterator<Item = usize> {
    (0..32).filter(move |i| mask >> i & 1 == 1)
}

/// All complete subgraphs among the usable features, grown bottom-up: the groups of size d + 1 are
/// the groups of size d extended by a higher-indexed feature adjacent to all their members.
/// Returned by increasing size, lexicographic within a size.
fn cliques(usable: u32, adj: &[u32], f: usize) -> Vec<u32> {
    let mut all: Vec<u32> = (0..f)
        .filter(|&i| usable >> i & 1 == 1)
        .map(|i| 1u32 << i)
        .collect();
    let mut start = 0;
    while start < all.len() {
        let end = all.len();
        for g in start..end {
            let group = all[g];
            let top = 31 - group.leading_zeros() as usize;
            for (j, &aj) in adj.iter().enumerate().take(f).skip(top + 1) {
                if usable >> j & 1 == 1 && aj & group == group {
                    all.push(group | 1 << j);
                }
            }
        }
        start = end;
    }
    all
}

/// Weighted RMS distance from `centre` and the smallest radius holding `share` of the weight.
fn uncertainty(weights: &[f64], poses: &[[f64; 2]], centre: [f64; 2], share: f64) -> Uncertainty {
    // Squared distances: the quantile is the same, and no square root per pose.
    let mut items: Vec<(f64, f64)> = weights
        .iter()
        .zip(poses)
        .filter(|(w, _)| **w > 0.0)
        .map(|(&w, p)| {
            let (dx, dy) = (p[0] - centre[0], p[1] - centre[1]);
            (dx * dx + dy * dy, w)
        })
        .collect();
    let total: f64 = items.iter().map(|x| x.1).sum();
    if items.is_empty() || total <= 0.0 {
        return Uncertainty {
            spread: 0.0,
            radius: 0.0,
        };
    }
    let spread = (items.iter().map(|(d2, w)| d2 * w).sum::<f64>() / total).sqrt();
    let radius = weighted_quantile(&mut items, share * total).sqrt();
    Uncertainty { spread, radius }
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
    use crate::evidence::{conflict, level_of_conflict};
    use crate::track::{FeatureModel, TrackSettings};

    #[test]
    fn cliques_grow_bottom_up() {
        // Triangle 0-1-2 plus edge 2-3.
        let adj = [0b0110, 0b0101, 0b1011, 0b0100];
        let g = cliques(0b1111, &adj, 4);
        assert_eq!(
            g,
            vec![0b0001, 0b0010, 0b0100, 0b1000, 0b0011, 0b0101, 0b0110, 0b1100, 0b0111]
        );
        // Without feature 1 usable.
        let g = cliques(0b1101, &adj, 4);
        assert_eq!(g, vec![0b0001, 0b0100, 0b1000, 0b0101, 0b1100]);
    }

    #[test]
    fn weighted_quantile_by_hand() {
        let mut items = vec![(3.0, 0.25), (1.0, 0.25), (2.0, 0.25), (4.0, 0.25)];
        assert_eq!(weighted_quantile(&mut items, 0.5), 2.0);
        assert_eq!(weighted_quantile(&mut items, 0.51), 3.0);
        assert_eq!(weighted_quantile(&mut items, 1.0), 4.0);
        assert_eq!(weighted_quantile(&mut items, 1.0 + 1e-9), 4.0);
        assert_eq!(weighted_quantile(&mut items, 0.1), 1.0);
    }

    fn tiny_tracker(constructor: crate::evidence::Constructor) -> Tracker {
        // 6 poses on a line; three features with different partitions.
        let poses: Vec<[f64; 2]> = (0..6).map(|i| [i as f64, 0.0]).collect();
        let feats = [
            vec![0, 0, 0, 1, 1, 1],
            vec![0, 0, 1, 1, 2, 2],
            vec![0, 1, 1, 0, 0, 1],
        ];
        let features = feats
            .iter()
            .map(|a| FeatureModel {
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
                        FeatureModel {
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
                    for group in 1u32..32 {
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
            let settings = TrackSettings { constructor, conflict_threshold: threshold, selection, ..TrackSettings::default() };
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
