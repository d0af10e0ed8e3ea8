//! A report for a feature's author (issue 28, item 4): per feature, what it measures and how
//! much it is worth, from a dataset folder (`evitrack features DATASET --report`).
//!
//! What it needs, and the choices made:
//!
//! - **Without ground truth** only what the images give: each feature's spread over the frames
//!   (mean, sd, range), its missing and non-finite shares, its correlation with the others
//!   (Pearson, over the frames where both are present) and how often each fault kind changes it
//!   (`faults.rs`).
//! - **Faults**: each `[[faults]]` spec on its own, applied with a seed to up to `fault_frames`
//!   evenly spaced frames; "changes it" is the faults module's own test (the value moved by more
//!   than [`crate::faults::CHANGE_TOLERANCE`] of its range over the dataset's frames, or
//!   appeared or vanished), as a share of the frames the fault struck. The default kinds are the
//!   image faults of `src/faults/` (feature faults change exactly the features they name, so
//!   they say nothing about a feature).
//! - **With ground truth** (`information.rs`): the feature maps are the continuous tracker's
//!   surrogates fitted on the even frames, and σ each feature's RMS residual y − f(q) on the odd
//!   frames (with a separate validation dataset: fitted on every frame, residuals on the
//!   validation frames), over the frames where its value lies strictly inside its range (a tile
//!   without the arm reads exactly 0, noise-free; fewer than 5 such frames: the maps'
//!   leave-one-out scale). Information over a grid of the workspace: a feature's own Fisher
//!   information is |∇f|²/σ² (the trace of its term of I); its **share** is its sum over the grid
//!   over every feature's. As the features correlate, the report also gives what leaving it out
//!   costs the full-covariance Cramér–Rao limit (RMS over the grid, relative). The **neighbour
//!   separation** of §3.1 (condition 2) over the dataset's neighbouring poses (`adaptive`'s
//!   Gabriel pairs): the largest change between neighbours as a share of the feature's range
//!   (condition 2 wants it small) and the median change in units of σ (above 1, the feature tells
//!   neighbours apart).
//! - **Ablation** (`ablation.rs`): each listed per-frame method fitted on the same split with all
//!   features and with each one left out; the change of its mean error on the held-out frames.
//!   Cost: (features + 1) fits per method, so the default is k-NN alone.

mod ablation;
mod faults;
mod information;
mod output;
mod truth_free;

use std::collections::BTreeMap;

use serde::Serialize;

use crate::estimator::{EstimatorError, Labelled, Method};
use crate::planar::Rect;

pub use faults::{default_faults, fault_changes, FaultChanges};
pub use output::{table, write_outputs, JSON_FILE, PLOT_FILE};

