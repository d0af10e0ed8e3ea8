//! PNG plots drawn offline with plotters and an embedded DejaVu font: a run's tracks, errors over
//! time, risk–coverage and ROC curves; a sweep's errors per variant and against a setting. Every
//! method has one colour in every plot ([`method_colour`]).

mod bars;
mod colours;
mod lines;
mod time;
mod track;

#[cfg(test)]
mod tests;

use std::path::Path;
use std::sync::Once;

use plotters::coord::types::RangedCoordf64;
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::{register_font, FontStyle};

use super::ReportError;

pub use bars::{plot_errors_by_variant, BarSeries};
pub use colours::{method_colour, FAULT_MARK, FAULT_SHADE, INTERVAL, LOST_SHADE, PAPER, WORKSPACE};
pub use lines::{plot_series, PlotSeries};
pub use time::plot_errors_over_time;
pub use track::{plot_trajectory, TrackPlot};

pub(crate) const FONT: &str = "sans-serif";
/// The size of most plots; the bars grow with the number of variants.
const SIZE: (u32, u32) = (1000, 760);
/// Width of the legend column right of a chart: the legend never covers the data.
const LEGEND_WIDTH: u32 = 230;
static REGISTER_FONT: Once = Once::new();

/// plotters renders text only through registered fonts when system fonts are off.
pub(crate) fn ensure_font() {
    REGISTER_FONT.call_once(|| {
        // The embedded font is a valid TTF, so registration cannot fail in practice; if it did,
        // drawing text would report the error through `ReportError::Plot`.
        let _ = register_font(FONT, FontStyle::Normal, dejavu::sans::regular());
    });
}

fn plot_error(path: &Path, error: impl std::fmt::Display) -> ReportError {
    ReportError::Plot {
        path: path.display().to_string(),
        message: error.to_string(),
    }
}

fn empty(path: &Path, what: impl Into<String>) -> ReportError {
    ReportError::Empty {
        path: path.display().to_string(),
        what: what.into(),
    }
}

type Root<'a> = DrawingArea<BitMapBackend<'a>, Shift>;
type Chart<'a> = ChartContext<'a, BitMapBackend<'a>, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

/// Draws on a white in-memory canvas of `size` with `paint`, then writes the PNG to `path`
/// atomically (a kill leaves the old plot or none, never half a file).
fn draw(
    path: &Path,
    size: (u32, u32),
    paint: impl FnOnce(&Root<'_>) -> Result<(), ReportError>,
) -> Result<(), ReportError> {
    ensure_font();
    let mut pixels = vec![0u8; size.0 as usize * size.1 as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut pixels, size).into_drawing_area();
        root.fill(&WHITE).map_err(|e| plot_error(path, e))?;
        paint(&root)?;
        root.present().map_err(|e| plot_error(path, e))?;
    }
    let image = image::RgbImage::from_raw(size.0, size.1, pixels)
        .ok_or_else(|| plot_error(path, "the canvas has the wrong size"))?;
    let mut png = Vec::new();
    image
        .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .map_err(|e| plot_error(path, e))?;
    crate::atomic::write(path, &png).map_err(|e| ReportError::Write {
        path: path.display().to_string(),
        source: e.into(),
    })
}

/// The title across the top, then the chart's area and the legend's column right of it.
fn split<'a>(
    root: &Root<'a>,
    path: &Path,
    title: &str,
) -> Result<(Root<'a>, Root<'a>), ReportError> {
    let body = root
        .titled(title, (FONT, 22))
        .map_err(|e| plot_error(path, e))?;
    let width = body.dim_in_pixel().0;
    Ok(body.split_horizontally(width.saturating_sub(LEGEND_WIDTH)))
}

/// Margin and label areas of every chart (pixels): [`track`] needs them to make the axes equal.
const MARGIN: u32 = 15;
const X_LABEL_AREA: u32 = 45;
const Y_LABEL_AREA: u32 = 70;

