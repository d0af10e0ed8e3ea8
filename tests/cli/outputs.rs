//! One rule for every output file: no NaN and no infinity, except the `inf` the README documents
//! for a level of conflict, a detection score and a conflict threshold. Scanned over a run of
//! every scenario file in `scenarios/` (shrunk to short motions, with their fault variants) and
//! over runs whose faults push the scores beyond the double range; model files that would lead
//! to non-finite outputs are refused when loaded.

use std::path::Path;

use super::*;

/// Columns and keys whose `inf` the README documents.
const INFINITE_ALLOWED: [&str; 3] = ["conflict_level", "detection_score", "threshold"];

fn allowed(name: &str, text: &str) -> bool {
    text == "inf" && INFINITE_ALLOWED.iter().any(|a| name.contains(a))
}

/// Whether `text` reads as a number that is not finite.
fn non_finite(text: &str) -> bool {
    text.trim().parse::<f64>().is_ok_and(|v| !v.is_finite())
}

fn scan_json(value: &serde_json::Value, key: &str, file: &Path, bad: &mut Vec<String>) {
    match value {
        serde_json::Value::String(s) if non_finite(s) && !allowed(key, s) => {
            bad.push(format!("{}: `{key}` = {s}", file.display()));
        }
        serde_json::Value::Array(items) => {
            (items.iter()).for_each(|v| scan_json(v, key, file, bad));
        }
        serde_json::Value::Object(map) => {
            (map.iter()).for_each(|(k, v)| scan_json(v, k, file, bad));
        }
        _ => {}
    }
}

fn scan_toml(value: &toml::Value, key: &str, file: &Path, bad: &mut Vec<String>) {
    match value {
        toml::Value::Float(v) if !v.is_finite() => {
            bad.push(format!("{}: `{key}` = {v}", file.display()));
        }
        toml::Value::String(s) if non_finite(s) && !allowed(key, s) => {
            bad.push(format!("{}: `{key}` = {s}", file.display()));
        }
        toml::Value::Array(items) => items.iter().for_each(|v| scan_toml(v, key, file, bad)),
        toml::Value::Table(map) => map.iter().for_each(|(k, v)| scan_toml(v, k, file, bad)),
        _ => {}
    }
}

/// Every non-finite number in the CSV, JSON and TOML files under `dir` that the README does not
/// document; also counts the files read.
fn scan(dir: &Path, bad: &mut Vec<String>) -> usize {
    let mut files = 0;
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            files += scan(&path, bad);
            continue;
        }
        let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("");
        if !["csv", "json", "toml"].contains(&ext) {
            continue;
        }
        files += 1;
        let text = std::fs::read_to_string(&path).unwrap();
        match ext {
            "csv" => {
                let mut reader = csv::Reader::from_reader(text.as_bytes());
                let header = reader.headers().unwrap().clone();
                for (row, record) in reader.records().enumerate() {
                    for (name, cell) in header.iter().zip(record.unwrap().iter()) {
                        if non_finite(cell) && !allowed(name, cell) {
                            bad.push(format!("{} row {row}: {name} = {cell}", path.display()));
                        }
                    }
                }
            }
            "json" => match serde_json::from_str::<serde_json::Value>(&text) {
                Ok(value) => scan_json(&value, "", &path, bad),
                Err(e) => bad.push(format!("{}: not JSON ({e})", path.display())),
            },
            _ => match text.parse::<toml::Table>() {
                Ok(table) => scan_toml(&toml::Value::Table(table), "", &path, bad),
                Err(e) => bad.push(format!("{}: not TOML ({e})", path.display())),
            },
        }
    }
    files
}

/// The files of `runs` a sweep would write that hold numbers (`frames.csv`, `results.json`,
/// `scenario.toml`, the model files; not the plots) carry no undocumented non-finite number. For the files whose check
/// test runs every variant anyway ([`SCANNED_BY_THEIR_CHECK`]), instead of a second, shrunk sweep.
pub(crate) fn scan_outputs(runs: &[(String, evitrack::experiment::RunOutput)]) {
    let dir = tempfile::tempdir().unwrap();
    for (name, output) in runs {
        let run_dir = dir.path().join(name);
        std::fs::create_dir_all(&run_dir).unwrap();
        let mut frames = Vec::new();
        evitrack::report::write_frames_csv(&mut frames, &output.records, &output.summary.features)
            .unwrap();
        std::fs::write(run_dir.join("frames.csv"), frames).unwrap();
        std::fs::write(run_dir.join("scenario.toml"), &output.scenario_toml).unwrap();
        let results = serde_json::to_string(&output.summary).unwrap();
        std::fs::write(run_dir.join("results.json"), results).unwrap();
        for estimator in &output.estimators {
            let file = evitrack::report::model_file_name(estimator.method());
            std::fs::write(run_dir.join(file), estimator.to_json().unwrap()).unwrap();
        }
    }
    let mut bad = Vec::new();
    let files = scan(dir.path(), &mut bad);
    assert!(bad.is_empty(), "{bad:#?}");
    assert!(files >= 4 * runs.len(), "{files} files scanned");
}

