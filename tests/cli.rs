//! The command line, run as a user would: exit statuses, stdout, stderr.

use std::io::Write;
use std::process::{Command, Output, Stdio};

mod dataset_cmd;
pub(crate) mod outputs;
mod report;
mod runs;
mod shards;

pub(crate) fn evitrack(args: &[&str], stdin: &str) -> Output {
    let mut child = Command::new(env!("CARGO_BIN_EXE_evitrack"))
        .args(args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("the evitrack binary starts");
    child
        .stdin
        .take()
        .expect("stdin is piped")
        .write_all(stdin.as_bytes())
        .expect("stdin accepts the input");
    child.wait_with_output().expect("evitrack finishes")
}

/// `evitrack COMMAND SCENARIO --out OUT`, asserted to exit with `code` (stderr in the message).
pub(crate) fn run_expecting(
    command: &str,
    scenario: &std::path::Path,
    out: &std::path::Path,
    code: i32,
) -> Output {
    let output = evitrack(
        &[
            command,
            scenario.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ],
        "",
    );
    assert_eq!(
        output.status.code(),
        Some(code),
        "{command} {}: {}",
        scenario.display(),
        String::from_utf8_lossy(&output.stderr)
    );
    output
}

/// A quick scenario: a 2 mm sample mesh and a 20-frame circle, plus `extra` TOML.
fn small_scenario(name: &str, extra: &str) -> String {
    format!(
        "name = \"{name}\"\n[sample]\nmotion = {{ kind = \"mesh\", spacing = 2.0 }}\n\
         [[tests]]\nkind = \"circle\"\nradius = 4.0\nspeed = 10.0\nduration = 2.0\nfps = 10.0\n{extra}"
    )
}

#[test]
fn combine_prints_the_issue_output_shape() {
    let input = r#"{"frame": 400, "rule": "dempster", "mass_functions": [
        {"focal": [[0, 5, 7], [1, 2]], "mass": [0.6, 0.4]},
        {"focal": [[5, 7], [2, 3]], "mass": [0.7, 0.3]}]}"#;
    let out = evitrack(&["combine", "-"], input);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    // κ = 0.6·0.3 + 0.4·0.7 = 0.46; {5,7} gets 0.42/0.54, {2} gets 0.12/0.54.
    assert!((json["conflict_mass"].as_f64().unwrap() - 0.46).abs() < 1e-12);
    let level = json["conflict_level"].as_f64().unwrap();
    assert!((level - (1.0f64 / 0.54).ln()).abs() < 1e-12);
    assert_eq!(json["focal"], serde_json::json!([[5, 7], [2]]));
    let plausibility = json["plausibility"].as_array().unwrap();
    assert_eq!(plausibility.len(), 400);
    assert!((plausibility[5].as_f64().unwrap() - 0.42 / 0.54).abs() < 1e-12);
}

#[test]
fn combine_total_conflict_is_inf_with_a_warning_and_status_zero() {
    let input = r#"{"frame": 3, "rule": "dempster", "mass_functions": [
        {"focal": [[0]], "mass": [1]}, {"focal": [[1]], "mass": [1]}]}"#;
    let out = evitrack(&["combine", "-"], input);
    assert_eq!(out.status.code(), Some(0));
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(json["conflict_level"], "inf");
    assert_eq!(json["focal"], serde_json::json!([]));
    assert!(String::from_utf8_lossy(&out.stderr).contains("total conflict"));
}

