//! A sweep's mean error per variant and method: horizontal bars, so that 25 variants' names stay
//! readable.

use std::path::Path;

use plotters::prelude::*;

use super::colours::{method_colour, INTERVAL, PAPER};
use super::{abbreviate, decade_label, empty, legend, log_range, plot_error, Mark, ReportError};

/// One method's bars: a value per variant (`None` where it has none).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct BarSeries {
    /// The method (legend entry and colour).
    pub name: String,
    /// One value per variant.
    pub values: Vec<Option<f64>>,
    /// Half the width of each value's 95 % interval across seeds (empty: none).
    pub half_widths: Vec<Option<f64>>,
}

/// Longest variant name drawn whole.
const LABEL_CHARS: usize = 34;

/// Mean error per variant as groups of horizontal bars, one per method in its colour, on a
/// logarithmic scale so that errors of 0.01 mm and 5 mm show side by side; across-seed intervals
/// as whiskers; `reference` values (the paper's figures), when given, as black ticks across the
/// variant's row. The canvas grows with the number of variants.
pub fn plot_errors_by_variant(
    path: &Path,
    title: &str,
    labels: &[String],
    series: &[BarSeries],
    reference: Option<&[Option<f64>]>,
) -> Result<(), ReportError> {
    if labels.is_empty() || series.is_empty() {
        return Err(empty(path, "no variant or no series"));
    }
    if let Some(s) = series.iter().find(|s| s.values.len() != labels.len()) {
        return Err(empty(
            path,
            format!(
                "series `{}` has {} values for {} labels",
                s.name,
                s.values.len(),
                labels.len()
            ),
        ));
    }
    let upper = series.iter().flat_map(|s| {
        (s.values.iter().enumerate()).filter_map(|(i, v)| {
            let h = s.half_widths.get(i).copied().flatten().unwrap_or(0.0);
            v.map(|v| v + h)
        })
    });
    let values = series
        .iter()
        .flat_map(|s| s.values.iter().flatten().copied());
    let references = reference.unwrap_or(&[]).iter().flatten().copied();
    let Some((floor, top)) = log_range(values.chain(upper).chain(references)) else {
        return Err(empty(path, "no positive finite value"));
    };
    let (n, m) = (labels.len(), series.len());
    let row = (12 * m as u32 + 12).max(30);
    let size = (super::SIZE.0, (140 + row * n as u32).max(480));
    let short: Vec<String> = labels.iter().map(|l| abbreviate(l, LABEL_CHARS)).collect();
    let widest = short.iter().map(|l| l.chars().count()).max().unwrap_or(1) as u32;
    super::draw(path, size, |root| {
        let (area, legend_area) = super::split(root, path, title)?;
        let mut chart = ChartBuilder::on(&area)
            .margin(super::MARGIN)
            .x_label_area_size(super::X_LABEL_AREA)
            .y_label_area_size((widest * 8 + 16).min(320))
            .build_cartesian_2d(floor..top, -0.5..n as f64 - 0.5)
            .map_err(|e| plot_error(path, e))?;
        // The first variant on top.
        let row_of = |i: usize| (n - 1 - i) as f64;
        let label_of = |y: &f64| {
            let r = y.round();
            if (y - r).abs() < 1e-6 && r >= 0.0 && (r as usize) < n {
                short[n - 1 - r as usize].clone()
            } else {
                String::new()
            }
        };
        chart
            .configure_mesh()
            .disable_y_mesh()
            .y_labels(2 * n + 1)
            .y_label_formatter(&label_of)
            .x_label_formatter(&decade_label)
            .x_desc("mean error (mm, log scale)")
            .label_style((super::FONT, 14))
            .axis_desc_style((super::FONT, 17))
            .draw()
            .map_err(|e| plot_error(path, e))?;
        let height = 0.8 / m as f64;
        let mut entries = Vec::new();
        for (k, line) in series.iter().enumerate() {
            let colour = method_colour(&line.name);
            let band = |i: usize| {
                let y_top = row_of(i) + 0.4 - height * k as f64;
                (y_top - 0.9 * height, y_top)
            };
            let bars = (line.values.iter().enumerate()).filter_map(|(i, v)| {
                let v = v.filter(|v| v.is_finite() && *v > 0.0)?;
                let (y0, y1) = band(i);
                Some(Rectangle::new(
                    [(floor, y0), (v.log10(), y1)],
                    colour.filled(),
                ))
            });
            chart.draw_series(bars).map_err(|e| plot_error(path, e))?;
            let whiskers = (line.values.iter().enumerate()).filter_map(|(i, v)| {
                let (v, h) = ((*v)?, line.half_widths.get(i).copied().flatten()?);
                let (y0, y1) = band(i);
                let y = 0.5 * (y0 + y1);
                let lo = (v - h).max(10f64.powf(floor)).log10();
                let hi = (v + h).log10();
                (h.is_finite() && v > 0.0).then(|| {
                    [
                        vec![(lo, y), (hi, y)],
                        vec![(lo, y0), (lo, y1)],
                        vec![(hi, y0), (hi, y1)],
                    ]
                })
            });
            let segments = whiskers
                .flatten()
                .map(|s| PathElement::new(s, INTERVAL.stroke_width(2)));
            chart
                .draw_series(segments)
                .map_err(|e| plot_error(path, e))?;
            entries.push((line.name.clone(), Mark::Block(colour)));
        }
        if series
            .iter()
            .any(|s| s.half_widths.iter().any(Option::is_some))
        {
            entries.push(("95 % interval (seeds)".into(), Mark::Line(INTERVAL)));
        }
        if let Some(reference) = reference {
            let ticks = (reference.iter().enumerate()).filter_map(|(i, r)| {
                let x = r.filter(|r| *r > 0.0)?.log10();
                let y = row_of(i);
                Some(PathElement::new(
                    [(x, y - 0.45), (x, y + 0.45)],
                    PAPER.stroke_width(4),
                ))
            });
            chart.draw_series(ticks).map_err(|e| plot_error(path, e))?;
            entries.push(("paper (black tick)".into(), Mark::Line(PAPER)));
        }
        legend(&legend_area, path, &entries)
    })
}
