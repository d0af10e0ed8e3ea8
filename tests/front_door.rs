//! The front door: model files written by `run`, `sweep` and `train` track with `evitrack track`
//! and give exactly the run's estimates; `simulate --scenario` writes exactly the frames a run
//! uses; scenarios are checked before anything runs.

use std::path::Path;
use std::process::{Command, Output};

fn evitrack(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_evitrack"))
        .args(args)
        .output()
        .expect("the evitrack binary runs")
}

fn ok(out: Output) -> Output {
    assert!(
        out.status.success(),
        "exit {:?}: {}",
        out.status.code(),
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

/// A 2 mm sample mesh (100 poses).
const SAMPLE_MESH: &str = r#"kind = "mesh", spacing = 2.0"#;

/// `evitrack simulate --out OUT --seed SEED --motion MOTION`, which must succeed.
fn simulate(out: &str, seed: &str, motion: &str) {
    ok(evitrack(&[
        "simulate", "--out", out, "--seed", seed, "--motion", motion,
    ]));
}

/// The rows of `method` in a frames CSV, without the method and the motion label (a run names
/// the motion `test0:circle`, `track` after the dataset folder).
fn rows_without_label(path: &Path, method: &str) -> Vec<Vec<String>> {
    let mut reader = csv::Reader::from_path(path).unwrap();
    let header = reader.headers().unwrap().clone();
    assert_eq!((&header[0], &header[1]), ("method", "motion"));
    // The information limit is the run's (its feature maps at the true poses), not the model's.
    let limit = header.iter().position(|h| h == "limit_mm");
    reader
        .records()
        .map(|r| r.unwrap())
        .filter(|r| &r[0] == method)
        .map(|r| {
            (r.iter().enumerate())
                .filter(|&(i, _)| i >= 2 && Some(i) != limit)
                .map(|(_, v)| String::from(v))
                .collect()
        })
        .collect()
}

const SCENARIO: &str = r#"
name = "door"
learn_threshold = true
estimators = ["evidential", "evidential_temporal", "continuous", "continuous_temporal", "particle_filter", "knn", "gp", "centre"]
[sample]
motion = { kind = "mesh", spacing = 2.0 }
[validation]
kind = "random_path"
speed = 8.0
duration = 4.0
fps = 10.0
[[tests]]
kind = "circle"
radius = 4.0
speed = 10.0
duration = 2.0
fps = 10.0
[features.barycentre]
enabled = true
[model]
states = 4
[track]
constructor = "consonant"
selection = { policy = "lowest_conflict", min_size = 2 }

# Also the render check from the sample frames (a share its 40 validation frames can set): the
# model files carry its limits, and `track --samples` applies them.
[[sweep.variant]]
name = "map"
set = { "track.estimator" = "map", "track.constructor" = "bayesian", "confidence.render_check" = true, "confidence.render_share" = 0.05 }

# Also a region quantile per half of the workspace: the model files carry it to `track`.
[[sweep.variant]]
name = "sparse"
set = { "sample.keep_every" = 2, "confidence.cells" = [2, 1] }
"#;

/// Tracks the scenario's test motion (as `simulate --scenario` writes it) with a model file and
/// checks the estimates equal the run's `frames.csv`.
fn assert_model_reproduces_run(dir: &Path, scenario: &Path, variant: Option<&str>, run_dir: &Path) {
    let label = variant.unwrap_or("base");
    let test = dir.join(format!("test-{label}"));
    let mut args = vec![
        "simulate",
        "--scenario",
        scenario.to_str().unwrap(),
        "--part",
        "test",
        "--out",
        test.to_str().unwrap(),
    ];
    if let Some(v) = variant {
        args.extend(["--variant", v]);
    }
    ok(evitrack(&args));
    // The map variant's models carry the render check's limits: they need the sample frames.
    let samples = dir.join(format!("samples-{label}"));
    let checked = variant == Some("map");
    if checked {
        let mut args = args.clone();
        args[4] = "sample";
        args[6] = samples.to_str().unwrap();
        ok(evitrack(&args));
    }
    let methods = [
        "evidential",
        "evidential_temporal",
        "continuous",
        "continuous_temporal",
        "particle_filter",
        "knn",
        "gp",
        "centre",
    ];
    for method in methods {
        let model = run_dir.join(evitrack::report::model_file_name(method));
        let estimates = dir.join(format!("est-{label}-{method}.csv"));
        let mut args = vec![
            "track",
            test.to_str().unwrap(),
            "--model",
            model.to_str().unwrap(),
            "--out",
            estimates.to_str().unwrap(),
        ];
        if checked && method != "centre" {
            args.extend(["--samples", samples.to_str().unwrap()]);
        }
        ok(evitrack(&args));
        let tracked = rows_without_label(&estimates, method);
        let ran = rows_without_label(&run_dir.join("frames.csv"), method);
        assert_eq!(tracked.len(), 20);
        assert_eq!(tracked, ran, "{label}, {method}: track and run disagree");
    }
}

#[test]
fn run_and_sweep_models_track_to_the_runs_own_estimates() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = dir.path().join("door.toml");
    std::fs::write(&scenario, SCENARIO).unwrap();
    let out = dir.path().join("out");
    let out_text = out.to_str().unwrap();
    ok(evitrack(&[
        "run",
        scenario.to_str().unwrap(),
        "--out",
        out_text,
    ]));
    let model: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(out.join("door/model-evidential.json")).unwrap(),
    )
    .unwrap();
    // The model file carries what tracking needs: settings, learned threshold, provenance.
    assert_eq!(model["method"], "evidential");
    assert_eq!(model["track"]["constructor"], "consonant");
    assert_eq!(model["threshold_learned"], true);
    assert!(model["track"]["conflict_threshold"].is_number());
    assert_eq!(model["validation_errors"].as_array().unwrap().len(), 8);
    assert_eq!(model["provenance"]["scenario"], "door");
    assert_eq!(model["provenance"]["seed"], 1);
    assert_eq!(
        model["provenance"]["crate_version"],
        env!("CARGO_PKG_VERSION")
    );
    assert_model_reproduces_run(dir.path(), &scenario, None, &out.join("door"));

    let sweep_out = dir.path().join("sweep");
    ok(evitrack(&[
        "sweep",
        scenario.to_str().unwrap(),
        "--out",
        sweep_out.to_str().unwrap(),
    ]));
    for variant in ["map", "sparse"] {
        let run_dir = sweep_out.join(format!("door-{variant}"));
        assert_model_reproduces_run(dir.path(), &scenario, Some(variant), &run_dir);
    }
    // The sparse variant's regions came from a half's own quantile where the half had frames
    // enough, and `track` gave the same (above).
    let model: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(sweep_out.join("door-sparse/model-continuous.json")).unwrap(),
    )
    .unwrap();
    let cells = &model["calibration"]["cell_radii"];
    assert_eq!(cells["cells"], serde_json::json!([2, 1]), "{model}");
    assert!(
        cells["radii"]
            .as_array()
            .unwrap()
            .iter()
            .any(|r| r.is_number()),
        "{cells}"
    );
    // The map variant's model files carry the render check's limits (applied by `track --samples`
    // above, frame for frame); the check made some of the run's frames abstain.
    let map = sweep_out.join("door-map");
    let model: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(map.join("model-continuous.json")).unwrap())
            .unwrap();
    assert!(
        model["calibration"]["render_limit_px"].is_number(),
        "{model}"
    );
    let frames = std::fs::read_to_string(map.join("frames.csv")).unwrap();
    assert!(
        frames.contains("render_mismatch"),
        "no frame abstained by the check"
    );
    // Without --samples `track` says what it leaves out; with them, a model without a limit is
    // refused.
    let test = dir.path().join("test-map");
    let samples = dir.path().join("samples-map");
    let plain = evitrack(&[
        "track",
        test.to_str().unwrap(),
        "--model",
        map.join("model-continuous.json").to_str().unwrap(),
    ]);
    let plain = ok(plain);
    let stderr = String::from_utf8_lossy(&plain.stderr);
    assert!(stderr.contains("pass --samples"), "{stderr}");
    let refused = evitrack(&[
        "track",
        test.to_str().unwrap(),
        "--model",
        map.join("model-centre.json").to_str().unwrap(),
        "--samples",
        samples.to_str().unwrap(),
    ]);
    assert_eq!(refused.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&refused.stderr);
    assert!(stderr.contains("no render-check limit"), "{stderr}");
    // The variant name can also be given in full; an unknown one lists the known ones.
    let bad = evitrack(&[
        "simulate",
        "--scenario",
        scenario.to_str().unwrap(),
        "--variant",
        "dense",
        "--out",
        dir.path().join("x").to_str().unwrap(),
    ]);
    assert_eq!(bad.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&bad.stderr);
    assert!(stderr.contains("door-map, door-sparse"), "{stderr}");
}