/// Issue 29, item 1: a product of 1e-200 · 1e-200 used to underflow and drop its focal set, so
/// `[S, S, C]` printed "inf" with the total-conflict warning; the exact level is 921.03 in every
/// order and under the conjunctive rule too.
#[test]
fn combine_level_survives_underflow_in_every_order() {
    let s = r#"{"focal": [[0], [1]], "mass": [1e-200, 1]}"#;
    let c = r#"{"focal": [[0]], "mass": [1]}"#;
    for order in [[s, s, c], [s, c, s], [c, s, s]] {
        for rule in ["dempster", "conjunctive", "yager", "pcr6"] {
            let input = format!(
                r#"{{"frame": 2, "rule": "{rule}", "mass_functions": [{}]}}"#,
                order.join(",")
            );
            let out = evitrack(&["combine", "-"], &input);
            assert_eq!(out.status.code(), Some(0));
            let json: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
            let level = json["conflict_level"].as_f64().expect("a finite level");
            assert!((level - 921.0340371976183).abs() < 1e-9, "{rule}: {level}");
            assert!(String::from_utf8_lossy(&out.stderr).is_empty());
        }
    }
}

/// Every rule by name, and `--reliability` (one for all, or one per function).
#[test]
fn combine_takes_every_rule_and_reliabilities() {
    let functions = r#"[{"focal": [[0]], "mass": [1]}, {"focal": [[1]], "mass": [1]}]"#;
    let rules = [
        "dempster",
        "conjunctive",
        "yager",
        "dubois_prade",
        "pcr6",
        "disjunctive",
        "cautious",
        "murphy",
    ];
    for rule in rules {
        let input = format!(r#"{{"frame": 2, "rule": "{rule}", "mass_functions": {functions}}}"#);
        // Discounted by 0.5, the two certain functions are no longer dogmatic nor in total conflict.
        let out = evitrack(&["combine", "-", "--reliability", "0.5"], &input);
        assert_eq!(
            out.status.code(),
            Some(0),
            "{rule}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        let json: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        // κ = ½ · ½ for the conjunctive-based rules; the cautious rule's own ∅ mass is also ¼
        // here; Murphy's mean has κ = 2 · ¼ · ¼ = 1/8.
        let kappa = json["conflict_mass"].as_f64().unwrap();
        let want = if rule == "murphy" { 0.125 } else { 0.25 };
        assert!((kappa - want).abs() < 1e-12, "{rule}: {kappa}");
    }
    let input = format!(r#"{{"frame": 2, "rule": "cautious", "mass_functions": {functions}}}"#);
    let out = evitrack(&["combine", "-"], &input);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("dogmatic"));
    let out = evitrack(&["combine", "-", "--reliability", "1,0.5"], &input);
    assert_eq!(out.status.code(), Some(2), "function 0 stays dogmatic");
    let out = evitrack(&["combine", "-", "--reliability", "0.5,0.5,0.5"], &input);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("reliabilities"));
    // Yager on total conflict: a result (all on the frame), "inf" and a warning that says so.
    let input = format!(r#"{{"frame": 2, "rule": "yager", "mass_functions": {functions}}}"#);
    let out = evitrack(&["combine", "-"], &input);
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(json["conflict_level"], "inf");
    assert_eq!(json["focal"], serde_json::json!([[0, 1]]));
    assert!(String::from_utf8_lossy(&out.stderr).contains("still gives"));
}

#[test]
fn combine_bad_input_names_the_culprit_and_exits_2() {
    let cases = [
        (
            r#"{"frame": 4, "rule": "dempster", "mass_functions": [
                {"focal": [[0]], "mass": [1]}, {"focal": [[0], [9]], "mass": [0.5, 0.5]}]}"#,
            "mass function 1, focal set 1",
        ),
        (
            r#"{"frame": 4, "rule": "dempster", "mass_functions": [
                {"focal": [[0], [1]], "mass": [0.5, 0.2]}]}"#,
            "mass function 0",
        ),
        (
            r#"{"frame": 4, "rule": "dempster", "mass_functions": [
                {"focal": [[0], []], "mass": [0.5, 0.5]}]}"#,
            "focal set 1",
        ),
        (
            r#"{"frame": 4, "rule": "dempster", "typo": 1, "mass_functions": []}"#,
            "unknown field `typo`",
        ),
    ];
    for (input, expected) in cases {
        let out = evitrack(&["combine", "-"], input);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{input}: {stderr}");
        assert!(stderr.contains(expected), "{expected:?} not in {stderr}");
        assert!(out.stdout.is_empty());
    }
}

