//! The report's table (stdout), JSON file and plot of each feature's information over the
//! workspace.

use std::path::{Path, PathBuf};

use plotters::prelude::*;

use crate::report::{check_json_numbers, ReportError, Table};

use super::FeatureReport;

/// The JSON file in `--out`.
pub const JSON_FILE: &str = "feature-report.json";
/// The plot in `--out`.
pub const PLOT_FILE: &str = "feature-information.png";

/// One panel of the plot (px).
const PANEL: (u32, u32) = (240, 200);

fn number(value: Option<f64>, digits: usize) -> String {
    value.map_or_else(|| "—".into(), |v| format!("{v:.digits$}"))
}

fn percent(value: Option<f64>) -> String {
    value.map_or_else(|| "—".into(), |v| format!("{:.1}", 100.0 * v))
}

/// The report as a table: one row per feature.
pub fn table(report: &FeatureReport) -> Table {
    let methods: Vec<&String> = report.method_errors.keys().collect();
    let mut header: Vec<String> = [
        "feature",
        "sd",
        "missing %",
        "max |r|",
        "σ",
        "info %",
        "limit +%",
        "nbr Δ/range",
        "nbr Δ/σ",
    ]
    .map(String::from)
    .to_vec();
    header.extend(report.faults.iter().map(|f| format!("{f} %")));
    header.extend(methods.iter().map(|m| format!("−{m} Δmm")));
    let mut table = Table::new(header);
    for e in &report.features {
        let mut row = vec![
            e.name.clone(),
            number(e.sd, 4),
            percent(Some(e.missing_share + e.non_finite_share)),
            number(e.most_correlated.as_ref().map(|(_, r)| r.abs()), 2),
            number(e.sigma, 4),
            percent(e.information_share),
            percent(e.limit_increase),
            number(e.neighbour_max_change, 3),
            number(e.neighbour_median_sigmas, 2),
        ];
        row.extend((report.faults.iter()).map(|f| percent(e.fault_changes.get(f).copied())));
        row.extend((methods.iter()).map(|m| number(e.ablation.get(m.as_str()).copied(), 4)));
        table.push(row);
    }
    table
}

/// Writes [`JSON_FILE`] (every number checked finite) and, when there is an information map,
/// [`PLOT_FILE`] into `dir`; returns the files written.
///
/// # Errors
/// A non-finite number, a file that cannot be written, a plot that cannot be drawn.
pub fn write_outputs(report: &FeatureReport, dir: &Path) -> Result<Vec<PathBuf>, ReportError> {
    check_json_numbers(JSON_FILE, report)?;
    let json = serde_json::to_string_pretty(report).map_err(|e| ReportError::Write {
        path: JSON_FILE.into(),
        source: e.into(),
    })?;
    let path = dir.join(JSON_FILE);
    crate::atomic::write(&path, json.as_bytes()).map_err(|e| ReportError::Write {
        path: path.display().to_string(),
        source: e.into(),
    })?;
    let mut written = vec![path];
    if report.grid.is_some() && report.features.iter().any(|e| e.information_map.is_some()) {
        let path = dir.join(PLOT_FILE);
        plot(report, &path)?;
        written.push(path);
    }
    Ok(written)
}

/// Dark blue (none) to yellow (the largest any feature has).
fn colour(t: f64) -> RGBColor {
    let t = t.clamp(0.0, 1.0);
    let mix = |a: f64, b: f64| (a + (b - a) * t).round() as u8;
    RGBColor(mix(20.0, 250.0), mix(20.0, 230.0), mix(90.0, 40.0))
}

/// One panel per feature: its own information |∇f|²/σ² over the grid, on one colour scale for
/// every panel (the square root of its share of the largest value), so that weak features look
/// dark.
fn plot(report: &FeatureReport, path: &Path) -> Result<(), ReportError> {
    let fail = |e: &dyn std::fmt::Display| ReportError::Plot {
        path: path.display().to_string(),
        message: e.to_string(),
    };
    let Some(grid) = &report.grid else {
        return Ok(());
    };
    crate::report::plot::ensure_font();
    let n = report.features.len();
    let columns = (n as f64).sqrt().ceil().max(1.0) as usize;
    let rows = n.div_ceil(columns);
    let size = (PANEL.0 * columns as u32, PANEL.1 * rows as u32);
    let largest = (report.features.iter())
        .filter_map(|e| e.information_map.as_ref())
        .flatten()
        .copied()
        .fold(0.0, f64::max);
    let step = |axis: &[f64]| {
        if axis.len() > 1 {
            axis[1] - axis[0]
        } else {
            1.0
        }
    };
    let (dx, dy) = (step(&grid.x), step(&grid.y));
    let x_range = grid.x[0] - dx / 2.0..grid.x[grid.x.len() - 1] + dx / 2.0;
    let y_range = grid.y[0] - dy / 2.0..grid.y[grid.y.len() - 1] + dy / 2.0;
    let mut pixels = vec![0u8; size.0 as usize * size.1 as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut pixels, size).into_drawing_area();
        root.fill(&WHITE).map_err(|e| fail(&e))?;
        let panels = root.split_evenly((rows, columns));
        for (entry, panel) in report.features.iter().zip(&panels) {
            let title = format!("{} {}%", entry.name, percent(entry.information_share));
            let mut chart = ChartBuilder::on(panel)
                .caption(title, (crate::report::plot::FONT, 14))
                .margin(6)
                .x_label_area_size(18)
                .y_label_area_size(26)
                .build_cartesian_2d(x_range.clone(), y_range.clone())
                .map_err(|e| fail(&e))?;
            chart
                .configure_mesh()
                .disable_mesh()
                .x_labels(3)
                .y_labels(3)
                .label_style((crate::report::plot::FONT, 10))
                .draw()
                .map_err(|e| fail(&e))?;
            let Some(map) = &entry.information_map else {
                continue;
            };
            let cells = grid
                .y
                .iter()
                .flat_map(|&y| grid.x.iter().map(move |&x| (x, y)));
            chart
                .draw_series(cells.zip(map).map(|((x, y), &v)| {
                    let t = if largest > 0.0 {
                        (v / largest).sqrt()
                    } else {
                        0.0
                    };
                    Rectangle::new(
                        [(x - dx / 2.0, y - dy / 2.0), (x + dx / 2.0, y + dy / 2.0)],
                        colour(t).filled(),
                    )
                }))
                .map_err(|e| fail(&e))?;
        }
        root.present().map_err(|e| fail(&e))?;
    }
    let image = image::RgbImage::from_raw(size.0, size.1, pixels)
        .ok_or_else(|| fail(&"the canvas has the wrong size"))?;
    let mut png = Vec::new();
    image
        .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .map_err(|e| fail(&e))?;
    crate::atomic::write(path, &png).map_err(|e| ReportError::Write {
        path: path.display().to_string(),
        source: e.into(),
    })
}
