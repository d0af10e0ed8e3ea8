//! PNG plots drawn offline with plotters and an embedded DejaVu font.

use std::path::Path;
use std::sync::Once;

use plotters::coord::types::RangedCoordf64;
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::{register_font, FontStyle};

use super::ReportError;

pub(crate) const FONT: &str = "sans-serif";
const SIZE: (u32, u32) = (900, 760);
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

type Root<'a> = DrawingArea<BitMapBackend<'a>, Shift>;
type Chart<'a> = ChartContext<'a, BitMapBackend<'a>, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

/// Draws on a white in-memory canvas with `paint`, then writes the PNG to `path` atomically (a
/// kill leaves the old plot or none, never half a file).
fn draw(
    path: &Path,
    paint: impl FnOnce(&Root<'_>) -> Result<(), ReportError>,
) -> Result<(), ReportError> {
    let mut pixels = vec![0u8; SIZE.0 as usize * SIZE.1 as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut pixels, SIZE).into_drawing_area();
        root.fill(&WHITE).map_err(|e| plot_error(path, e))?;
        paint(&root)?;
    }
    let image = image::RgbImage::from_raw(SIZE.0, SIZE.1, pixels)
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

/// Axes over the given ranges with a title, in the common style.
fn axes<'a>(
    root: &Root<'a>,
    path: &Path,
    title: &str,
    x: (f64, f64),
    y: (f64, f64),
) -> Result<Chart<'a>, ReportError> {
    ChartBuilder::on(root)
        .caption(title, (FONT, 24))
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(60)
        .build_cartesian_2d(x.0..x.1, y.0..y.1)
        .map_err(|e| plot_error(path, e))
}

/// Draws the legend box (upper right) and writes the file.
fn finish(root: &Root<'_>, mut chart: Chart<'_>, path: &Path) -> Result<(), ReportError> {
    chart
        .configure_series_labels()
        .label_font((FONT, 15))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .position(SeriesLabelPosition::UpperRight)
        .draw()
        .map_err(|e| plot_error(path, e))?;
    root.present().map_err(|e| plot_error(path, e))
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

/// True (grey) against estimated (black) positions, like the paper's Figure 2; the sample poses,
/// when given, are drawn as faint crosses.
pub fn plot_trajectory(
    path: &Path,
    title: &str,
    truth: &[[f64; 2]],
    estimate: &[Option<[f64; 2]>],
    samples: Option<&[[f64; 2]]>,
) -> Result<(), ReportError> {
    ensure_font();
    let estimated: Vec<[f64; 2]> = estimate.iter().flatten().copied().collect();
    let all = || {
        truth
            .iter()
            .chain(&estimated)
            .chain(samples.unwrap_or(&[]).iter())
    };
    let (Some(x_range), Some(y_range)) = (
        padded_range(all().map(|p| p[0])),
        padded_range(all().map(|p| p[1])),
    ) else {
        return Err(ReportError::Empty {
            path: path.display().to_string(),
            what: "no finite positions".into(),
        });
    };
    draw(path, |root| {
        let mut chart = axes(root, path, title, x_range, y_range)?;
        chart
            .configure_mesh()
            .x_desc("x (mm)")
            .y_desc("y (mm)")
            .label_style((FONT, 15))
            .axis_desc_style((FONT, 17))
            .draw()
            .map_err(|e| plot_error(path, e))?;
        let light = RGBColor(200, 200, 230);
        let grey = RGBColor(150, 150, 150);
        if let Some(samples) = samples {
            chart
                .draw_series(
                    samples
                        .iter()
                        .map(|p| Cross::new((p[0], p[1]), 3, light.stroke_width(1))),
                )
                .map_err(|e| plot_error(path, e))?
                .label("sample poses")
                .legend(move |(x, y)| Cross::new((x + 10, y), 3, light.stroke_width(1)));
        }
        chart
            .draw_series(LineSeries::new(
                truth.iter().map(|p| (p[0], p[1])),
                grey.stroke_width(2),
            ))
            .map_err(|e| plot_error(path, e))?
            .label("true position")
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 20, y)], grey.stroke_width(2)));
        chart
            .draw_series(
                estimated
                    .iter()
                    .map(|p| Circle::new((p[0], p[1]), 2, BLACK.filled())),
            )
            .map_err(|e| plot_error(path, e))?
            .label("estimate")
            .legend(|(x, y)| Circle::new((x + 10, y), 3, BLACK.filled()));
        finish(root, chart, path)
    })
}

