//! The plots read back pixel by pixel: what must be there is there.

use super::*;
use crate::estimator::EstimateFlags;
use crate::faults::FrameFaults;
use crate::report::FrameRecord;

type Image = image::RgbImage;

fn read(path: &Path) -> Image {
    image::open(path).unwrap().to_rgb8()
}

fn count(image: &Image, colour: RGBColor) -> usize {
    let want = [colour.0, colour.1, colour.2];
    image.pixels().filter(|p| p.0 == want).count()
}

/// The smallest box holding every pixel of `colour` left of the legend: (x0, y0, x1, y1).
fn bounds(image: &Image, colour: RGBColor) -> (u32, u32, u32, u32) {
    let want = [colour.0, colour.1, colour.2];
    let mut b = (u32::MAX, u32::MAX, 0, 0);
    let chart = image.width() - LEGEND_WIDTH;
    for (x, y, p) in image.enumerate_pixels() {
        if p.0 == want && x < chart {
            b = (b.0.min(x), b.1.min(y), b.2.max(x), b.3.max(y));
        }
    }
    b
}

/// A record of `method` at frame `i` of a circle, its error `error` (no estimate when `None`).
fn record(
    method: &str,
    i: usize,
    error: Option<f64>,
    struck: bool,
    abstained: bool,
) -> FrameRecord {
    let t = i as f64 / 10.0;
    let truth = [4.0 * t.cos(), 47.0 + 4.0 * t.sin()];
    FrameRecord {
        method: method.into(),
        motion: "test0:circle".into(),
        frame: i,
        t,
        truth: Some(truth),
        estimate: error.map(|e| [truth[0] + e, truth[1]]),
        error,
        group: None,
        conflict_level: None,
        uncertainty_radius: None,
        detection_score: None,
        region_area: error.map(|_| 0.5),
        region_covers: None,
        flags: String::new(),
        flag_set: EstimateFlags {
            abstained,
            ..EstimateFlags::default()
        },
        faults: Some(FrameFaults {
            faults: if struck { vec!["stuck".into()] } else { vec![] },
            changed: if struck { vec![0] } else { vec![] },
            dropped: false,
        }),
        limit_mm: None,
    }
}

#[test]
fn errors_over_time_shade_struck_and_lost_frames_in_each_methods_colour() {
    let dir = tempfile::tempdir().unwrap();
    let frames: Vec<FrameRecord> = (0..30)
        .flat_map(|i| {
            let struck = (10..15).contains(&i);
            [
                record(
                    "evidential",
                    i,
                    Some(0.5 + i as f64 / 10.0),
                    struck,
                    i == 12,
                ),
                record("knn", i, (i != 20).then_some(0.2), struck, false),
            ]
        })
        .collect();
    let refs: Vec<&FrameRecord> = frames.iter().collect();
    let path = dir.path().join("errors.png");
    plot_errors_over_time(&path, "t", &refs).unwrap();
    let image = read(&path);
    assert!(count(&image, method_colour("evidential")) > 200);
    assert!(count(&image, method_colour("knn")) > 200);
    let shaded = count(&image, FAULT_SHADE);
    assert!(shaded > 5_000, "struck frames shaded: {shaded} pixels");
    assert!(
        count(&image, LOST_SHADE) > 1_000,
        "the lost frame is shaded"
    );
    // The shading sits where frames 10–14 are: in the left half of a 0–2.9 s axis.
    let (x0, _, x1, _) = bounds(&image, FAULT_SHADE);
    assert!(x1 < image.width() / 2 && x0 > 100, "{x0}..{x1}");
    // Without faults nor lost frames, no shading.
    let clean: Vec<FrameRecord> = (0..30)
        .map(|i| record("knn", i, Some(0.2), false, false))
        .collect();
    let refs: Vec<&FrameRecord> = clean.iter().collect();
    plot_errors_over_time(&path, "t", &refs).unwrap();
    let image = read(&path);
    let at = |colour: RGBColor| -> Vec<(u32, u32)> {
        let want = [colour.0, colour.1, colour.2];
        (image.enumerate_pixels())
            .filter(|(_, _, p)| p.0 == want)
            .map(|(x, y, _)| (x, y))
            .take(12)
            .collect()
    };
    assert_eq!(at(FAULT_SHADE), []);
    assert_eq!(at(LOST_SHADE), []);
}

#[test]
fn track_axes_are_equal_and_the_workspace_is_outlined() {
    let dir = tempfile::tempdir().unwrap();
    let frames: Vec<FrameRecord> = (0..40)
        .map(|i| record("gp", i, Some(0.3), i % 9 == 0, i == 5))
        .collect();
    let refs: Vec<&FrameRecord> = frames.iter().collect();
    let path = dir.path().join("track.png");
    // A workspace twice as wide as high: its outline must be too, in pixels.
    let workspace = crate::planar::Rect {
        x_min: -20.0,
        x_max: 20.0,
        y_min: 37.0,
        y_max: 57.0,
    };
    let plot = TrackPlot {
        method: "gp",
        samples: None,
        workspace: Some(workspace),
    };
    plot_trajectory(&path, "t", &refs, &plot).unwrap();
    let image = read(&path);
    let (x0, y0, x1, y1) = bounds(&image, WORKSPACE);
    let ratio = f64::from(x1 - x0) / f64::from(y1 - y0);
    assert!(
        (ratio - 2.0).abs() < 0.03,
        "outline {x0},{y0}..{x1},{y1}: {ratio}"
    );
    assert!(count(&image, method_colour("gp")) > 100);
    assert!(count(&image, FAULT_MARK) > 20, "struck frames ringed");
}