#[test]
fn simulate_sample_part_writes_the_trajectory_the_run_trains_on() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = dir.path().join("s.toml");
    std::fs::write(
        &scenario,
        r#"
name = "s"
[sample]
motion = { kind = "mesh", spacing = 2.0 }
adaptive = { threshold = 0.1, max_samples = 130, max_rounds = 2 }
[[tests]]
kind = "circle"
radius = 4.0
speed = 10.0
duration = 1.0
fps = 10.0
[[sweep.variant]]
name = "sparse"
set = { "sample.keep_every" = 2, "sample.adaptive" = {} }
"#
        .replace(", \"sample.adaptive\" = {}", ""),
    )
    .unwrap();
    let out = dir.path().join("out");
    ok(evitrack(&[
        "sweep",
        scenario.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]));
    let sample = dir.path().join("sample");
    ok(evitrack(&[
        "simulate",
        "--scenario",
        scenario.to_str().unwrap(),
        "--variant",
        "sparse",
        "--out",
        sample.to_str().unwrap(),
    ]));
    let written = evitrack::dataset::Dataset::read(&sample).unwrap();
    let mut reader = csv::Reader::from_path(out.join("s-sparse/samples.csv")).unwrap();
    let trained: Vec<[f64; 2]> = reader
        .records()
        .map(|r| {
            let r = r.unwrap();
            [r[0].parse().unwrap(), r[1].parse().unwrap()]
        })
        .collect();
    // Every other node of the 100-node mesh, then the adaptive samples, in the run's order.
    assert!(trained.len() > 50, "the adaptive rounds add samples");
    assert_eq!(written.len(), trained.len());
    for (frame, pose) in written.frames.iter().zip(&trained) {
        let t = frame.truth.unwrap();
        assert_eq!([t.x, t.y], *pose);
    }
}

