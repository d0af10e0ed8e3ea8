//! `train`'s settings from the command line, built as a scenario's are (issue 26, item 4).

use super::*;

/// Issue 26, item 4: `train` builds its settings as a scenario does — any registered method,
/// a scenario file's sections, `--set` by dotted path, the options as shorthands for paths the
/// method reads, one `--threshold` spelling — and refuses what the method does not read.
#[test]
fn train_builds_its_settings_as_a_scenario_does() {
    let dir = tempfile::tempdir().unwrap();
    let path = |name: &str| dir.path().join(name).to_str().unwrap().to_string();
    simulate(&path("sample"), "1", SAMPLE_MESH);
    simulate(
        &path("validation"),
        "5",
        r#"kind = "random_path", speed = 8, duration = 3, fps = 10"#,
    );
    let train = |out: &str, extra: &[&str]| -> serde_json::Value {
        let out = path(out);
        let sample = path("sample");
        let mut args = vec![
            "train",
            sample.as_str(),
            "--out",
            out.as_str(),
            "--barycentre",
        ];
        args.extend(extra);
        ok(evitrack(&args));
        serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap()
    };
    let knn = train(
        "knn.json",
        &[
            "--method",
            "knn",
            "--set",
            "knn.k=3",
            "--weights",
            "uniform",
        ],
    );
    assert_eq!(knn["settings"]["k"], 3, "{knn}");
    assert_eq!(knn["settings"]["weights"], "uniform");
    // A scenario file's section is the base that options and --set replace values in.
    std::fs::write(
        path("base.toml"),
        "name = \"base\"\n[knn]\nk = 5\nweights = \"uniform\"\n",
    )
    .unwrap();
    let knn = train(
        "knn5.json",
        &["--method", "knn", "--scenario", &path("base.toml")],
    );
    assert_eq!(
        (
            knn["settings"]["k"].clone(),
            knn["settings"]["weights"].clone()
        ),
        (5.into(), "uniform".into())
    );
    let knn = train(
        "knn2.json",
        &[
            "--method",
            "knn",
            "--scenario",
            &path("base.toml"),
            "--k",
            "2",
        ],
    );
    assert_eq!(knn["settings"]["k"], 2);
    // One threshold spelling: learned by a quantile for the continuous tracker too.
    let continuous = train(
        "continuous.json",
        &[
            "--method",
            "continuous",
            "--validation",
            &path("validation"),
            "--threshold",
            "quantile:0.9",
        ],
    );
    assert_eq!(
        continuous["settings"]["learn_threshold"], true,
        "{}",
        continuous["settings"]
    );
    assert_eq!(continuous["settings"]["threshold_rule"]["quantile"], 0.9);
    // Every registered method trains from the command line, the temporal ones included.
    let temporal = train(
        "temporal.json",
        &[
            "--method",
            "evidential_temporal",
            "--validation",
            &path("validation"),
            "--states",
            "3",
        ],
    );
    assert_eq!(temporal["method"], "evidential_temporal");
    let refused = |extra: &[&str], expected: &str| {
        let sample = path("sample");
        let out = path("x.json");
        let mut args = vec!["train", sample.as_str(), "--out", out.as_str()];
        args.extend(extra);
        let bad = evitrack(&args);
        assert_eq!(bad.status.code(), Some(2));
        let stderr = String::from_utf8_lossy(&bad.stderr);
        assert!(stderr.contains(expected), "{stderr}");
    };
    refused(
        &["--method", "kalman"],
        "unknown method `kalman`: this build knows `evidential`",
    );
    refused(
        &["--method", "gp", "--set", "knn.k=3"],
        "--set sets `knn.k`, which `gp` does not read (it reads [gp])",
    );
    refused(
        &["--method", "knn", "--set", "knn.kk=3"],
        "unknown field `kk`",
    );
    refused(&["--method", "knn", "--k", "0"], "[knn]");
    refused(
        &["--method", "centre", "--threshold", "2"],
        "which `centre` does not read (it reads no settings)",
    );
    refused(
        &["--threshold", "often"],
        "must be a number ≥ 0, `inf`, `learned` or `quantile:Q`",
    );
}
