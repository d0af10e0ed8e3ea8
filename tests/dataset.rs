//! Datasets on disk: round trip and clear errors on malformed folders.

use evitrack::dataset::{
    CameraGeometry, Dataset, DatasetError, Frame, Manifest, Polarity, Truth, Units, FORMAT_VERSION,
    MANIFEST_FILE, POSES_FILE,
};
use image::GrayImage;
use std::fs;

fn small_dataset(with_truth: bool) -> Dataset {
    let camera = CameraGeometry {
        width: 12,
        height: 8,
        mm_per_px: 0.2,
        centre: [0.0, 47.5],
        polarity: Polarity::BrightOnDark,
    };
    let frames = (0..5)
        .map(|k| Frame {
            file: format!("frames/{k:05}.png"),
            t: 0.1 * k as f64 + 1.0 / 3.0,
            image: GrayImage::from_fn(12, 8, |i, j| image::Luma([(i * 17 + j * 31 + k * 7) as u8])),
            truth: (with_truth || k % 2 == 0).then(|| Truth {
                x: -9.5 + 0.123_456_789_012_345 * k as f64,
                y: 38.0 + std::f64::consts::PI * k as f64,
                angles: Some([2.0 + 1e-17 * k as f64, 0.5 - k as f64 / 7.0]),
            }),
        })
        .collect::<Vec<_>>();
    Dataset {
        manifest: Manifest {
            format_version: FORMAT_VERSION,
            camera,
            units: Units::default(),
            workspace: None,
            seed: Some(42),
            scenario: "unit".into(),
            source: "tests/dataset.rs".into(),
            frame_count: frames.len(),
        },
        frames,
    }
}

#[test]
fn dataset_round_trip_is_exact() {
    for with_truth in [true, false] {
        let dir = tempfile::tempdir().unwrap();
        let d = small_dataset(with_truth);
        d.write(dir.path()).unwrap();
        let back = Dataset::read(dir.path()).unwrap();
        assert_eq!(back, d);
    }
}

#[test]
fn simulated_dataset_round_trip() {
    let s = evitrack::sim::SimSettings::default();
    let m = evitrack::sim::Motion::Points {
        points: vec![[0.0, 40.0], [-3.0, 50.0], [9.0, 56.0]],
    };
    let d = evitrack::sim::simulate(&s, &m, 5, &mut |_, _| {}).unwrap();
    let dir = tempfile::tempdir().unwrap();
    d.write(dir.path()).unwrap();
    let back = Dataset::read(dir.path()).unwrap();
    assert_eq!(back, d);
    assert_eq!(back.truth_positions().unwrap().len(), 3);
}

#[test]
fn truth_positions_need_every_frame() {
    assert!(small_dataset(false).truth_positions().is_none());
    assert!(small_dataset(false).truths().is_none());
    assert_eq!(small_dataset(true).truths().unwrap().len(), 5);
    let p = small_dataset(true).truth_positions().unwrap();
    assert_eq!(p[0], [-9.5, 38.0]);
}

fn written() -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    small_dataset(true).write(dir.path()).unwrap();
    dir
}

#[test]
fn missing_frame_is_named() {
    let dir = written();
    fs::remove_file(dir.path().join("frames/00003.png")).unwrap();
    let e = Dataset::read(dir.path()).unwrap_err();
    assert!(matches!(e, DatasetError::Frame { line: 5, .. }), "{e}");
    let msg = e.to_string();
    assert!(
        msg.contains("00003.png") && msg.contains("missing"),
        "{msg}"
    );
}

