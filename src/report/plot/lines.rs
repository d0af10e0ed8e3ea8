//! Lines of points: risk–coverage and ROC curves, error against a swept setting.

use std::path::Path;

use plotters::prelude::*;

use super::colours::{method_colour, INTERVAL};
use super::{axes, empty, legend, padded_range, plot_error, split, Mark, ReportError};

/// A named line of (x, y) points for [`plot_series`].
#[derive(Debug, Clone, Default)]
pub struct PlotSeries {
    /// Legend label.
    pub name: String,
    /// The method whose colour it is drawn in.
    pub method: String,
    /// A colour of its own instead (a reference line), as RGB.
    pub colour: Option<[u8; 3]>,
    /// The points, in drawing order.
    pub points: Vec<(f64, f64)>,
    /// Half the width of each point's interval (across seeds); empty or `None`: no interval.
    pub half_widths: Vec<Option<f64>>,
}

impl PlotSeries {
    /// A line of `method`, labelled with its name.
    pub fn of(method: &str, points: Vec<(f64, f64)>) -> Self {
        Self {
            name: method.to_string(),
            method: method.to_string(),
            points,
            ..Self::default()
        }
    }

    fn colour(&self) -> RGBColor {
        self.colour.map_or_else(
            || method_colour(&self.method),
            |[r, g, b]| RGBColor(r, g, b),
        )
    }
}

/// Lines with point markers, one per series, each method in its colour; intervals as whiskers
/// (their colour [`INTERVAL`]); the legend in its own column.
pub fn plot_series(
    path: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[PlotSeries],
) -> Result<(), ReportError> {
    let points = || series.iter().flat_map(|s| s.points.iter());
    let ends = || {
        series.iter().flat_map(|s| {
            (s.points.iter().zip(&s.half_widths))
                .filter_map(|(p, h)| h.map(|h| [p.1 - h, p.1 + h]))
                .flatten()
        })
    };
    let (Some(x), Some(y)) = (
        padded_range(points().map(|p| p.0)),
        padded_range(points().map(|p| p.1).chain(ends()).chain([0.0])),
    ) else {
        return Err(empty(path, "no finite points"));
    };
    super::draw(path, super::SIZE, |root| {
        let (area, legend_area) = split(root, path, title)?;
        let mut chart = axes(&area, path, x, y)?;
        chart
            .configure_mesh()
            .x_desc(x_label)
            .y_desc(y_label)
            .label_style((super::FONT, 15))
            .axis_desc_style((super::FONT, 17))
            .draw()
            .map_err(|e| plot_error(path, e))?;
        let mut entries = Vec::new();
        let cap = 0.006 * (x.1 - x.0);
        for line in series {
            let colour = line.colour();
            let whiskers = (line.points.iter().zip(&line.half_widths))
                .filter_map(|(&(px, py), h)| Some((px, py, (*h)?)))
                .filter(|(_, _, h)| h.is_finite())
                .flat_map(|(px, py, h)| {
                    [
                        vec![(px, py - h), (px, py + h)],
                        vec![(px - cap, py - h), (px + cap, py - h)],
                        vec![(px - cap, py + h), (px + cap, py + h)],
                    ]
                })
                .map(|segment| PathElement::new(segment, INTERVAL.stroke_width(2)));
            chart
                .draw_series(whiskers)
                .map_err(|e| plot_error(path, e))?;
            chart
                .draw_series(LineSeries::new(
                    line.points.iter().copied(),
                    colour.stroke_width(2),
                ))
                .map_err(|e| plot_error(path, e))?;
            chart
                .draw_series((line.points.iter()).map(|&p| Circle::new(p, 4, colour.filled())))
                .map_err(|e| plot_error(path, e))?;
            entries.push((line.name.clone(), Mark::Line(colour)));
        }
        if series
            .iter()
            .any(|s| s.half_widths.iter().any(Option::is_some))
        {
            entries.push(("95 % interval (seeds)".into(), Mark::Line(INTERVAL)));
        }
        legend(&legend_area, path, &entries)
    })
}