/// A named line of (x, y) points for [`plot_series`].
#[derive(Debug, Clone)]
pub struct PlotSeries {
    /// Legend label.
    pub name: String,
    /// The points, in drawing order.
    pub points: Vec<(f64, f64)>,
}

/// Lines with point markers, one per series, with a legend.
pub fn plot_series(
    path: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[PlotSeries],
) -> Result<(), ReportError> {
    ensure_font();
    let points = || series.iter().flat_map(|s| s.points.iter());
    let (Some(x_range), Some(y_range)) = (
        padded_range(points().map(|p| p.0)),
        padded_range(points().map(|p| p.1).chain([0.0])),
    ) else {
        return Err(ReportError::Empty {
            path: path.display().to_string(),
            what: "no finite points".into(),
        });
    };
    draw(path, |root| {
        let mut chart = axes(root, path, title, x_range, y_range)?;
        chart
            .configure_mesh()
            .x_desc(x_label)
            .y_desc(y_label)
            .label_style((FONT, 15))
            .axis_desc_style((FONT, 17))
            .draw()
            .map_err(|e| plot_error(path, e))?;
        for (i, line) in series.iter().enumerate() {
            let colour = Palette99::pick(i).to_rgba();
            chart
                .draw_series(LineSeries::new(
                    line.points.iter().copied(),
                    colour.stroke_width(2),
                ))
                .map_err(|e| plot_error(path, e))?
                .label(line.name.clone())
                .legend(move |(x, y)| {
                    PathElement::new([(x, y), (x + 20, y)], colour.stroke_width(2))
                });
            chart
                .draw_series(
                    line.points
                        .iter()
                        .map(|&p| Circle::new(p, 4, colour.filled())),
                )
                .map_err(|e| plot_error(path, e))?;
        }
        finish(root, chart, path)
    })
}

/// One method's bars: a value per variant (`None` where it has none).
#[derive(Debug, Clone, PartialEq)]
pub struct BarSeries {
    /// Legend entry (the method).
    pub name: String,
    /// One value per variant.
    pub values: Vec<Option<f64>>,
}