#[test]
fn train_with_a_validation_dataset_learns_threshold_and_feature_errors() {
    let dir = tempfile::tempdir().unwrap();
    let path = |name: &str| dir.path().join(name).to_str().unwrap().to_string();
    simulate(&path("sample"), "1", SAMPLE_MESH);
    simulate(
        &path("validation"),
        "5",
        r#"kind = "random_path", speed = 8, duration = 3, fps = 10"#,
    );
    let sample = path("sample");
    let train = |out: &str, extra: &[&str]| {
        let out = path(out);
        let mut args = vec![
            "train",
            &sample,
            "--out",
            &out,
            "--barycentre",
            "--states",
            "4",
        ];
        args.extend(extra);
        let output = ok(evitrack(&args));
        let model: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
        (output, model)
    };
    let (output, learned) = train("learned.json", &["--validation", &path("validation")]);
    assert_eq!(learned["threshold_learned"], true);
    let threshold = learned["track"]["conflict_threshold"].as_f64().unwrap();
    assert!(threshold.is_finite() && threshold > 0.0, "{threshold}");
    let errors = learned["validation_errors"].as_array().unwrap();
    assert_eq!(errors.len(), 8);
    assert!(errors.iter().all(|e| e.as_f64().unwrap() > 0.0));
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(stderr.contains("(learned)"), "{stderr}");

    let (_, kept) = train(
        "kept.json",
        &["--validation", &path("validation"), "--threshold", "0.5"],
    );
    assert_eq!(kept["threshold_learned"], false);
    assert_eq!(kept["track"]["conflict_threshold"], 0.5);
    assert_eq!(kept["validation_errors"], learned["validation_errors"]);

    let (_, plain) = train("plain.json", &["--constructor", "consonant"]);
    assert!(plain["validation_errors"].is_null());
    assert_eq!(plain["track"]["conflict_threshold"], "inf");
    assert_eq!(plain["track"]["constructor"], "consonant");
    // The model's own settings are used unless the command line replaces them.
    let tracked = ok(evitrack(&[
        "track",
        &path("validation"),
        "--model",
        &path("learned.json"),
    ]));
    assert_eq!(String::from_utf8_lossy(&tracked.stdout).lines().count(), 31);
    let bad = evitrack(&[
        "track",
        &path("validation"),
        "--model",
        &path("learned.json"),
        "--selection",
        "lowest:9",
    ]);
    assert_eq!(bad.status.code(), Some(2));
    assert!(
        String::from_utf8_lossy(&bad.stderr).contains("more than the model's 8 features"),
        "{}",
        String::from_utf8_lossy(&bad.stderr)
    );
}

