//! The per-frame tracker's data: the frame types, the [`Tracker`] and the measurement of a frame.
//! Sibling files hold the steps, each above this one: `cells` (cells and state co-occurrences,
//! built once per model, below it), `conflict` (levels of conflict of pairs and groups),
//! `cell_levels` (the cells seen by the generic `group_search`), `estimate` (plausibility,
//! estimate and uncertainty) and `tracking` (the public entry points that run them).
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

use serde::{Deserialize, Serialize};

use super::cells::{Cells, PairTuples};
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
    /// The splitting policy found more alternatives than `max_alternatives`: only the kept ones
    /// were estimated and weighed (`FrameEstimate::alternatives_found` says how many there were).
    #[serde(default)]
    pub alternatives_capped: bool,
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
    /// Second moments of the sample poses about the estimate, weighted (mm²).
    pub covariance: [[f64; 2]; 2],
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
    /// Alternatives of the splitting policy, the chosen one first (empty for other policies):
    /// the `max_alternatives` the cap keeps, each estimated.
    pub alternatives: Vec<Alternative>,
    /// How many maximal eligible groups the splitting policy found in all, `alternatives` and
    /// those beyond the cap (0 for other policies and on fallback).
    #[serde(default)]
    pub alternatives_found: usize,
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
            alternatives_found: 0,
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
    /// Per pair of features, its state tuples on the cells (cheap exact pair levels).
    pub(super) pair_tuples: PairTuples,
    /// Each feature's reliability (1 without discounting).
    pub(super) alpha: Vec<f64>,
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
            pair_tuples,
        } = Cells::new(&model)?;
        let alpha = super::fusion::reliabilities(&model, settings.get(), cell_size.len())?;
        Ok(Tracker {
            model,
            settings: settings.get().clone(),
            cell_of,
            cell_size,
            to_cells,
            co,
            pair_tuples,
            alpha,
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
}