/// Failures of the feature report.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum FeatureReportError {
    /// Nothing to report on.
    #[error("{0}")]
    Input(String),
    /// A method could not be used for the ablation.
    #[error("ablation with `{method}`: {message}")]
    Method {
        /// The method.
        method: String,
        /// Why.
        message: String,
    },
    /// A method failed to fit or estimate.
    #[error("ablation with `{method}` {stage}: {source}")]
    Estimator {
        /// The method.
        method: String,
        /// Which fit (`with every feature`, `without f`).
        stage: String,
        /// The estimator's error.
        source: EstimatorError,
    },
    /// A fault spec is invalid.
    #[error(transparent)]
    Fault(#[from] crate::faults::FaultError),
    /// A feature program failed on the faulted frames.
    #[error("the features of the faulted frames: {0}")]
    External(#[from] crate::external::ExternalError),
    /// Writing the JSON or the plot failed.
    #[error(transparent)]
    Report(#[from] crate::report::ReportError),
}

/// What the report is computed from (feature rows already extracted).
#[derive(Debug, Clone, Copy)]
pub struct Inputs<'a> {
    /// Feature names, one per column.
    pub names: &'a [String],
    /// One row per frame.
    pub rows: &'a [Vec<Option<f64>>],
    /// Ground-truth positions, one per row, when the dataset has them.
    pub poses: Option<&'a [[f64; 2]]>,
    /// A separate dataset for σ and the ablation's errors; `None`: the dataset's odd frames.
    pub validation: Option<Labelled<'a>>,
    /// The workspace the information is mapped over (default: the poses' bounding box).
    pub workspace: Option<Rect>,
}

/// How the report is computed.
#[derive(Debug, Clone)]
pub struct Options {
    /// Per-frame methods of the ablation (none: no ablation).
    pub methods: Vec<Method>,
    /// Grid points per axis of the information map.
    pub grid: usize,
}

impl Default for Options {
    fn default() -> Self {
        Self {
            methods: vec![Method::KNN],
            grid: 20,
        }
    }
}

/// The report: per feature, and what it was measured on.
#[derive(Debug, Clone, Serialize)]
pub struct FeatureReport {
    /// Frames of the dataset.
    pub frames: usize,
    /// Whether it has ground truth (else only the truth-free columns are filled).
    pub ground_truth: bool,
    /// Where σ and the ablation's errors come from.
    pub split: String,
    /// Frames each fault was applied to.
    pub fault_frames: usize,
    /// The faults, by name, in order.
    pub faults: Vec<String>,
    /// Each ablation method's mean error (mm) on the held-out frames with every feature.
    pub method_errors: BTreeMap<String, f64>,
    /// The RMS over the grid of the Cramér–Rao limit with every feature (mm).
    pub limit_rms: Option<f64>,
    /// The information map's grid: x and y of its points (mm), row-major with x fastest.
    pub grid: Option<Grid>,
    /// One entry per feature.
    pub features: Vec<FeatureEntry>,
    /// Pearson correlation between features (`None`: fewer than 3 common frames, or constant).
    pub correlation: Vec<Vec<Option<f64>>>,
    /// What could not be measured, and why.
    pub notes: Vec<String>,
}

/// The information map's grid.
#[derive(Debug, Clone, Serialize)]
pub struct Grid {
    /// x of the columns (mm).
    pub x: Vec<f64>,
    /// y of the rows (mm).
    pub y: Vec<f64>,
}

/// What the report says of one feature.
#[derive(Debug, Clone, Default, Serialize)]
pub struct FeatureEntry {
    /// Its name.
    pub name: String,
    /// Mean over the frames where it is present and finite.
    pub mean: Option<f64>,
    /// Standard deviation over those frames.
    pub sd: Option<f64>,
    /// Smallest value.
    pub min: Option<f64>,
    /// Largest value.
    pub max: Option<f64>,
    /// Share of frames without a value.
    pub missing_share: f64,
    /// Share of frames with a NaN or infinite value.
    pub non_finite_share: f64,
    /// The other feature it correlates with most, and that correlation.
    pub most_correlated: Option<(String, f64)>,
    /// Per fault: share of the struck frames whose value the fault changed.
    pub fault_changes: BTreeMap<String, f64>,
    /// Noise σ: RMS residual of the feature map on the held-out frames.
    pub sigma: Option<f64>,
    /// Share of the Fisher information (trace, summed over the grid).
    pub information_share: Option<f64>,
    /// Relative increase of the RMS Cramér–Rao limit over the grid when it is left out.
    pub limit_increase: Option<f64>,
    /// Share of the grid where leaving it out makes the information singular.
    pub singular_without: Option<f64>,
    /// Largest change between neighbouring poses, as a share of its range (condition 2).
    pub neighbour_max_change: Option<f64>,
    /// Median change between neighbouring poses, in units of σ.
    pub neighbour_median_sigmas: Option<f64>,
    /// Per method: change of its mean error (mm) when the feature is left out.
    pub ablation: BTreeMap<String, f64>,
    /// Its own information |∇f|²/σ² (mm⁻²) at each grid point.
    pub information_map: Option<Vec<f64>>,
}

/// Builds the report from extracted rows; `changes` are the faults' ([`fault_changes`]),
/// `progress(stage, done, total)` follows the fits.
///
/// # Errors
/// [`FeatureReportError::Input`] for no frames, no features or rows of the wrong length; a
/// method that cannot be fitted.
pub fn build(
    inputs: &Inputs<'_>,
    options: &Options,
    changes: &FaultChanges,
    progress: &mut dyn FnMut(&str, usize, usize),
) -> Result<FeatureReport, FeatureReportError> {
    let n = inputs.names.len();
    if inputs.rows.is_empty() {
        return Err(FeatureReportError::Input(
            "the dataset has no frames".into(),
        ));
    }
    if n == 0 {
        return Err(FeatureReportError::Input("no features to report on".into()));
    }
    if let Some(i) = inputs.rows.iter().position(|r| r.len() != n) {
        return Err(FeatureReportError::Input(format!(
            "frame {i} has {} feature values for {n} features",
            inputs.rows[i].len()
        )));
    }
    if inputs.poses.is_some_and(|p| p.len() != inputs.rows.len()) {
        return Err(FeatureReportError::Input(
            "the poses and the feature rows differ in number".into(),
        ));
    }
    let mut notes = Vec::new();
    let mut features = truth_free::entries(inputs.names, inputs.rows);
    let correlation = truth_free::correlation(inputs.rows, n);
    truth_free::most_correlated(&mut features, &correlation);
    for (entry, per_fault) in features.iter_mut().zip(&changes.per_feature) {
        entry.fault_changes = per_fault.clone();
    }
    let mut report = FeatureReport {
        frames: inputs.rows.len(),
        ground_truth: inputs.poses.is_some(),
        split: "none (no ground truth)".into(),
        fault_frames: changes.frames,
        faults: changes.faults.clone(),
        method_errors: BTreeMap::new(),
        limit_rms: None,
        grid: None,
        features,
        correlation,
        notes: Vec::new(),
    };
    if let Some(poses) = inputs.poses {
        let split = information::Split::new(inputs, poses)?;
        report.split = split.describe();
        progress("feature maps", 0, 1);
        information::fill(&mut report, inputs, &split, options.grid, &mut notes);
        information::neighbours(&mut report.features, poses, inputs.rows, &mut notes);
        ablation::fill(
            &mut report,
            inputs.names,
            &split,
            &options.methods,
            progress,
        )?;
    } else {
        notes.push(
            "no ground truth: no noise σ, information, neighbour separation or ablation".into(),
        );
    }
    // Notes of the measurements first, then the ablation's.
    report.notes.splice(0..0, notes);
    Ok(report)
}
