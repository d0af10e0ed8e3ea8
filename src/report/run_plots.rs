//! The plots of a run: per test motion, each method's track and every method's errors over
//! time; over the run, risk–coverage and (with faults) detection ROC curves.

use std::path::{Path, PathBuf};

use super::auc::roc_curve;
use super::plot::{plot_errors_over_time, plot_series, plot_trajectory, PlotSeries, TrackPlot};
use super::{FrameRecord, ReportError, RunOutput, CURVE_POINTS};

/// A plot written and what it shows (its caption in `report.html`).
#[derive(Debug, Clone)]
pub struct Written {
    /// The file.
    pub path: PathBuf,
    /// One line on what it shows.
    pub caption: String,
}

/// The file name part of a motion label (`test0:circle` → `test0-circle`).
fn motion_file(label: &str) -> String {
    label.replace(':', "-")
}

/// Writes every plot of `output` into `dir`; returns them in the order the report shows them.
pub(super) fn write_run_plots(dir: &Path, output: &RunOutput) -> Result<Vec<Written>, ReportError> {
    let mut written = Vec::new();
    let scenario = &output.summary.scenario;
    let motions: Vec<&String> = (output.summary.methods.first()).map_or(Vec::new(), |m| {
        m.per_motion.iter().map(|(l, _)| l).collect()
    });
    for label in &motions {
        let frames: Vec<&FrameRecord> = (output.records.iter())
            .filter(|r| &&r.motion == label)
            .collect();
        let path = dir.join(format!("errors-{}.png", motion_file(label)));
        let caption = format!(
            "each method's error over {label} (log scale); red: a fault struck, grey: a method \
             lost the frame, ×: abstained"
        );
        match plot_errors_over_time(
            &path,
            &format!("{scenario} — {label}: error over time"),
            &frames,
        ) {
            Ok(()) => written.push(Written { path, caption }),
            // No method has a positive error on this motion: nothing to draw.
            Err(ReportError::Empty { .. }) => {}
            Err(e) => return Err(e),
        }
    }
    for summary in &output.summary.methods {
        let method = summary.method.as_str();
        let suffix = match method {
            "evidential" => String::new(),
            other => format!("-{other}"),
        };
        for (label, stats) in &summary.per_motion {
            let frames: Vec<&FrameRecord> = (output.records.iter())
                .filter(|r| &r.motion == label && r.method == method)
                .collect();
            let path = dir.join(format!("track-{}{suffix}.png", motion_file(label)));
            let title = match stats {
                Some(s) => format!(
                    "{scenario} — {label}, {method}: mean error {:.3} mm",
                    s.mean
                ),
                None => format!("{scenario} — {label}, {method}: no estimate"),
            };
            let plot = TrackPlot {
                method,
                samples: Some(&output.samples),
                workspace: output.workspace,
            };
            plot_trajectory(&path, &title, &frames, &plot)?;
            written.push(Written {
                path,
                caption: format!(
                    "{method} on {label}: true path, estimates linked to their truth, regions"
                ),
            });
        }
    }
    // Curves divided by the method's mean error: methods whose errors differ a hundredfold
    // share one axis, and below 1 means its surest frames are its better ones.
    let curves: Vec<PlotSeries> = (output.summary.methods.iter())
        .filter_map(|m| {
            let rc = &m.confidence.as_ref()?.all;
            let full = *rc.curve.last()?;
            (full > 0.0).then(|| {
                let points = (rc.curve.iter().enumerate())
                    .map(|(i, r)| (100.0 * (i + 1) as f64 / CURVE_POINTS as f64, r / full))
                    .collect();
                PlotSeries::of(&m.method, points)
            })
        })
        .collect();
    if !curves.is_empty() {
        let path = dir.join("risk-coverage.png");
        let title = format!("{scenario} — mean error of the surest frames, over the method's mean");
        plot_series(&path, &title, "coverage (%)", "risk / mean error", &curves)?;
        written.push(Written {
            path,
            caption: "risk–coverage: below 1, a method's surest frames are its better ones".into(),
        });
    }
    let mut rocs: Vec<PlotSeries> = (output.summary.methods.iter())
        .filter_map(|m| {
            let own: Vec<FrameRecord> = (output.records.iter())
                .filter(|r| r.method == m.method)
                .cloned()
                .collect();
            Some(PlotSeries::of(&m.method, roc_curve(&own)?))
        })
        .collect();
    if !rocs.is_empty() {
        rocs.push(PlotSeries {
            name: "chance".into(),
            colour: Some([170, 170, 170]),
            points: vec![(0.0, 0.0), (1.0, 1.0)],
            ..PlotSeries::default()
        });
        let path = dir.join("roc.png");
        let title = format!("{scenario} — detection of the frames faults struck (ROC)");
        plot_series(
            &path,
            &title,
            "false positive rate (clean frames flagged)",
            "true positive rate (struck frames flagged)",
            &rocs,
        )?;
        written.push(Written {
            path,
            caption: "detection ROC: each method's detection score against \"a fault struck\""
                .into(),
        });
    }
    Ok(written)
}