#[test]
fn too_many_features_are_refused_before_anything_runs() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = dir.path().join("wide.toml");
    // Exit status 2 and the message; refused by the check: nothing simulated or written.
    let refused = |toml: &str| -> String {
        std::fs::write(&scenario, toml).unwrap();
        let out = evitrack(&[
            "run",
            scenario.to_str().unwrap(),
            "--out",
            dir.path().to_str().unwrap(),
        ]);
        assert_eq!(out.status.code(), Some(2));
        assert!(!dir.path().join("wide").exists());
        String::from_utf8_lossy(&out.stderr).into_owned()
    };
    let stderr = refused(
        "name = \"wide\"\nestimators = [\"evidential\", \"knn\"]\n[features]\n\
         size_functions = { lines = 65 }\n[model]\nstates = 3\n",
    );
    assert!(
        stderr.contains("65 features") && stderr.contains("at most 64"),
        "{stderr}"
    );
    // The continuous tracker's own cap, and how to get past it; over time, one bit less.
    let stderr = refused(
        "name = \"wide\"\nestimators = [\"continuous\", \"knn\"]\n[features]\n\
         size_functions = { lines = 65 }\n[model]\nstates = 3\n",
    );
    assert!(
        stderr.contains("65 features, but the continuous tracker takes at most 64")
            && stderr.contains("without \"continuous\" and \"particle_filter\" in `estimators`"),
        "{stderr}"
    );
    let stderr = refused(
        "name = \"wide\"\nestimators = [\"continuous_temporal\"]\n[features]\n\
         size_functions = { lines = 64 }\n[model]\nstates = 3\n",
    );
    assert!(
        stderr.contains("64 features, but the continuous tracker over time takes at most 63"),
        "{stderr}"
    );
    // 64 features are the paper's tracker's most; its temporal form carries one more bit.
    let stderr = refused(
        "name = \"wide\"\nestimators = [\"evidential\", \"evidential_temporal\"]\n\
         [features]\nsize_functions = { lines = 64 }\n[model]\nstates = 3\n",
    );
    assert!(
        stderr.contains("64 features, but the temporal evidential tracker takes at most 63"),
        "{stderr}"
    );
}

