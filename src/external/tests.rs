//! The output checker on hand-written outputs, and the runner and cache on `sh` programs.

use super::*;
use crate::dataset::{CameraGeometry, Manifest, Polarity, Units, FORMAT_VERSION};
use crate::features::{ExternalFeatureConfig, FeatureConfig, MissingValues};
use image::GrayImage;

fn program(command: &[&str], values: &[&str], missing: MissingValues) -> ExternalFeatureConfig {
    ExternalFeatureConfig {
        command: command.iter().map(|s| s.to_string()).collect(),
        values: values.iter().map(|s| s.to_string()).collect(),
        missing,
        timeout_seconds: 10.0,
    }
}

fn files(n: usize) -> Vec<String> {
    (0..n).map(crate::dataset::frame_file_name).collect()
}

fn read(text: &str, missing: MissingValues) -> Result<FeatureRows, String> {
    let p = program(&["prog"], &["a", "b"], missing);
    table::read(text.as_bytes(), &p, &files(2)).map_err(|e| e.to_string())
}

#[test]
fn rows_are_read_by_name_in_declared_order() {
    let rows = read(
        "frame,b,a\n0,2,1\nframes/00001.png,NA,-3.5e2\n",
        MissingValues::Allowed,
    )
    .unwrap();
    assert_eq!(
        rows,
        vec![vec![Some(1.0), Some(2.0)], vec![Some(-350.0), None]]
    );
    let spaced = read("frame, a, b\n0, 1,\n1 ,2,3\n", MissingValues::Allowed).unwrap();
    assert_eq!(spaced[0], vec![Some(1.0), None]);
}

#[test]
fn every_problem_names_the_program_line_and_column() {
    let error = MissingValues::Error;
    for (text, expected) in [
        ("", "prog`, line 1 (the header): the output is empty"),
        ("idx,a,b\n", "the first column must be `frame`, found `idx`"),
        (
            "frame,a,c\n",
            "column `c` is not a declared value (declared: a, b)",
        ),
        (
            "frame,a\n0,1\n1,2\n",
            "no column for the declared value `b`",
        ),
        ("frame,a,b,a\n", "column `a` appears twice"),
        ("frame,a,b\n0,1,2\n", "wrote 1 rows for 2 frames"),
        (
            "frame,a,b\n0,1,2\n1,1,2\n2,1,2\n3,1,2\n",
            "wrote 4 rows for 2 frames",
        ),
        (
            "frame,a,b\n0,1,2\n1,nan,2\n",
            "line 3 (frame 1), column `a`: `nan` is not finite",
        ),
        (
            "frame,a,b\n0,1,inf\n1,1,2\n",
            "line 2 (frame 0), column `b`: `inf` is not finite",
        ),
        (
            "frame,a,b\n0,1,x\n",
            "line 2 (frame 0), column `b`: `x` is not a number",
        ),
        (
            "frame,a,b\n0,1,\n",
            "line 2 (frame 0), column `b`: the value is missing",
        ),
        (
            "frame,a,b\n0,1,2\n2,1,2\n",
            "line 3 (frame 1), column `frame`: `2` where frame 1",
        ),
        (
            "frame,a,b\n0,1\n",
            "line 2 (frame 0): 2 fields, the header has 3",
        ),
    ] {
        let message = read(text, error).unwrap_err();
        assert!(message.contains(expected), "{text:?}: {message}");
        assert!(message.starts_with("feature program `prog`"), "{message}");
    }
}

/// A dataset of `n` tiny frames, each a shade of grey.
fn tiny(n: usize) -> Dataset {
    let camera = CameraGeometry {
        width: 4,
        height: 3,
        mm_per_px: 1.0,
        centre: [0.0, 0.0],
        polarity: Polarity::BrightOnDark,
    };
    Dataset {
        manifest: Manifest {
            format_version: FORMAT_VERSION,
            camera,
            units: Units::default(),
            workspace: None,
            seed: None,
            scenario: "tiny".into(),
            source: String::new(),
            frame_count: n,
        },
        frames: (0..n)
            .map(|k| Frame {
                file: crate::dataset::frame_file_name(k),
                t: k as f64,
                image: GrayImage::from_pixel(4, 3, image::Luma([10 * k as u8])),
                truth: None,
            })
            .collect(),
    }
}

