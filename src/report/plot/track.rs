//! A test motion as one method tracked it: truth against estimates on equal axes, like the
//! paper's Figure 2, with what a reader needs to judge it.

use std::path::Path;

use plotters::prelude::*;

use super::colours::{method_colour, FAULT_MARK, WORKSPACE};
use super::{axes, empty, legend, padded_range, plot_error, split, Mark, ReportError};
use super::{MARGIN, SIZE, X_LABEL_AREA, Y_LABEL_AREA};
use crate::planar::Rect;
use crate::report::FrameRecord;

/// Regions drawn per plot at most.
const MAX_REGIONS: usize = 40;

/// What a track plot shows besides the frames.
#[derive(Debug, Clone, Copy)]
pub struct TrackPlot<'a> {
    /// The method (its colour).
    pub method: &'a str,
    /// The sample poses the method was trained on (faint crosses).
    pub samples: Option<&'a [[f64; 2]]>,
    /// The workspace, outlined.
    pub workspace: Option<Rect>,
}

/// The frames of one motion and method (in time order): the true path (grey), each estimate
/// linked to its truth, calibrated regions (of at most 40 frames spread evenly)
/// drawn as circles of their area, struck frames
/// ringed in red and abstentions crossed; the axes have equal scales and the legend its own
/// column.
pub fn plot_trajectory(
    path: &Path,
    title: &str,
    frames: &[&FrameRecord],
    plot: &TrackPlot<'_>,
) -> Result<(), ReportError> {
    let truth: Vec<[f64; 2]> = frames.iter().filter_map(|r| r.truth).collect();
    let estimated: Vec<[f64; 2]> = frames.iter().filter_map(|r| r.estimate).collect();
    let corners: Vec<[f64; 2]> = plot
        .workspace
        .map_or(Vec::new(), |w| vec![[w.x_min, w.y_min], [w.x_max, w.y_max]]);
    let all = || {
        (truth.iter())
            .chain(&estimated)
            .chain(&corners)
            .chain(plot.samples.unwrap_or(&[]))
    };
    let (Some(x), Some(y)) = (
        padded_range(all().map(|p| p[0])),
        padded_range(all().map(|p| p[1])),
    ) else {
        return Err(empty(path, "no finite positions"));
    };
    let colour = method_colour(plot.method);
    let light = RGBColor(200, 200, 230);
    let grey = RGBColor(150, 150, 150);
    super::draw(path, SIZE, |root| {
        let (area, legend_area) = split(root, path, title)?;
        let (w, h) = area.dim_in_pixel();
        let (x, y, mm_per_px) = equal_scales(x, y, (w, h));
        let mut chart = axes(&area, path, x, y)?;
        chart
            .configure_mesh()
            .x_desc("x (mm)")
            .y_desc("y (mm)")
            .label_style((super::FONT, 15))
            .axis_desc_style((super::FONT, 17))
            .draw()
            .map_err(|e| plot_error(path, e))?;
        let mut entries = Vec::new();
        if let Some(samples) = plot.samples {
            chart
                .draw_series(
                    (samples.iter()).map(|p| Cross::new((p[0], p[1]), 3, light.stroke_width(1))),
                )
                .map_err(|e| plot_error(path, e))?;
            entries.push(("sample poses".to_string(), Mark::Cross(light)));
        }
        if let Some(w) = plot.workspace {
            let outline = [
                (w.x_min, w.y_min),
                (w.x_max, w.y_min),
                (w.x_max, w.y_max),
                (w.x_min, w.y_max),
                (w.x_min, w.y_min),
            ];
            chart
                .draw_series([PathElement::new(outline, WORKSPACE.stroke_width(2))])
                .map_err(|e| plot_error(path, e))?;
            entries.push(("workspace".to_string(), Mark::Line(WORKSPACE)));
        }
        // Regions first, faint, so that the paths stay on top; at most about 40 of them, evenly
        // spread, or a long motion's regions cover everything.
        let stride = frames.len().div_ceil(MAX_REGIONS).max(1);
        let regions = frames.iter().step_by(stride).filter_map(|r| {
            let (p, area) = (r.estimate?, r.region_area?);
            let radius = (area / std::f64::consts::PI).sqrt() / mm_per_px;
            (!r.flag_set.abstained && radius.is_finite())
                .then(|| Circle::new((p[0], p[1]), radius.round() as i32, colour.mix(0.25)))
        });
        chart
            .draw_series(regions)
            .map_err(|e| plot_error(path, e))?;
        if frames.iter().any(|r| r.region_area.is_some()) {
            entries.push(("region (equal-area circle)".to_string(), Mark::Ring(colour)));
        }
        let links = frames.iter().filter_map(|r| {
            let (e, t) = (r.estimate?, r.truth?);
            Some(PathElement::new(
                [(e[0], e[1]), (t[0], t[1])],
                colour.mix(0.45).stroke_width(1),
            ))
        });
        chart.draw_series(links).map_err(|e| plot_error(path, e))?;
        chart
            .draw_series(LineSeries::new(
                truth.iter().map(|p| (p[0], p[1])),
                grey.stroke_width(2),
            ))
            .map_err(|e| plot_error(path, e))?;
        entries.push(("true position".to_string(), Mark::Line(grey)));
        entries.push(("estimate → truth".to_string(), Mark::Line(colour)));
        chart
            .draw_series((estimated.iter()).map(|p| Circle::new((p[0], p[1]), 3, colour.filled())))
            .map_err(|e| plot_error(path, e))?;
        entries.push((format!("estimate ({})", plot.method), Mark::Dot(colour)));
        let struck = (frames.iter())
            .filter(|r| r.corrupted())
            .filter_map(|r| r.estimate);
        chart
            .draw_series(struck.map(|p| Circle::new((p[0], p[1]), 6, FAULT_MARK.stroke_width(2))))
            .map_err(|e| plot_error(path, e))?;
        if frames.iter().any(|r| r.corrupted()) {
            entries.push(("fault struck".to_string(), Mark::Ring(FAULT_MARK)));
        }
        let abstained = (frames.iter())
            .filter(|r| r.flag_set.abstained)
            .filter_map(|r| r.estimate);
        chart
            .draw_series(abstained.map(|p| Cross::new((p[0], p[1]), 6, BLACK.stroke_width(2))))
            .map_err(|e| plot_error(path, e))?;
        if frames.iter().any(|r| r.flag_set.abstained) {
            entries.push(("abstained".to_string(), Mark::Cross(BLACK)));
        }
        legend(&legend_area, path, &entries)
    })
}

/// Widens the shorter of the two ranges so that a millimetre is as many pixels along x as along
/// y in a chart area of `size` pixels; returns the ranges and the millimetres per pixel.
fn equal_scales(x: (f64, f64), y: (f64, f64), size: (u32, u32)) -> ((f64, f64), (f64, f64), f64) {
    let width = f64::from(size.0.saturating_sub(2 * MARGIN + Y_LABEL_AREA).max(1));
    let height = f64::from(size.1.saturating_sub(2 * MARGIN + X_LABEL_AREA).max(1));
    let scale = ((x.1 - x.0) / width).max((y.1 - y.0) / height);
    let centred = |r: (f64, f64), pixels: f64| {
        let (mid, half) = (0.5 * (r.0 + r.1), 0.5 * scale * pixels);
        (mid - half, mid + half)
    };
    (centred(x, width), centred(y, height), scale)
}