#[test]
fn every_method_trains_and_tracks_from_the_command_line() {
    let dir = tempfile::tempdir().unwrap();
    let path = |name: &str| dir.path().join(name).to_str().unwrap().to_string();
    simulate(&path("sample"), "1", SAMPLE_MESH);
    simulate(
        &path("test"),
        "4",
        r#"kind = "circle", radius = 5, speed = 10, duration = 2, fps = 10"#,
    );
    let mut means = Vec::new();
    for method in ["knn", "gp", "centre", "continuous"] {
        let model = path(&format!("{method}.json"));
        ok(evitrack(&[
            "train",
            &path("sample"),
            "--out",
            &model,
            "--barycentre",
            "--method",
            method,
        ]));
        let text = std::fs::read_to_string(&model).unwrap();
        let file: serde_json::Value = serde_json::from_str(&text).unwrap();
        assert_eq!(file["method"], method);
        let out = ok(evitrack(&["track", &path("test"), "--model", &model]));
        let csv = String::from_utf8_lossy(&out.stdout).to_string();
        assert_eq!(csv.lines().count(), 21, "{csv}");
        assert!(csv.lines().skip(1).all(|l| l.starts_with(method)), "{csv}");
        let stderr = String::from_utf8_lossy(&out.stderr).to_string();
        let mean: f64 = stderr
            .split("error mean ")
            .nth(1)
            .and_then(|r| r.split(' ').next())
            .and_then(|m| m.parse().ok())
            .unwrap_or_else(|| panic!("no mean error in {stderr}"));
        means.push(mean);
        // Tracker options belong to evidential models.
        let bad = evitrack(&[
            "track",
            &path("test"),
            "--model",
            &model,
            "--constructor",
            "consonant",
        ]);
        assert_eq!(bad.status.code(), Some(2));
        assert!(String::from_utf8_lossy(&bad.stderr).contains("evidential models only"));
    }
    // On the 2 mm mesh with 8 features: the regressors and the continuous tracker beat knowing
    // nothing by far.
    assert!(
        means[0] < 1.0 && means[1] < 1.0 && means[2] > 3.0 && means[3] < 1.0,
        "{means:?}"
    );
    // The continuous tracker takes a threshold and a selection at training, not a constructor;
    // a learned threshold needs a validation dataset.
    let model = path("continuous-fixed.json");
    ok(evitrack(&[
        "train",
        &path("sample"),
        "--out",
        &model,
        "--barycentre",
        "--method",
        "continuous",
        "--threshold",
        "12.5",
        "--selection",
        "lowest:5",
    ]));
    let file: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&model).unwrap()).unwrap();
    assert_eq!(file["conflict_threshold"], 12.5);
    assert_eq!(file["settings"]["selection"]["min_size"], 5);
    let bad = evitrack(&[
        "train",
        &path("sample"),
        "--out",
        &path("y.json"),
        "--method",
        "continuous",
        "--constructor",
        "consonant",
    ]);
    assert_eq!(bad.status.code(), Some(2));
    assert!(
        String::from_utf8_lossy(&bad.stderr)
            .contains("--constructor sets `track.constructor`, which `continuous` does not read"),
        "{}",
        String::from_utf8_lossy(&bad.stderr)
    );
    let bad = evitrack(&[
        "train",
        &path("sample"),
        "--out",
        &path("x.json"),
        "--method",
        "knn",
        "--states",
        "3",
    ]);
    assert_eq!(bad.status.code(), Some(2));
    assert!(
        String::from_utf8_lossy(&bad.stderr)
            .contains("--states sets `model.states`, which `knn` does not read (it reads [knn])"),
        "{}",
        String::from_utf8_lossy(&bad.stderr)
    );
}