/// A scenario file made quick: a mesh of 2 mm or coarser, motions of at most 2 s, and of its
/// sweep only the variants that inject faults.
fn shrunk(text: &str) -> String {
    let mut table: toml::Table = text.parse().unwrap();
    let cap = |t: &mut toml::Table| {
        if let Some(toml::Value::Float(d)) = t.get_mut("duration") {
            *d = d.min(2.0);
        }
    };
    if let Some(toml::Value::Table(sample)) = table.get_mut("sample") {
        if let Some(toml::Value::Table(motion)) = sample.get_mut("motion") {
            if let Some(toml::Value::Float(s)) = motion.get_mut("spacing") {
                *s = s.max(2.0);
            }
        }
    }
    if let Some(toml::Value::Table(v)) = table.get_mut("validation") {
        cap(v);
    }
    if let Some(toml::Value::Array(tests)) = table.get_mut("tests") {
        tests
            .iter_mut()
            .filter_map(toml::Value::as_table_mut)
            .for_each(cap);
    }
    if let Some(toml::Value::Table(sweep)) = table.get_mut("sweep") {
        sweep.remove("grid");
        sweep.remove("finding");
        sweep.remove("seeds");
        if let Some(toml::Value::Array(variants)) = sweep.get_mut("variant") {
            variants.retain(|v| v.get("set").and_then(|s| s.get("faults")).is_some());
        }
    }
    toml::to_string(&table).unwrap()
}

/// The shrunk sweep of `scenarios/NAME.toml` writes no undocumented non-finite number.
fn scan_scenario(name: &str) {
    let dir = tempfile::tempdir().unwrap();
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scenarios")
        .join(format!("{name}.toml"));
    let quick = dir.path().join(format!("{name}.toml"));
    std::fs::write(&quick, shrunk(&std::fs::read_to_string(&path).unwrap())).unwrap();
    let out_dir = dir.path().join(name);
    // Exit 1 would be a missed expectation, which is not this test's concern.
    run_expecting("sweep", &quick, &out_dir, 0);
    let mut bad = Vec::new();
    let files = scan(&out_dir, &mut bad);
    assert!(bad.is_empty(), "{bad:#?}");
    assert!(files > 5, "{name}: {files} files scanned");
}

/// One test per shipped scenario file, so they run side by side.
macro_rules! scan_tests {
    ($($test:ident: $name:literal),* $(,)?) => {
        $(
            #[test]
            fn $test() {
                scan_scenario($name);
            }
        )*
        const SCANNED: &[&str] = &[$($name),*];
    };
}

scan_tests! {
    no_undocumented_non_finite_number_in_best: "best",
    no_undocumented_non_finite_number_in_coarse: "coarse",
    no_undocumented_non_finite_number_in_faults: "faults",
    no_undocumented_non_finite_number_in_noise: "noise",
    no_undocumented_non_finite_number_in_paper: "paper",
    no_undocumented_non_finite_number_in_scale: "scale",
    no_undocumented_non_finite_number_in_states: "states",
    no_undocumented_non_finite_number_in_time: "time",
}

/// Scanned by their check test, which runs every variant at full size ([`scan_outputs`]).
const SCANNED_BY_THEIR_CHECK: &[&str] = &["confidence", "occlusion", "rules"];

#[test]
fn every_scenario_file_is_scanned_for_non_finite_numbers() {
    let mut names: Vec<String> =
        std::fs::read_dir(concat!(env!("CARGO_MANIFEST_DIR"), "/scenarios"))
            .unwrap()
            .map(|e| e.unwrap().path())
            .filter(|p| p.extension().is_some_and(|e| e == "toml"))
            .map(|p| p.file_stem().unwrap().to_str().unwrap().to_string())
            .collect();
    names.sort();
    let mut scanned: Vec<&str> = SCANNED
        .iter()
        .chain(SCANNED_BY_THEIR_CHECK)
        .copied()
        .collect();
    scanned.sort();
    assert_eq!(
        names, scanned,
        "add a scan_tests! line for each new scenario file"
    );
}