#[test]
fn bad_row_is_named_with_its_line() {
    let dir = written();
    let path = dir.path().join(POSES_FILE);
    let text = fs::read_to_string(&path).unwrap();
    let mut lines: Vec<String> = text.lines().map(String::from).collect();
    // replace the time field of line 4 by garbage
    let mut fields: Vec<&str> = lines[3].split(',').collect();
    fields[1] = "12x";
    lines[3] = fields.join(",");
    fs::write(&path, lines.join("\n") + "\n").unwrap();
    let e = Dataset::read(dir.path()).unwrap_err();
    assert!(matches!(e, DatasetError::Row { line: 4, .. }), "{e}");
    assert!(e.to_string().contains("12x"), "{e}");

    // a short row
    let mut short = lines.clone();
    short[2] = "frames/00001.png,0.5".into();
    fs::write(&path, short.join("\n") + "\n").unwrap();
    let e = Dataset::read(dir.path()).unwrap_err();
    assert!(matches!(e, DatasetError::Row { line: 3, .. }), "{e}");

    // half-filled pose columns
    let mut half: Vec<String> = text.lines().map(String::from).collect();
    let mut f: Vec<&str> = half[1].split(',').collect();
    f[4] = "";
    half[1] = f.join(",");
    fs::write(&path, half.join("\n") + "\n").unwrap();
    let e = Dataset::read(dir.path()).unwrap_err();
    assert!(matches!(e, DatasetError::Row { line: 2, .. }), "{e}");
}

#[test]
fn bad_manifest_version_is_clear() {
    let dir = written();
    let path = dir.path().join(MANIFEST_FILE);
    let text = fs::read_to_string(&path).unwrap();
    let bumped = text.replace(
        &format!("\"format_version\": {FORMAT_VERSION}"),
        "\"format_version\": 99",
    );
    assert_ne!(bumped, text);
    fs::write(&path, bumped).unwrap();
    let e = Dataset::read(dir.path()).unwrap_err();
    assert!(matches!(e, DatasetError::Manifest { .. }), "{e}");
    assert!(e.to_string().contains("99"), "{e}");

    fs::write(&path, "{ not json").unwrap();
    assert!(matches!(
        Dataset::read(dir.path()),
        Err(DatasetError::Manifest { .. })
    ));
    fs::remove_file(&path).unwrap();
    assert!(matches!(
        Dataset::read(dir.path()),
        Err(DatasetError::Io { .. })
    ));
}

#[test]
fn frame_count_and_size_mismatches_are_errors() {
    let dir = written();
    let path = dir.path().join(MANIFEST_FILE);
    let text = fs::read_to_string(&path).unwrap();
    fs::write(
        &path,
        text.replace("\"frame_count\": 5", "\"frame_count\": 6"),
    )
    .unwrap();
    assert!(matches!(
        Dataset::read(dir.path()),
        Err(DatasetError::Manifest { .. })
    ));
    fs::write(&path, &text).unwrap();
    GrayImage::new(3, 3)
        .save(dir.path().join("frames/00002.png"))
        .unwrap();
    let e = Dataset::read(dir.path()).unwrap_err();
    assert!(matches!(e, DatasetError::Frame { line: 4, .. }), "{e}");
}

#[test]
fn inconsistent_dataset_is_not_written() {
    let mut d = small_dataset(true);
    d.manifest.frame_count = 2;
    let dir = tempfile::tempdir().unwrap();
    assert!(matches!(d.write(dir.path()), Err(DatasetError::Invalid(_))));
    let mut d = small_dataset(true);
    d.frames[1].file = "../escape.png".into();
    d.manifest.frame_count = d.frames.len();
    assert!(matches!(d.write(dir.path()), Err(DatasetError::Invalid(_))));
}

#[test]
fn poses_without_joint_angles_round_trip_in_four_columns() {
    let mut d = small_dataset(true);
    for f in &mut d.frames {
        if let Some(t) = &mut f.truth {
            t.angles = None;
        }
    }
    let dir = tempfile::tempdir().unwrap();
    d.write(dir.path()).unwrap();
    let text = fs::read_to_string(dir.path().join(POSES_FILE)).unwrap();
    assert!(text.starts_with("file,t,x,y\n"), "{text}");
    assert_eq!(Dataset::read(dir.path()).unwrap(), d);
    // Six columns with the angles left empty read the same.
    let six: String = text
        .lines()
        .enumerate()
        .map(|(k, l)| match k {
            0 => "file,t,x,y,theta1,theta2\n".to_string(),
            _ => format!("{l},,\n"),
        })
        .collect();
    fs::write(dir.path().join(POSES_FILE), six).unwrap();
    assert_eq!(Dataset::read(dir.path()).unwrap(), d);
}