/// Issue 15, item 6: the manifest's `camera.polarity` is honoured. Inverted frames declared
/// `dark_on_bright` give the features of the original frames with the default configuration; a
/// configuration or model of the other polarity is an error that says how to fix it.
#[test]
fn the_manifests_polarity_is_honoured_or_refused() {
    use evitrack::dataset::{Dataset, Polarity};
    let dir = tempfile::tempdir().unwrap();
    let path = |name: &str| dir.path().join(name).to_str().unwrap().to_string();
    simulate(
        &path("bright"),
        "4",
        r#"kind = "circle", radius = 5, speed = 10, duration = 1, fps = 10"#,
    );
    let mut dark = Dataset::read(path("bright")).unwrap();
    for frame in &mut dark.frames {
        for p in frame.image.pixels_mut() {
            p.0[0] = 255 - p.0[0];
        }
    }
    dark.manifest.camera.polarity = Polarity::DarkOnBright;
    dark.write(path("dark")).unwrap();
    let features = |dataset: &str| -> Vec<f64> {
        let out = ok(evitrack(&["features", &path(dataset), "--barycentre"]));
        let text = String::from_utf8_lossy(&out.stdout).to_string();
        let mut reader = csv::Reader::from_reader(text.as_bytes());
        let records: Vec<csv::StringRecord> = reader.records().map(|r| r.unwrap()).collect();
        records
            .iter()
            .flat_map(|r| {
                (2..10)
                    .map(|c| r[c].parse::<f64>().unwrap())
                    .collect::<Vec<_>>()
            })
            .collect()
    };
    let (bright, dark) = (features("bright"), features("dark"));
    assert_eq!(bright.len(), 80);
    for (b, d) in bright.iter().zip(&dark) {
        assert!((b - d).abs() <= 0.01 * b.abs().max(1.0), "{b} against {d}");
    }
    // A configuration that says otherwise is refused, naming both and the fix.
    std::fs::write(path("bright.toml"), "polarity = \"bright_on_dark\"\n").unwrap();
    let bad = evitrack(&["features", &path("dark"), "--config", &path("bright.toml")]);
    assert_eq!(bad.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&bad.stderr).to_string();
    assert!(
        stderr.contains("camera.polarity = dark_on_bright")
            && stderr.contains("polarity = \"dark_on_bright\""),
        "{stderr}"
    );
    // So is a model trained on bright frames, tracking dark ones.
    simulate(&path("sample"), "1", SAMPLE_MESH);
    ok(evitrack(&[
        "train",
        &path("sample"),
        "--out",
        &path("model.json"),
        "--method",
        "knn",
    ]));
    let bad = evitrack(&["track", &path("dark"), "--model", &path("model.json")]);
    assert_eq!(bad.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&bad.stderr).contains("camera.polarity = dark_on_bright"));
    ok(evitrack(&[
        "track",
        &path("bright"),
        "--model",
        &path("model.json"),
    ]));
}

mod train_settings;

