//! The cells of a model: the classes of sample poses that share the same state in every feature,
//! with every feature's refining onto them and the state co-occurrences between features. Built
//! once per model by [`Tracker::new`](super::Tracker::new); the per-frame work runs on them.

use std::collections::HashMap;
use std::sync::OnceLock;

use super::cell_products::NearRepeats;
use super::tracker_model::TrackerModel;
use super::TrackError;
use crate::evidence::{Refining, Subset};

/// The cells of a model and the state co-occurrences of its features.
pub(super) struct Cells {
    /// Cell of every sample pose.
    pub(super) cell_of: Vec<usize>,
    /// Number of sample poses of every cell.
    pub(super) cell_size: Vec<usize>,
    /// Per feature, the refining of its frame onto the cells.
    pub(super) to_cells: Vec<Refining>,
    /// `co[i][j][a]` for i < j: the states of feature j that occur together with state a of i.
    pub(super) co: Vec<Vec<Vec<Subset>>>,
    /// The pairs' state tuples in order of first occurrence on the cells.
    pub(super) pair_tuples: PairTuples,
}

/// Per pair of features i < j, the state pairs (a, b) that occur on the cells, in order of first
/// occurrence: the order in which the grown Bayesian level sums them, so that a pair's group level
/// costs one pass over its few tuples instead of two over the cells, with the same bits.
#[derive(Clone, Debug)]
pub(super) struct PairTuples {
    features: usize,
    /// Tuples of pair (i, j) are `tuples[start[i * features + j]..start[i * features + j + 1]]`.
    start: Vec<usize>,
    tuples: Vec<(u32, u32)>,
    /// Per feature, its states occurring on the cells in order of first occurrence.
    states: Vec<Vec<u32>>,
    /// Per pair (indexed as `start`), each cell's tuple number, built when first asked for
    /// (empty when the model is too large for them: [`MAX_CELL_TUPLES`]).
    cell_tuples: Vec<OnceLock<Vec<u16>>>,
    /// The pairs of cells that differ in a few features, built when first asked for.
    near_repeats: OnceLock<Option<NearRepeats>>,
}

/// Most cell tuple numbers [`PairTuples::cell_tuples`] keeps over every pair (2 MB): beyond it
/// the per-frame work indexes the state pairs instead.
const MAX_CELL_TUPLES: usize = 1 << 20;

impl PairTuples {
    fn new(to_cells: &[Refining]) -> Self {
        let f = to_cells.len();
        let mut start = Vec::with_capacity(f * f + 1);
        let mut tuples = Vec::new();
        let mut seen = Vec::new();
        start.push(0);
        for i in 0..f {
            for j in 0..f {
                if j > i {
                    let nj = to_cells[j].coarse_size();
                    seen.clear();
                    seen.resize(to_cells[i].coarse_size() * nj, false);
                    let pairs = to_cells[i]
                        .assignment()
                        .iter()
                        .zip(to_cells[j].assignment());
                    for (&a, &b) in pairs {
                        if !std::mem::replace(&mut seen[a * nj + b], true) {
                            tuples.push((a as u32, b as u32));
                        }
                    }
                }
                start.push(tuples.len());
            }
        }
        let states = to_cells
            .iter()
            .map(|r| {
                let mut seen = vec![false; r.coarse_size()];
                (r.assignment().iter())
                    .filter(|&&a| !std::mem::replace(&mut seen[a], true))
                    .map(|&a| a as u32)
                    .collect()
            })
            .collect();
        let cells = to_cells.first().map_or(0, |r| r.assignment().len());
        // Tuple numbers fit in 16 bits when the cells do (each tuple occurs on a cell).
        let numbered = cells <= usize::from(u16::MAX) && f * f * cells <= MAX_CELL_TUPLES;
        let cell_tuples = if numbered {
            (0..f * f).map(|_| OnceLock::new()).collect()
        } else {
            Vec::new()
        };
        PairTuples {
            features: f,
            start,
            tuples,
            states,
            cell_tuples,
            near_repeats: OnceLock::new(),
        }
    }

    /// The pairs of cells that differ in a few features ([`NearRepeats`]), built on first use;
    /// `None` when the model is too large for them.
    pub(super) fn near_repeats(&self, to_cells: &[Refining]) -> Option<&NearRepeats> {
        (self.near_repeats)
            .get_or_init(|| NearRepeats::new(to_cells))
            .as_ref()
    }

    /// The number of each cell's tuple of features `i < j` in [`PairTuples::of`]'s list, built
    /// on first use (a frame then reads one number per cell instead of both states); `None`
    /// when the model is too large to keep them.
    pub(super) fn cell_tuples(&self, i: usize, j: usize, to_cells: &[Refining]) -> Option<&[u16]> {
        let slot = self.cell_tuples.get(i * self.features + j)?;
        let ids = slot.get_or_init(|| {
            let nb = to_cells[j].coarse_size();
            let mut number = vec![0u16; to_cells[i].coarse_size() * nb];
            for (t, &(x, y)) in self.of(i, j).iter().enumerate() {
                // At most one tuple per cell, and the cells fit in 16 bits.
                number[x as usize * nb + y as usize] = t as u16;
            }
            (to_cells[i].assignment().iter())
                .zip(to_cells[j].assignment())
                .map(|(&x, &y)| number[x * nb + y])
                .collect()
        });
        Some(ids)
    }

    /// The states of feature `i` occurring on the cells, in order of first occurrence.
    pub(super) fn states(&self, i: usize) -> &[u32] {
        &self.states[i]
    }

    /// The state pairs of features `i < j` occurring on the cells, in order of first occurrence.
    pub(super) fn of(&self, i: usize, j: usize) -> &[(u32, u32)] {
        let k = i * self.features + j;
        &self.tuples[self.start[k]..self.start[k + 1]]
    }
}

impl Cells {
    /// The cells of the model's sample poses, every feature's refining onto them and the state
    /// co-occurrences.
    ///
    /// # Errors
    /// [`TrackError::Evidence`] if a refining onto the cells cannot be built (not expected for a
    /// validated model).
    pub(super) fn new(model: &TrackerModel) -> Result<Self, TrackError> {
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
        let pair_tuples = PairTuples::new(&to_cells);
        Ok(Cells {
            cell_of,
            cell_size,
            to_cells,
            co,
            pair_tuples,
        })
    }
}
