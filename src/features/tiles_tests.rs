use image::{GrayImage, Luma};

use super::*;
use crate::features::synthetic::{render, rig_like_frame, Shape};
use crate::features::FeatureConfig;

fn values(feature: &TileFeature, image: &GrayImage) -> Vec<Option<f64>> {
    let mut out = Vec::new();
    feature.extract(image, &mut out);
    assert_eq!(out.len(), feature.names().len());
    out
}

fn grid(columns: usize, rows: usize) -> TileFeature {
    let config = TileConfig {
        enabled: true,
        columns,
        rows,
        ..TileConfig::default()
    };
    config.check(Polarity::BrightOnDark).unwrap()
}

/// Pixels `x0..=x1`, `y0..=y1` exactly.
fn pixels(x0: f64, y0: f64, x1: f64, y1: f64) -> Shape {
    Shape::Rect {
        min: [x0 - 0.5, y0 - 0.5],
        max: [x1 + 0.5, y1 + 0.5],
    }
}

fn paint(image: &mut GrayImage, x0: u32, y0: u32, size: u32, level: u8) {
    for y in y0..(y0 + size).min(image.height()) {
        for x in x0..(x0 + size).min(image.width()) {
            image.put_pixel(x, y, Luma([level]));
        }
    }
}

#[test]
fn names_run_row_by_row() {
    let names = grid(4, 3).names();
    assert_eq!(names.len(), 12);
    assert_eq!(names[0], "tile_r0_c0");
    assert_eq!(names[5], "tile_r1_c1");
    assert_eq!(names[11], "tile_r2_c3");
}

#[test]
fn a_covered_tile_is_one_and_the_others_zero() {
    // 40 × 30 in 4 × 3 tiles of 10 × 10; the body covers tile (1, 2) and half of tile (0, 0).
    let shapes = [pixels(20.0, 10.0, 29.0, 19.0), pixels(0.0, 0.0, 4.0, 9.0)];
    let image = render(40, 30, &shapes, 30, 220, 4);
    let v = values(&grid(4, 3), &image);
    for (i, value) in v.iter().enumerate() {
        let want = match i {
            6 => 1.0,
            0 => 0.5,
            _ => 0.0,
        };
        assert_eq!(*value, Some(want), "tile {i}");
    }
    // Dark on bright, the same body reads the same.
    let mut dark = image.clone();
    dark.pixels_mut().for_each(|p| p.0[0] = 255 - p.0[0]);
    let flipped = TileConfig {
        enabled: true,
        columns: 4,
        rows: 3,
        ..TileConfig::default()
    };
    let flipped = flipped.check(Polarity::DarkOnBright).unwrap();
    assert_eq!(values(&flipped, &dark), v);
}

#[test]
fn an_occluding_box_moves_only_the_tiles_it_overlaps() {
    let feature = grid(4, 4);
    // 170 × 120 in tiles of 42–43 × 30 px.
    let xs = [0, 42, 85, 127, 170];
    let ys = [0, 30, 60, 90, 120];
    for (k, pose) in [[0.0, 47.0], [-8.0, 40.0], [7.0, 55.0]]
        .into_iter()
        .enumerate()
    {
        let clean = rig_like_frame(pose, 2.0, k as u64).unwrap();
        let before = values(&feature, &clean);
        for (x0, y0) in [(5, 5), (35, 25), (80, 70), (150, 100), (60, 95)] {
            for level in [0, 255] {
                let mut image = clean.clone();
                paint(&mut image, x0, y0, 15, level);
                let after = values(&feature, &image);
                let mut moved = 0;
                for (i, (a, b)) in before.iter().zip(&after).enumerate() {
                    let (r, c) = (i / 4, i % 4);
                    let overlaps =
                        x0 < xs[c + 1] && x0 + 15 > xs[c] && y0 < ys[r + 1] && y0 + 15 > ys[r];
                    let shift = (a.unwrap() - b.unwrap()).abs();
                    if !overlaps {
                        assert!(
                            shift < 1e-3,
                            "{pose:?} box ({x0}, {y0}) {level}: tile {i} by {shift}"
                        );
                    } else if shift > 0.0 {
                        moved += 1;
                    }
                }
                assert!(moved <= 4, "{pose:?} ({x0}, {y0}) {level}: {moved} tiles");
                if level == 255 {
                    assert!(moved >= 1, "a bright box on the background shows");
                }
            }
        }
    }
}

#[test]
fn bad_settings_are_refused_with_the_reason() {
    let base = TileConfig {
        enabled: true,
        ..TileConfig::default()
    };
    let cases = [
        TileConfig {
            columns: 0,
            ..base.clone()
        },
        TileConfig {
            columns: 9,
            rows: 8,
            ..base.clone()
        },
        TileConfig {
            floor: f64::NAN,
            ..base.clone()
        },
        TileConfig {
            contrast: 0.0,
            ..base.clone()
        },
        TileConfig {
            region: Some([0, 0, 3, 40]),
            ..base.clone()
        },
        TileConfig {
            region: Some([u32::MAX, 0, 10, 10]),
            ..base.clone()
        },
    ];
    for config in cases {
        let error = config.check(Polarity::BrightOnDark).unwrap_err();
        assert!(matches!(error, FeatureError::BadTiles { .. }), "{config:?}");
        let set = FeatureConfig {
            tiles: config,
            ..FeatureConfig::default()
        };
        assert!(set
            .check()
            .unwrap_err()
            .to_string()
            .contains("[features.tiles]"));
    }
}

#[test]
fn a_region_beyond_the_frame_gives_missing_values() {
    let config = TileConfig {
        enabled: true,
        columns: 2,
        rows: 2,
        region: Some([100, 0, 100, 50]),
        ..TileConfig::default()
    };
    let feature = config.check(Polarity::BrightOnDark).unwrap();
    let image = rig_like_frame([0.0, 47.0], 2.0, 1).unwrap();
    assert_eq!(values(&feature, &image), vec![None; 4]);
    assert_eq!(values(&feature, &GrayImage::new(0, 0)), vec![None; 4]);
}

#[test]
fn the_family_enters_a_feature_set_from_toml_and_stays_out_of_it_when_off() {
    let config: FeatureConfig = toml::from_str(
        "[barycentre]\nenabled = true\n[tiles]\nenabled = true\ncolumns = 3\nrows = 2",
    )
    .unwrap();
    let set = config.check().unwrap();
    assert_eq!(set.len(), 6 + 2 + 6);
    assert_eq!(set.names()[8], "tile_r0_c0");
    let written = serde_json::to_string(&FeatureConfig::with_barycentre()).unwrap();
    assert!(!written.contains("tiles"), "{written}");
    assert!(toml::from_str::<FeatureConfig>("[tiles]\ncount = 4").is_err());
}