#[test]
fn render_writes_a_frame_and_refuses_poses_outside_the_workspace() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("frame.png");
    let path_text = path.to_str().unwrap();
    let out = evitrack(
        &["render", "--x", "-3", "--y", "45", "--out", path_text],
        "",
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let image = image::open(&path).unwrap();
    assert_eq!((image.width(), image.height()), (170, 120));
    let out = evitrack(
        &["render", "--x", "30", "--y", "45", "--out", path_text],
        "",
    );
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("outside the workspace"));
}

#[test]
fn simulate_writes_a_readable_dataset_and_rejects_bad_motions() {
    let dir = tempfile::tempdir().unwrap();
    let out_dir = dir.path().join("ds");
    let out_text = out_dir.to_str().unwrap();
    let motion = r#"kind = "circle", radius = 3, speed = 10, duration = 1, fps = 5"#;
    let out = evitrack(&["simulate", "--out", out_text, "--motion", motion], "");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let dataset = evitrack::dataset::Dataset::read(&out_dir).unwrap();
    assert_eq!(dataset.len(), 5);
    // A second run into the same folder would overwrite it: refused.
    let out = evitrack(&["simulate", "--out", out_text, "--motion", motion], "");
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("not empty"));
    let other = dir.path().join("other");
    let out = evitrack(
        &[
            "simulate",
            "--out",
            other.to_str().unwrap(),
            "--motion",
            r#"kind = "wobble""#,
        ],
        "",
    );
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("not a valid motion"));
}

#[test]
fn features_writes_one_named_column_per_feature_plus_truth() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("ds");
    let motion = r#"kind = "circle", radius = 4, speed = 10, duration = 1, fps = 4"#;
    let out = evitrack(
        &[
            "simulate",
            "--out",
            data.to_str().unwrap(),
            "--motion",
            motion,
        ],
        "",
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let out = evitrack(&["features", data.to_str().unwrap(), "--barycentre"], "");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8(out.stdout).unwrap();
    let mut lines = text.lines();
    let header = lines.next().unwrap();
    assert_eq!(
        header,
        "file,t,size_line0,size_line1,size_line2,size_line3,size_line4,size_line5,\
         barycentre_x,barycentre_y,x,y,theta1,theta2"
    );
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    assert_eq!(rows.len(), 4);
    for row in &rows {
        assert_eq!(row.len(), 14);
        for cell in &row[2..] {
            assert!(cell.parse::<f64>().unwrap().is_finite(), "{cell}");
        }
    }
    let out = evitrack(&["features", dir.path().join("none").to_str().unwrap()], "");
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("manifest.json"));
}