fn bars(path: &Path, labels: &[String], half: Option<f64>, paper: bool) -> Image {
    let series: Vec<BarSeries> = ["evidential", "knn", "gp"]
        .iter()
        .enumerate()
        .map(|(k, m)| BarSeries {
            name: m.to_string(),
            values: (0..labels.len())
                .map(|i| Some(0.1 * (k + 1) as f64 + i as f64 * 0.01))
                .collect(),
            half_widths: vec![half; labels.len()],
        })
        .collect();
    let reference: Vec<Option<f64>> = vec![Some(0.5); labels.len()];
    plot_errors_by_variant(path, "t", labels, &series, paper.then_some(&reference[..])).unwrap();
    read(path)
}

#[test]
fn bars_show_intervals_only_with_seeds_and_stay_readable_with_25_variants() {
    let dir = tempfile::tempdir().unwrap();
    let labels: Vec<String> = (0..25)
        .map(|i| format!("paper-variant-with-a-long-name-{i}"))
        .collect();
    let one = bars(&dir.path().join("one.png"), &labels, None, false);
    let seeds = bars(&dir.path().join("seeds.png"), &labels, Some(0.02), true);
    assert_eq!(count(&one, INTERVAL), 0);
    assert!(count(&seeds, INTERVAL) > 25 * 3 * 10, "whiskers drawn");
    assert_ne!(one.as_raw(), seeds.as_raw());
    // The canvas grows: every variant has its own row of bars, each method its colour.
    assert!(one.height() > 25 * 40);
    for method in ["evidential", "knn", "gp"] {
        let colour = method_colour(method);
        let (x0, ..) = bounds(&one, colour);
        let want = [colour.0, colour.1, colour.2];
        let column: Vec<bool> = (0..one.height())
            .map(|y| one.get_pixel(x0 + 2, y).0 == want)
            .collect();
        let rows = column.windows(2).filter(|w| w[1] && !w[0]).count();
        assert_eq!(rows, 25, "{method}: one bar per variant");
    }
}

#[test]
fn colours_are_fixed_per_method() {
    assert_eq!(method_colour("evidential"), RGBColor(0, 114, 178));
    assert_eq!(method_colour("my_method"), method_colour("my_method"));
    let built_in = [
        "evidential",
        "evidential_temporal",
        "continuous",
        "continuous_temporal",
        "particle_filter",
        "knn",
        "gp",
        "centre",
    ];
    let mut seen: Vec<RGBColor> = built_in.iter().map(|m| method_colour(m)).collect();
    seen.extend([
        INTERVAL,
        PAPER,
        FAULT_SHADE,
        LOST_SHADE,
        WORKSPACE,
        FAULT_MARK,
    ]);
    for (i, a) in seen.iter().enumerate() {
        assert!(seen[i + 1..].iter().all(|b| b != a), "{a:?} is used twice");
    }
    assert_eq!(abbreviate("abcdefghij", 7), "abc…hij");
    assert_eq!(abbreviate("short", 7), "short");
}

#[test]
fn empty_inputs_are_errors_not_panics() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("none.png");
    let plot = TrackPlot {
        method: "knn",
        samples: None,
        workspace: None,
    };
    assert!(matches!(
        plot_trajectory(&path, "t", &[], &plot),
        Err(ReportError::Empty { .. })
    ));
    assert!(plot_errors_by_variant(&path, "t", &[], &[], None).is_err());
    let short = BarSeries {
        name: "m".into(),
        values: vec![Some(1.0)],
        half_widths: vec![],
    };
    let two = ["a".to_string(), "b".to_string()];
    assert!(plot_errors_by_variant(&path, "t", &two, &[short], None).is_err());
    assert!(plot_series(&path, "t", "x", "y", &[]).is_err());
    assert!(plot_errors_over_time(&path, "t", &[]).is_err());
    assert!(!path.exists());
}

#[test]
fn lines_draw_intervals_where_given() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("lines.png");
    let mut line = PlotSeries::of("continuous", vec![(0.0, 1.0), (5.0, 1.2), (10.0, 1.5)]);
    plot_series(&path, "t", "σ", "error", std::slice::from_ref(&line)).unwrap();
    let without = read(&path);
    assert!(count(&without, method_colour("continuous")) > 100);
    assert_eq!(count(&without, INTERVAL), 0);
    line.half_widths = vec![Some(0.1); 3];
    plot_series(&path, "t", "σ", "error", &[line]).unwrap();
    assert!(count(&read(&path), INTERVAL) > 50);
}
