//! `dataset init` and `dataset check`: a folder of PNGs and a CSV of x, y become a dataset that
//! a model trained elsewhere tracks; every problem of a folder is reported at once.

use std::fs;
use std::path::Path;

use super::evitrack;

fn ok(args: &[&str]) -> String {
    let out = evitrack(args, "");
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "{args:?}: {stderr}");
    stderr
}

/// The mean error `track` prints on stderr (`error mean 0.1234 mm`).
fn mean_error(stderr: &str) -> f64 {
    let rest = stderr.split("error mean ").nth(1).expect(stderr);
    rest.split(' ').next().unwrap().parse().expect(stderr)
}

#[test]
fn a_folder_of_pngs_and_positions_is_tracked_by_a_model_trained_elsewhere() {
    let dir = tempfile::tempdir().unwrap();
    let path = |name: &str| dir.path().join(name).to_str().unwrap().to_string();
    ok(&[
        "simulate",
        "--out",
        &path("sample"),
        "--motion",
        r#"kind = "mesh", spacing = 2.0"#,
    ]);
    let test = r#"kind = "circle", radius = 5, speed = 10, duration = 2, fps = 10"#;
    ok(&[
        "simulate",
        "--out",
        &path("test"),
        "--motion",
        test,
        "--seed",
        "3",
    ]);
    ok(&[
        "train",
        &path("sample"),
        "--out",
        &path("model.json"),
        "--barycentre",
        "--states",
        "3",
    ]);
    let original = mean_error(&ok(&[
        "track",
        &path("test"),
        "--model",
        &path("model.json"),
    ]));

    // The test motion's frames alone, renamed, with a CSV of x, y in file-name order.
    let own = dir.path().join("own");
    fs::create_dir(&own).unwrap();
    let poses = fs::read_to_string(dir.path().join("test/poses.csv")).unwrap();
    let mut csv = String::from("x,y\n");
    for (k, line) in poses.lines().skip(1).enumerate() {
        let f: Vec<&str> = line.split(',').collect();
        fs::copy(
            dir.path().join("test").join(f[0]),
            own.join(format!("shot-{k:03}.png")),
        )
        .unwrap();
        csv.push_str(&format!("{},{}\n", f[2], f[3]));
    }
    fs::write(dir.path().join("xy.csv"), csv).unwrap();
    let said = ok(&[
        "dataset",
        "init",
        &path("own"),
        "--poses",
        &path("xy.csv"),
        "--fps",
        "10",
    ]);
    assert!(
        said.contains("20 frames of 170×120 px") && said.contains("20 with a pose"),
        "{said}"
    );
    let table = fs::read_to_string(own.join("poses.csv")).unwrap();
    assert!(table.starts_with("file,t,x,y\nshot-000.png,0,"), "{table}");
    ok(&["dataset", "check", &path("own")]);
    let tracked = mean_error(&ok(&[
        "track",
        &path("own"),
        "--model",
        &path("model.json"),
    ]));
    assert!(
        original > 0.0 && (tracked - original).abs() < 1e-3,
        "{tracked} vs {original}"
    );

    // Without --force an existing manifest stays; a CSV one row short is refused, naming it.
    let again = evitrack(
        &["dataset", "init", &path("own"), "--poses", &path("xy.csv")],
        "",
    );
    assert_eq!(again.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&again.stderr).contains("--force"));
    let short: String = fs::read_to_string(dir.path().join("xy.csv"))
        .unwrap()
        .lines()
        .take(20)
        .map(|l| format!("{l}\n"))
        .collect();
    fs::write(dir.path().join("short.csv"), short).unwrap();
    let out = evitrack(
        &[
            "dataset",
            "init",
            &path("own"),
            "--poses",
            &path("short.csv"),
            "--force",
        ],
        "",
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains("1 frame(s) have no row: shot-019.png"),
        "{stderr}"
    );
}

#[test]
fn dataset_check_reports_every_problem_at_once() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("d");
    let motion = r#"kind = "circle", radius = 5, speed = 10, duration = 1, fps = 10"#;
    ok(&[
        "simulate",
        "--out",
        data.to_str().unwrap(),
        "--motion",
        motion,
    ]);
    ok(&["dataset", "check", data.to_str().unwrap()]);
    // Two manifest fields gone, one of the wrong type, a frame missing, one of another size,
    // a row with a bad time: all six named in one run.
    let manifest = data.join("manifest.json");
    let mut m: serde_json::Value =
        serde_json::from_str(&fs::read_to_string(&manifest).unwrap()).unwrap();
    let object = m.as_object_mut().unwrap();
    object.remove("frame_count");
    object
        .get_mut("camera")
        .unwrap()
        .as_object_mut()
        .unwrap()
        .remove("mm_per_px");
    object.insert("seed".into(), serde_json::json!("one"));
    fs::write(&manifest, serde_json::to_string(&m).unwrap()).unwrap();
    fs::remove_file(data.join("frames/00002.png")).unwrap();
    image::GrayImage::new(5, 5)
        .save(data.join("frames/00004.png"))
        .unwrap();
    let poses = data.join("poses.csv");
    let mut lines: Vec<String> = fs::read_to_string(&poses)
        .unwrap()
        .lines()
        .map(String::from)
        .collect();
    lines[7] = lines[7].replacen(",0.6,", ",soon,", 1);
    fs::write(&poses, lines.join("\n") + "\n").unwrap();
    let out = evitrack(&["dataset", "check", data.to_str().unwrap()], "");
    assert_eq!(out.status.code(), Some(1));
    let report = String::from_utf8_lossy(&out.stdout);
    for needle in [
        "required field `frame_count` is missing",
        "required field `camera.mm_per_px` is missing",
        "seed \"one\" must be a whole number",
        "00002.png (listed on line 4 of poses.csv): frame file is missing",
        "00004.png (listed on line 6 of poses.csv): image is 5×5 but the manifest camera is 170×120",
        "poses.csv line 8: t = \"soon\" is not a number",
    ] {
        assert!(report.contains(needle), "{needle:?} not in\n{report}");
    }
    assert_eq!(report.lines().count(), 6, "{report}");
    assert!(String::from_utf8_lossy(&out.stderr).contains("6 problem(s)"));
    // `read` still stops at the first.
    assert!(evitrack::dataset::Dataset::read(&data).is_err());
    assert!(Path::new(&poses).exists());
}