#[test]
fn train_then_track_reports_errors_and_refuses_broken_models() {
    let dir = tempfile::tempdir().unwrap();
    let path = |name: &str| dir.path().join(name).to_str().unwrap().to_string();
    let sample = r#"kind = "mesh", spacing = 2.0"#;
    let out = evitrack(
        &["simulate", "--out", &path("sample"), "--motion", sample],
        "",
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let test = r#"kind = "circle", radius = 5, speed = 10, duration = 2, fps = 10"#;
    let out = evitrack(
        &[
            "simulate",
            "--out",
            &path("test"),
            "--motion",
            test,
            "--seed",
            "3",
        ],
        "",
    );
    assert!(out.status.success());
    let out = evitrack(
        &[
            "train",
            &path("sample"),
            "--out",
            &path("model.json"),
            "--barycentre",
            "--states",
            "3",
        ],
        "",
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let table = String::from_utf8_lossy(&out.stdout);
    assert!(
        table.contains("barycentre_y") && table.contains("log-likelihood"),
        "{table}"
    );
    let out = evitrack(
        &[
            "track",
            &path("test"),
            "--model",
            &path("model.json"),
            "--out",
            &path("est.csv"),
        ],
        "",
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(stderr.contains("error mean"), "{stderr}");
    let estimates = std::fs::read_to_string(path("est.csv")).unwrap();
    assert_eq!(estimates.lines().count(), 21, "header + 20 frames");
    let out = evitrack(
        &[
            "track",
            &path("test"),
            "--model",
            &path("model.json"),
            "--out",
            &path("map.csv"),
            "--estimator",
            "map",
            "--selection",
            "split:2",
            "--constructor",
            "consonant",
        ],
        "",
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_ne!(std::fs::read_to_string(path("map.csv")).unwrap(), estimates);
    let out = evitrack(
        &[
            "track",
            &path("test"),
            "--model",
            &path("model.json"),
            "--selection",
            "split:0",
        ],
        "",
    );
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("N must be"));
    // A wrong state list, and a corrupted model file, are clear errors.
    let out = evitrack(
        &[
            "train",
            &path("sample"),
            "--out",
            &path("m2.json"),
            "--states",
            "2,2",
        ],
        "",
    );
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("2 counts for 6 features"));
    std::fs::write(
        path("broken.json"),
        "{\"format_version\": 1, \"sample_poses\": [",
    )
    .unwrap();
    let out = evitrack(
        &["track", &path("test"), "--model", &path("broken.json")],
        "",
    );
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("broken.json"));
}

#[test]
fn scenario_prints_every_setting_explained_and_the_text_runs_the_same() {
    let defaults = evitrack(&["scenario", "--defaults"], "");
    assert_eq!(defaults.status.code(), Some(0));
    let text = String::from_utf8(defaults.stdout).unwrap();
    let builtin = evitrack::scenario::ScenarioSet::builtin_default().unwrap();
    let parsed = evitrack::scenario::ScenarioSet::parse(&text, "printed").unwrap();
    assert_eq!(
        parsed.base.to_toml().unwrap(),
        builtin.base.to_toml().unwrap()
    );
    let lines: Vec<&str> = text.lines().collect();
    for (i, line) in lines.iter().enumerate().skip(1) {
        let setting = line.starts_with('[') || line.contains(" = ");
        if setting && !line.starts_with('#') {
            assert!(lines[i - 1].starts_with('#'), "no comment above `{line}`");
        }
    }
    assert!(
        defaults.stderr.is_empty(),
        "{}",
        String::from_utf8_lossy(&defaults.stderr)
    );

    let variant = evitrack(&["scenario", "scenarios/paper.toml", "--variant", "c"], "");
    let set = evitrack::scenario::ScenarioSet::load(std::path::Path::new("scenarios/paper.toml"))
        .unwrap();
    let c = set.variants.iter().find(|v| v.name() == "paper-c").unwrap();
    let printed = String::from_utf8(variant.stdout).unwrap();
    let again = evitrack::scenario::ScenarioSet::parse(&printed, "printed").unwrap();
    assert_eq!(again.base.to_toml().unwrap(), c.to_toml().unwrap());

    let unknown = evitrack(&["scenario", "scenarios/paper.toml", "--variant", "zz"], "");
    assert_eq!(unknown.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&unknown.stderr).contains("its variants are"));

    // The printed text of a file runs exactly as the file does.
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("small.toml");
    std::fs::write(&file, small_scenario("small", "")).unwrap();
    let printed = evitrack(&["scenario", file.to_str().unwrap()], "");
    let copy = dir.path().join("printed.toml");
    std::fs::write(&copy, &printed.stdout).unwrap();
    run_expecting("run", &file, &dir.path().join("a"), 0);
    run_expecting("run", &copy, &dir.path().join("b"), 0);
    let results =
        |side: &str| std::fs::read(dir.path().join(side).join("small/results.json")).unwrap();
    assert_eq!(results("a"), results("b"));
}
