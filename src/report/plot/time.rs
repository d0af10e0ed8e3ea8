//! Each method's error over the frames of one test motion.

use std::path::Path;

use plotters::prelude::*;

use super::colours::{method_colour, FAULT_SHADE, LOST_SHADE};
use super::{axes, decade_label, empty, legend, log_range, plot_error, split, Mark, ReportError};
use crate::report::FrameRecord;

/// Errors (log scale) against time, one line per method in its colour, broken where it has no
/// estimate; frames a fault struck shaded red behind them, frames some method lost (no estimate)
/// shaded grey, abstentions crossed. `frames` are one motion's records of every method.
pub fn plot_errors_over_time(
    path: &Path,
    title: &str,
    frames: &[&FrameRecord],
) -> Result<(), ReportError> {
    let mut methods: Vec<&str> = Vec::new();
    for r in frames {
        if !methods.contains(&r.method.as_str()) {
            methods.push(&r.method);
        }
    }
    let (Some(x), Some(y)) = (
        super::padded_range(frames.iter().map(|r| r.t)),
        log_range(frames.iter().filter_map(|r| r.error)),
    ) else {
        return Err(empty(path, "no frame with a positive error"));
    };
    // Each frame shaded over half the step to its neighbours.
    let mut times: Vec<f64> = frames.iter().map(|r| r.t).collect();
    times.sort_by(f64::total_cmp);
    times.dedup();
    let step = (times.windows(2))
        .map(|w| w[1] - w[0])
        .filter(|d| *d > 0.0)
        .min_by(f64::total_cmp)
        .unwrap_or(1.0);
    let shade = |t: f64, colour: RGBColor| {
        Rectangle::new(
            [(t - step / 2.0, y.0), (t + step / 2.0, y.1)],
            colour.filled(),
        )
    };
    let struck: Vec<f64> = times
        .iter()
        .copied()
        .filter(|&t| frames.iter().any(|r| r.t == t && r.corrupted()))
        .collect();
    let lost: Vec<f64> = times
        .iter()
        .copied()
        .filter(|&t| frames.iter().any(|r| r.t == t && r.estimate.is_none()))
        .collect();
    super::draw(path, super::SIZE, |root| {
        let (area, legend_area) = split(root, path, title)?;
        let mut chart = axes(&area, path, x, y)?;
        let mut entries = Vec::new();
        chart
            .draw_series(struck.iter().map(|&t| shade(t, FAULT_SHADE)))
            .map_err(|e| plot_error(path, e))?;
        chart
            .draw_series(lost.iter().map(|&t| shade(t, LOST_SHADE)))
            .map_err(|e| plot_error(path, e))?;
        chart
            .configure_mesh()
            .x_desc("time (s)")
            .y_desc("error (mm, log scale)")
            .y_label_formatter(&decade_label)
            .label_style((super::FONT, 15))
            .axis_desc_style((super::FONT, 17))
            .draw()
            .map_err(|e| plot_error(path, e))?;
        for method in &methods {
            let colour = method_colour(method);
            let own: Vec<&&FrameRecord> = frames.iter().filter(|r| r.method == *method).collect();
            let point = |r: &FrameRecord| Some((r.t, r.error.filter(|e| *e > 0.0)?.log10()));
            // One line per stretch of frames with an error: a lost frame breaks it.
            for stretch in own.split(|r| point(r).is_none()) {
                chart
                    .draw_series(LineSeries::new(
                        stretch.iter().filter_map(|r| point(r)),
                        colour.stroke_width(2),
                    ))
                    .map_err(|e| plot_error(path, e))?;
            }
            let crosses = (own.iter())
                .filter(|r| r.flag_set.abstained)
                .filter_map(|r| point(r))
                .map(|p| Cross::new(p, 5, colour.stroke_width(2)));
            chart
                .draw_series(crosses)
                .map_err(|e| plot_error(path, e))?;
            entries.push((method.to_string(), Mark::Line(colour)));
        }
        if frames.iter().any(|r| r.flag_set.abstained) {
            entries.push(("abstained (×)".to_string(), Mark::Cross(BLACK)));
        }
        if !struck.is_empty() {
            entries.push(("fault struck".to_string(), Mark::Block(FAULT_SHADE)));
        }
        if !lost.is_empty() {
            entries.push(("lost (no estimate)".to_string(), Mark::Block(LOST_SHADE)));
        }
        legend(&legend_area, path, &entries)
    })
}