#[cfg(unix)]
fn sh(script: &str, values: &[&str]) -> ExternalFeatureConfig {
    program(&["sh", "-c", script], values, MissingValues::Error)
}

#[cfg(unix)]
#[test]
fn programs_run_with_a_time_limit_and_their_failures_are_named() {
    let dir = tempfile::tempdir().unwrap();
    let ok = sh("ls \"$0\" >&2; printf 'frame,v\\n0,1.5\\n1,2\\n'", &["v"]);
    let out = process::run(&ok, dir.path()).unwrap();
    assert_eq!(out, b"frame,v\n0,1.5\n1,2\n");
    let failed = sh("echo one >&2; echo two >&2; exit 3", &["v"]);
    let message = process::run(&failed, dir.path()).unwrap_err().to_string();
    assert!(message.contains("exit status: 3"), "{message}");
    assert!(message.ends_with("one\ntwo"), "{message}");
    let mut slow = sh("sleep 5", &["v"]);
    slow.timeout_seconds = 0.2;
    let clock = std::time::Instant::now();
    let message = process::run(&slow, dir.path()).unwrap_err().to_string();
    assert!(message.contains("still running after 0.2 s"), "{message}");
    assert!(clock.elapsed().as_secs_f64() < 4.0);
    let absent = program(&["evitrack-no-such-program"], &["v"], MissingValues::Error);
    let message = process::run(&absent, dir.path()).unwrap_err().to_string();
    assert!(
        message.contains("`evitrack-no-such-program` could not start"),
        "{message}"
    );
}

#[cfg(unix)]
#[test]
fn values_follow_the_built_in_ones_and_a_cache_hit_skips_the_program() {
    let dir = tempfile::tempdir().unwrap();
    let count = dir.path().join("count");
    // Counts its runs; writes each frame's index and the mean grey of its pose table's line.
    let script = format!(
        "echo run >> '{}'; test -f \"$0/frames/00002.png\" || exit 9; \
         grep -c ',,,,' \"$0/poses.csv\" >&2; printf 'frame,twice\\n0,0\\n1,2\\n2,NA\\n'",
        count.display()
    );
    let mut config = FeatureConfig::default();
    let mut p = sh(&script, &["twice"]);
    p.missing = MissingValues::Allowed;
    config.external.push(p);
    let set = config.check().unwrap();
    assert_eq!(set.len(), 7);
    assert_eq!(set.names()[6], "twice");
    assert_eq!(set.image_values(), 6);
    let data = tiny(3);
    let cache = dir.path().join("cache");
    let runs = || std::fs::read_to_string(&count).unwrap().lines().count();
    let mut rows = vec![vec![None; 7]; 3];
    fill_cached(&set, &data, &mut rows, Some(&cache)).unwrap();
    assert_eq!(rows[1][6], Some(2.0));
    assert_eq!(rows[2][6], None);
    assert_eq!(runs(), 1);
    let mut again = vec![vec![None; 7]; 3];
    fill_cached(&set, &data, &mut again, Some(&cache)).unwrap();
    assert_eq!(
        (again, runs()),
        (rows.clone(), 1),
        "the second fill is a hit"
    );
    // Other frames are another key; so is no cache at all.
    let mut other = tiny(3);
    other.frames[0].image.put_pixel(0, 0, image::Luma([255]));
    fill_cached(&set, &other, &mut rows, Some(&cache)).unwrap();
    assert_eq!(runs(), 2);
    fill_cached(&set, &data, &mut rows, None).unwrap();
    assert_eq!(runs(), 3);
    // Rows of another set are refused before the program runs.
    let mut short = vec![vec![None; 6]; 3];
    let message = fill_cached(&set, &data, &mut short, None)
        .unwrap_err()
        .to_string();
    assert!(
        message.contains("3 feature rows for 3 frames (each needs 7 values)"),
        "{message}"
    );
    assert_eq!(runs(), 3);
}