/// Axes over the given ranges, in the common style, without a caption (the title is the root's).
fn axes<'a>(
    area: &Root<'a>,
    path: &Path,
    x: (f64, f64),
    y: (f64, f64),
) -> Result<Chart<'a>, ReportError> {
    ChartBuilder::on(area)
        .margin(MARGIN)
        .x_label_area_size(X_LABEL_AREA)
        .y_label_area_size(Y_LABEL_AREA)
        .build_cartesian_2d(x.0..x.1, y.0..y.1)
        .map_err(|e| plot_error(path, e))
}

/// How a legend entry is drawn.
#[derive(Debug, Clone, Copy)]
enum Mark {
    Line(RGBColor),
    Dot(RGBColor),
    Cross(RGBColor),
    Block(RGBColor),
    Ring(RGBColor),
}

/// The legend in its own column: one entry per line, never over the data.
fn legend(area: &Root<'_>, path: &Path, entries: &[(String, Mark)]) -> Result<(), ReportError> {
    let style = (FONT, 15).into_font().color(&BLACK);
    for (i, (label, mark)) in entries.iter().enumerate() {
        let y = 40 + 24 * i as i32;
        let (x0, x1) = (8, 30);
        let drawn = match *mark {
            Mark::Line(c) => area.draw(&PathElement::new([(x0, y), (x1, y)], c.stroke_width(3))),
            Mark::Dot(c) => area.draw(&Circle::new((19, y), 4, c.filled())),
            Mark::Cross(c) => area.draw(&Cross::new((19, y), 5, c.stroke_width(2))),
            Mark::Block(c) => area.draw(&Rectangle::new([(x0, y - 7), (x1, y + 7)], c.filled())),
            Mark::Ring(c) => area.draw(&Circle::new((19, y), 6, c.stroke_width(2))),
        };
        drawn.map_err(|e| plot_error(path, e))?;
        let text = abbreviate(label, 26);
        area.draw(&Text::new(text, (38, y - 8), style.clone()))
            .map_err(|e| plot_error(path, e))?;
    }
    Ok(())
}

/// `text` cut to `max` characters with an ellipsis in the middle, so that both a long variant
/// name's start and its distinguishing end stay readable.
pub(crate) fn abbreviate(text: &str, max: usize) -> String {
    let chars: Vec<char> = text.chars().collect();
    if chars.len() <= max || max < 5 {
        return text.to_string();
    }
    let head = (max - 1) / 2;
    let tail = max - 1 - head;
    let mut out: String = chars[..head].iter().collect();
    out.push('…');
    out.extend(&chars[chars.len() - tail..]);
    out
}

/// Range covering `values` with a 5% margin (and a unit range when all are equal).
fn padded_range(values: impl Iterator<Item = f64>) -> Option<(f64, f64)> {
    let (lo, hi) = values
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
            (lo.min(v), hi.max(v))
        });
    if !lo.is_finite() {
        return None;
    }
    let pad = if hi > lo { 0.05 * (hi - lo) } else { 0.5 };
    Some((lo - pad, hi + pad))
}

/// Labels whole decades of a log10 axis only: 0.01, 0.1, 1, 10.
fn decade_label(v: &f64) -> String {
    if (v - v.round()).abs() < 1e-6 {
        format!("{}", 10f64.powi(v.round() as i32))
    } else {
        String::new()
    }
}

/// The log10 axis range of positive `values`: from half a decade below the smallest to a little
/// above the largest whole decade.
fn log_range(values: impl Iterator<Item = f64>) -> Option<(f64, f64)> {
    let positive: Vec<f64> = values.filter(|v| v.is_finite() && *v > 0.0).collect();
    let low = positive.iter().copied().min_by(f64::total_cmp)?;
    let high = positive.iter().copied().max_by(f64::total_cmp)?;
    let floor = low.log10().floor() - 0.5;
    let top = high.log10().ceil().max(floor + 1.0) + 0.2;
    Some((floor, top))
}