/// Mean error per variant as groups of bars, one bar per series (method), on a logarithmic
/// scale so that errors of 0.01 mm and 5 mm show side by side; `reference` values (e.g. the
/// paper's figures), when given, are drawn as red markers over the first series.
pub fn plot_errors_by_variant(
    path: &Path,
    title: &str,
    labels: &[String],
    series: &[BarSeries],
    reference: Option<&[Option<f64>]>,
) -> Result<(), ReportError> {
    ensure_font();
    let empty = |what: String| ReportError::Empty {
        path: path.display().to_string(),
        what,
    };
    if labels.is_empty() || series.is_empty() {
        return Err(empty("no variant or no series".into()));
    }
    if let Some(s) = series.iter().find(|s| s.values.len() != labels.len()) {
        return Err(empty(format!(
            "series `{}` has {} values for {} labels",
            s.name,
            s.values.len(),
            labels.len()
        )));
    }
    let finite = || {
        series
            .iter()
            .flat_map(|s| s.values.iter().flatten())
            .chain(reference.unwrap_or(&[]).iter().flatten())
            .copied()
            .filter(|v| v.is_finite() && *v > 0.0)
    };
    let (Some(low), Some(high)) = (
        finite().min_by(f64::total_cmp),
        finite().max_by(f64::total_cmp),
    ) else {
        return Err(empty("no positive finite value".into()));
    };
    // Bars rise from half a decade below the smallest value; the axis is in log10 units.
    let floor = low.log10().floor() - 0.5;
    let top = high.log10().ceil().max(floor + 1.0) + 0.2;
    draw(path, |root| {
        let n = labels.len();
        let mut chart = axes(root, path, title, (-0.5, n as f64 - 0.5), (floor, top))?;
        let label_of = |x: &f64| {
            let i = x.round();
            if (x - i).abs() < 1e-6 && i >= 0.0 && (i as usize) < n {
                labels[i as usize].clone()
            } else {
                String::new()
            }
        };
        chart
            .configure_mesh()
            .disable_x_mesh()
            .x_labels(n.max(2) * 2 + 1)
            .x_label_formatter(&label_of)
            // Label whole decades only: 0.01, 0.1, 1, 10.
            .y_label_formatter(&|v: &f64| {
                if (v - v.round()).abs() < 1e-6 {
                    let decade = v.round() as i32;
                    format!("{}", 10f64.powi(decade))
                } else {
                    String::new()
                }
            })
            .y_desc("mean error (mm, log scale)")
            .label_style((FONT, 15))
            .axis_desc_style((FONT, 17))
            .draw()
            .map_err(|e| plot_error(path, e))?;
        let width = 0.8 / series.len() as f64;
        for (k, line) in series.iter().enumerate() {
            let colour = Palette99::pick(k).to_rgba();
            let offset = -0.4 + width * k as f64;
            chart
                .draw_series(line.values.iter().enumerate().filter_map(|(i, v)| {
                    let v = v.filter(|v| v.is_finite() && *v > 0.0)?;
                    let x = i as f64 + offset;
                    Some(Rectangle::new(
                        [(x, floor), (x + width * 0.9, v.log10())],
                        colour.filled(),
                    ))
                }))
                .map_err(|e| plot_error(path, e))?
                .label(line.name.clone())
                .legend(move |(x, y)| {
                    Rectangle::new([(x, y - 5), (x + 15, y + 5)], colour.filled())
                });
        }
        if let Some(reference) = reference {
            let centre = -0.4 + width * 0.45;
            chart
                .draw_series(
                    reference
                        .iter()
                        .enumerate()
                        .filter_map(|(i, r)| {
                            r.filter(|r| *r > 0.0)
                                .map(|r| (i as f64 + centre, r.log10()))
                        })
                        .map(|p| TriangleMarker::new(p, 8, RED.filled())),
                )
                .map_err(|e| plot_error(path, e))?
                .label("paper")
                .legend(|(x, y)| TriangleMarker::new((x + 8, y), 6, RED.filled()));
        }
        finish(root, chart, path)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn trajectory_plot_is_written_as_png() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("track.png");
        let truth: Vec<[f64; 2]> = (0..50)
            .map(|i| {
                let t = i as f64 / 8.0;
                [5.0 * t.cos(), 47.0 + 5.0 * t.sin()]
            })
            .collect();
        let estimate: Vec<Option<[f64; 2]>> = truth
            .iter()
            .enumerate()
            .map(|(i, p)| (i % 7 != 0).then_some([p[0] + 0.3, p[1] - 0.2]))
            .collect();
        plot_trajectory(&path, "test", &truth, &estimate, Some(&truth[..5])).unwrap();
        let image = image::open(&path).unwrap();
        assert_eq!((image.width(), image.height()), SIZE);
    }

    #[test]
    fn empty_inputs_are_errors_not_panics() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("none.png");
        assert!(matches!(
            plot_trajectory(&path, "t", &[], &[None], None),
            Err(ReportError::Empty { .. })
        ));
        assert!(plot_errors_by_variant(&path, "t", &[], &[], None).is_err());
        let short = BarSeries {
            name: "m".into(),
            values: vec![Some(1.0)],
        };
        let two = ["a".to_string(), "b".to_string()];
        assert!(plot_errors_by_variant(&path, "t", &two, &[short], None).is_err());
        assert!(plot_series(&path, "t", "x", "y", &[]).is_err());
    }

    #[test]
    fn bar_and_line_plots_are_written() {
        let dir = tempfile::tempdir().unwrap();
        let bars = dir.path().join("bars.png");
        let labels = vec!["a".to_string(), "b".to_string()];
        plot_errors_by_variant(
            &bars,
            "t",
            &labels,
            &[
                BarSeries {
                    name: "evidential".into(),
                    values: vec![Some(1.0), Some(2.0)],
                },
                BarSeries {
                    name: "gp".into(),
                    values: vec![Some(0.01), None],
                },
            ],
            Some(&[Some(2.3), None]),
        )
        .unwrap();
        assert!(image::open(&bars).is_ok());
        let lines = dir.path().join("lines.png");
        let series = [PlotSeries {
            name: "f".into(),
            points: vec![(2.0, 1.5), (3.0, 1.2), (4.0, 1.1)],
        }];
        plot_series(&lines, "t", "states", "error", &series).unwrap();
        assert!(image::open(&lines).is_ok());
    }
}