/// Faults of 1e200 and 1e308 (finite feature values) overflow squares and χ²: the run exits 0
/// with only documented infinities, and k-NN and the GP measure the 1e200 offset finitely (the GP in length scales, hence above 1e150).
#[test]
fn faults_beyond_the_double_range_write_only_documented_infinities() {
    let dir = tempfile::tempdir().unwrap();
    let mut bad = Vec::new();
    let estimators = "estimators = [\"evidential\", \"continuous\", \"knn\", \"gp\"]\n";
    for (name, fault) in [
        ("offset", "kind = \"offset\"\nvalue = 1e200"),
        ("stuck", "kind = \"stuck\"\nvalue = 1e308"),
        ("gain", "kind = \"gain\"\nfactor = 1e308"),
    ] {
        let extra = format!("[[faults]]\n{fault}\nfeatures = [\"size_line0\"]\nshare = 1.0\n");
        let text = small_scenario(name, &extra).replacen('\n', &format!("\n{estimators}"), 1);
        let scenario = dir.path().join(format!("{name}.toml"));
        std::fs::write(&scenario, text).unwrap();
        let out_dir = dir.path().join("out");
        run_expecting("run", &scenario, &out_dir, 0);
        scan(&out_dir.join(name), &mut bad);
    }
    assert!(bad.is_empty(), "{bad:#?}");
    let frames = std::fs::read_to_string(dir.path().join("out/offset/frames.csv")).unwrap();
    let mut reader = csv::Reader::from_reader(frames.as_bytes());
    let header = reader.headers().unwrap().clone();
    let column = |n: &str| header.iter().position(|h| h == n).unwrap();
    let (method, score) = (column("method"), column("detection_score"));
    let mut seen = 0;
    for record in reader.records() {
        let record = record.unwrap();
        if ["knn", "gp"].contains(&&record[method]) {
            let value: f64 = record[score].parse().unwrap();
            assert!(
                value.is_finite() && value > 1e150,
                "{}: {value}",
                &record[method]
            );
            seen += 1;
        }
    }
    assert_eq!(seen, 40);
}

/// Model files whose standardisation or samples would make every score NaN or infinite are
/// refused when loaded, naming the field, with exit status 2.
#[test]
fn model_files_leading_to_non_finite_outputs_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = dir.path().join("m.toml");
    let text = small_scenario("m", "").replacen(
        '\n',
        "\nestimators = [\"continuous\", \"knn\", \"gp\"]\n",
        1,
    );
    std::fs::write(&scenario, text).unwrap();
    let out_dir = dir.path().join("out");
    let scenario = scenario.to_str().unwrap();
    let out = evitrack(&["run", scenario, "--out", out_dir.to_str().unwrap()], "");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let test = dir.path().join("test0");
    let out = evitrack(
        &[
            "simulate",
            "--scenario",
            scenario,
            "--part",
            "test",
            "--out",
            test.to_str().unwrap(),
        ],
        "",
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let cases: [(&str, &str, serde_json::Value, &str); 6] = [
        (
            "knn",
            "/standardisation/means/0",
            1e308.into(),
            "sample_features[0][0]",
        ),
        (
            "knn",
            "/standardisation/scales/0",
            1e-310.into(),
            "standardisation.scales[0]",
        ),
        (
            "gp",
            "/standardisation/means/1",
            (-1e308).into(),
            "sample_features[0][1]",
        ),
        (
            "continuous",
            "/sample_features/3/1",
            f64::MAX.into(),
            "sample_features[3][1]",
        ),
        (
            "continuous",
            "/feature_standardisation/scales/2",
            1e-310.into(),
            "feature_standardisation.scales[2]",
        ),
        (
            "continuous",
            "/pose_standardisation/means/0",
            1e300.into(),
            "sample_poses[0][0]",
        ),
    ];
    for (method, pointer, value, field) in cases {
        let file = out_dir.join(format!("m/model-{method}.json"));
        let mut json: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&file).unwrap()).unwrap();
        *json.pointer_mut(pointer).unwrap() = value;
        let bad = dir.path().join("bad.json");
        std::fs::write(&bad, serde_json::to_string(&json).unwrap()).unwrap();
        let out = evitrack(
            &[
                "track",
                test.to_str().unwrap(),
                "--model",
                bad.to_str().unwrap(),
            ],
            "",
        );
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{method} {pointer}: {stderr}");
        assert!(stderr.contains(field), "{method} {pointer}: {stderr}");
        assert!(out.stdout.is_empty(), "{method} {pointer}");
    }
}
