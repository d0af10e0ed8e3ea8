//! Reporting: error statistics, per-frame records and run summaries, the files of a run,
//! plain-text tables, PNG plots and `report.html`.

mod auc;
mod confidence;
mod files;
pub mod finite;
mod finite_json;
pub mod html;
mod limit;
mod pages;
pub(crate) mod plot;
mod reach;
mod records;
mod run_plots;
mod seeds;
mod sweep_plots;
mod table;
pub mod tables;

pub use auc::{detection_auc, roc_curve};
pub use confidence::{
    ConfidenceSummary, RegionSummary, RenderCheckSummary, RiskCoverage, CURVE_POINTS,
};
pub use files::{
    model_file_name, write_run, RunOutput, PRODUCER_FILE, REPORT_FILE, RESULTS_FILE, SCENARIO_FILE,
};
pub use finite_json::check_json_numbers;
pub use limit::{efficiency, LimitNoise, LimitSummary};
pub use pages::{run_page, sweep_page, SweepPage};
pub use plot::{
    method_colour, plot_errors_by_variant, plot_errors_over_time, plot_series, plot_trajectory,
    BarSeries, PlotSeries, TrackPlot, FAULT_MARK, FAULT_SHADE, INTERVAL, LOST_SHADE, PAPER,
    WORKSPACE,
};
pub use reach::{CalibrationReach, MethodReach, REACH_MM};
pub use records::{
    write_frames_csv, EvidentialSummary, FaultSummary, FrameRecord, MethodSummary, MethodTimings,
    RunSummary, Timings,
};
pub use seeds::{AcrossSeeds, Claim, Comparison, Finding, Interval, SeedReport, Side, Verdict};
pub use sweep_plots::{write_sweep_plots, SweepPlots};
pub use table::Table;

use serde::{Deserialize, Serialize};

/// Failures while writing reports.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ReportError {
    /// A plot could not be drawn or written.
    #[error("could not draw plot {path}: {message}")]
    Plot {
        /// The file being written.
        path: String,
        /// What the plotting library said.
        message: String,
    },
    /// A file of a run could not be written.
    #[error("writing {path}: {source}")]
    Write {
        /// The file.
        path: String,
        /// Why.
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    /// A number no output file may hold (NaN, or an infinity the README does not document).
    #[error("{what} is {value}, which no output file may hold (a bug: please report it)")]
    NonFinite {
        /// Which number, where.
        what: String,
        /// The number.
        value: f64,
    },
    /// A CSV file could not be written.
    #[error("writing CSV: {0}")]
    Csv(#[from] csv::Error),
    /// There is nothing to plot.
    #[error("nothing to plot in {path}: {what}")]
    Empty {
        /// The file that was not written.
        path: String,
        /// What was missing.
        what: String,
    },
}

/// Summary statistics of a set of estimation errors, in mm.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ErrorStats {
    /// Number of errors summarised (frames with an estimate and a ground truth).
    pub count: usize,
    /// Mean error.
    pub mean: f64,
    /// Median error.
    pub median: f64,
    /// Root-mean-square error.
    pub rms: f64,
    /// Largest error.
    pub max: f64,
}

impl ErrorStats {
    /// Summarises the finite values of `errors`; `None` when there are none.
    pub fn from_errors(errors: &[f64]) -> Option<Self> {
        let mut finite: Vec<f64> = errors.iter().copied().filter(|e| e.is_finite()).collect();
        if finite.is_empty() {
            return None;
        }
        finite.sort_by(f64::total_cmp);
        let count = finite.len();
        let mean = finite.iter().sum::<f64>() / count as f64;
        let rms = (finite.iter().map(|e| e * e).sum::<f64>() / count as f64).sqrt();
        let median = if count % 2 == 1 {
            finite[count / 2]
        } else {
            0.5 * (finite[count / 2 - 1] + finite[count / 2])
        };
        Some(Self {
            count,
            mean,
            median,
            rms,
            max: finite[count - 1],
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stats_of_known_errors() {
        let stats = ErrorStats::from_errors(&[3.0, 1.0, 2.0, 4.0, f64::NAN]).unwrap();
        assert_eq!(stats.count, 4);
        assert!((stats.mean - 2.5).abs() < 1e-12);
        assert!((stats.median - 2.5).abs() < 1e-12);
        assert!((stats.rms - (30.0f64 / 4.0).sqrt()).abs() < 1e-12);
        assert_eq!(stats.max, 4.0);
        assert!(ErrorStats::from_errors(&[f64::NAN]).is_none());
        assert!(ErrorStats::from_errors(&[]).is_none());
    }
}