/// `train` with `confidence.render_check` learns the check's limit on the validation frames and
/// keeps it in the model file; `track --samples` then makes frames under a dark box abstain that
/// it answers without the check, and frames with specks for their stray pixels.
#[test]
fn train_learns_the_render_check_and_track_applies_it_under_a_dark_box_and_specks() {
    let dir = tempfile::tempdir().unwrap();
    let path = |name: &str| dir.path().join(name).to_str().unwrap().to_string();
    let simulate = |name: &str, seed: &str, motion: &str| {
        ok(evitrack(&[
            "simulate",
            "--out",
            &path(name),
            "--seed",
            seed,
            "--motion",
            motion,
        ]));
    };
    simulate("sample", "1", r#"kind = "mesh", spacing = 1.0"#);
    let path_motion = r#"kind = "random_path", seed = 5, speed = 6, duration = 10, fps = 10"#;
    simulate("validation", "2", path_motion);
    simulate("test", "3", &path_motion.replace("seed = 5", "seed = 9"));
    // A dark box over part of every test frame, and white specks along the bottom row of every
    // fourth (frames are numbered in file-name order).
    let mut files: Vec<_> = std::fs::read_dir(dir.path().join("test/frames"))
        .unwrap()
        .map(|entry| entry.unwrap().path())
        .collect();
    files.sort();
    for (i, file) in files.iter().enumerate() {
        let mut frame = image::open(file).unwrap().to_luma8();
        for y in 12..60 {
            for x in 38..86 {
                frame.put_pixel(x, y, image::Luma([0]));
            }
        }
        if i % 4 == 0 {
            let bottom = frame.height() - 1;
            for k in 0..10 {
                frame.put_pixel(5 + 15 * k, bottom, image::Luma([255]));
            }
        }
        frame.save(file).unwrap();
    }
    let train = |extra: &[&str]| {
        let mut args = vec![
            "train",
            &path("sample"),
            "--validation",
            &path("validation"),
            "--method",
            "continuous",
            "--barycentre",
            "--out",
            &path("model.json"),
        ]
        .into_iter()
        .map(String::from)
        .collect::<Vec<_>>();
        args.extend(extra.iter().map(|s| s.to_string()));
        evitrack(&args.iter().map(String::as_str).collect::<Vec<_>>())
    };
    let check = ["--set", "confidence.render_check=true"];
    ok(train(
        &[&check[..], &["--set", "confidence.render_share=0.02"]].concat(),
    ));
    let model: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(path("model.json")).unwrap()).unwrap();
    let limit = model["calibration"]["render_limit_px"]
        .as_f64()
        .expect("a limit");
    assert!(limit > 0.0 && limit < 500.0, "{limit}");
    // The simulator's clean validation frames show no stray pixel.
    assert_eq!(model["calibration"]["stray_limit_px"], 0.0, "{model}");
    let track = |samples: bool, out: &str| {
        let (test, model, sample, out) =
            (path("test"), path("model.json"), path("sample"), path(out));
        let mut args = vec!["track", &test, "--model", &model, "--out", &out];
        if samples {
            args.extend(["--samples", &sample]);
        }
        ok(evitrack(&args));
        std::fs::read_to_string(&out).unwrap()
    };
    let (plain, checked) = (track(false, "plain.csv"), track(true, "checked.csv"));
    assert!(!plain.contains("render_mismatch") && !plain.contains("stray_pixels"));
    let rows_with =
        |word: &str| -> Vec<&str> { (checked.lines()).filter(|row| row.contains(word)).collect() };
    let flagged = (checked.lines())
        .filter(|row| row.contains("render_mismatch") || row.contains("stray_pixels"))
        .count();
    // The check abstains on frames the method answered, and leaves its own abstentions alone.
    let abstained = |csv: &str| csv.matches("abstained").count();
    assert_eq!(abstained(&checked), abstained(&plain) + flagged);
    assert!(!rows_with("render_mismatch").is_empty(), "{checked}");
    // Every speckled frame the method answered abstains for its stray pixels (so do frames where
    // the dark box cuts a piece off the robot's silhouette).
    let frame = |row: &str| row.split(',').nth(2).unwrap().parse::<usize>().unwrap();
    let stray: Vec<usize> = rows_with("stray_pixels").into_iter().map(frame).collect();
    let answered = (plain.lines().skip(1))
        .filter(|row| !row.contains("abstained"))
        .map(frame);
    let speckled: Vec<usize> = answered.filter(|i| i % 4 == 0).collect();
    assert!(speckled.len() > 10, "{plain}");
    assert!(speckled.iter().all(|i| stray.contains(i)), "{checked}");
    // The simulator's renderer is not a model file's to use.
    let refused = train(
        &[
            &check[..],
            &["--set", "confidence.render_from=\"simulator\""],
        ]
        .concat(),
    );
    assert_eq!(refused.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&refused.stderr);
    assert!(stderr.contains("does not have"), "{stderr}");
}
