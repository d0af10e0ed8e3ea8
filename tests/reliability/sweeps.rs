//! Issue 15's reproducers for scenarios and sweeps: checks before anything runs, killed and
//! failing sweeps, the smaller messages.

use super::*;

/// The error of a scenario text: it must not check.
fn scenario_error(text: &str) -> String {
    match ScenarioSet::parse(text, "bomb.toml") {
        Ok(_) => panic!("accepted:\n{text}"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn a_grid_is_counted_before_it_is_expanded() {
    // 10⁶ variants in 700 bytes once took 11 minutes and 2 GB to validate.
    let keys = [
        "sim.noise.sigma",
        "model.seed",
        "seed",
        "knn.k",
        "gp.starts",
        "sample.keep_every",
    ];
    let grid: String = keys
        .iter()
        .map(|k| format!("\"{k}\" = [1, 2, 3, 4, 5, 6, 7, 8, 9, 10]\n"))
        .collect();
    let clock = std::time::Instant::now();
    let error = scenario_error(&format!("name = \"g\"\n[sweep.grid]\n{grid}"));
    assert!(clock.elapsed().as_secs_f64() < 5.0);
    assert!(error.contains("1000000 variants"), "{error}");
    assert!(error.contains("more than the 1000"), "{error}");
    // 1000 is within: 10 × 10 × 10, each checked.
    let grid: String = keys[..3]
        .iter()
        .map(|k| format!("\"{k}\" = [1, 2, 3, 4, 5, 6, 7, 8, 9, 10]\n"))
        .collect();
    let set = ScenarioSet::parse(&format!("name = \"g\"\n[sweep.grid]\n{grid}"), "g.toml").unwrap();
    assert_eq!(set.variants.len(), 1000);
    // …but 1000 variants × 11 seeds is more runs than a sweep may ask for.
    let error = set
        .seeded(Some(&SeedList::Count(11)))
        .unwrap_err()
        .to_string();
    assert!(error.contains("11000 runs, more than the 10000"), "{error}");
}

#[test]
fn settings_outside_their_ranges_are_refused_before_anything_runs() {
    for (section, setting, needle) in [
        (
            "sim.robot",
            "solver_iterations = 1000000",
            "robot.solver_iterations = 1000000 is outside its range 1..=100",
        ),
        (
            "sim.robot",
            "max_settle_steps = 1000000000",
            "robot.max_settle_steps = 1000000000 is outside",
        ),
        (
            "sim.robot",
            "dt = 1e-9",
            "robot.dt = 0.000000001 is outside",
        ),
        ("sim.noise", "sigma = 1e308", "noise.sigma"),
        ("model.hmm", "max_iterations = 100000000", "max_iterations"),
        ("model", "states = 1000", "must be in 1..=64"),
        ("knn", "k = 1000000", "knn.k"),
        ("gp", "max_fit_samples = 100000", "gp.max_fit_samples"),
    ] {
        let error = scenario_error(&format!("name = \"r\"\n[{section}]\n{setting}\n"));
        assert!(
            error.contains(needle),
            "{setting}: {needle:?} not in {error}"
        );
    }
}

#[test]
fn motions_are_checked_with_the_scenario_not_once_the_run_starts() {
    for (motion, needle) in [
        (
            "kind = \"circle\"\nradius = 4.0\nspeed = 10.0\nduration = 2.0\nfps = 0.0",
            "fps",
        ),
        (
            "kind = \"points\"\npoints = [[0.0, 47.0], [30.0, 47.0]]",
            "outside",
        ),
    ] {
        let error = scenario_error(&format!("name = \"m\"\n[[tests]]\n{motion}\n"));
        assert!(
            error.contains("[[tests]] 0") && error.contains(needle),
            "{error}"
        );
    }
}

/// Every file under `dir`, relative, sorted.
fn files_under(dir: &std::path::Path) -> Vec<std::path::PathBuf> {
    let mut files = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for entry in std::fs::read_dir(&d).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                stack.push(path);
            } else {
                files.push(path.strip_prefix(dir).unwrap().to_path_buf());
            }
        }
    }
    files.sort();
    files
}

const KILL_SCENARIO: &str = r#"
name = "kill"
estimators = ["evidential", "knn"]
[sample]
motion = { kind = "mesh", spacing = 2.0 }
[validation]
kind = "circle"
radius = 4.0
speed = 10.0
duration = 2.0
fps = 10.0
[[tests]]
kind = "circle"
radius = 4.0
speed = 10.0
duration = 2.0
fps = 10.0
[sweep.grid]
"sim.noise.sigma" = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]
"#;

#[test]
fn a_killed_sweep_leaves_whole_files_and_resumes_to_the_same_bytes() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = dir.path().join("kill.toml");
    std::fs::write(&scenario, KILL_SCENARIO).unwrap();
    let sweep = |out: &std::path::Path| {
        std::process::Command::new(env!("CARGO_BIN_EXE_evitrack"))
            .args(["sweep", scenario.to_str().unwrap(), "--jobs", "2", "--out"])
            .arg(out)
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null())
            .spawn()
            .unwrap()
    };
    let reference = dir.path().join("reference");
    let clock = std::time::Instant::now();
    assert!(sweep(&reference).wait().unwrap().success());
    let full = clock.elapsed();
    let expected = files_under(&reference);
    // Two runs of the same files and seeds are byte-identical: a second full sweep is.
    let again = dir.path().join("again");
    assert!(sweep(&again).wait().unwrap().success());
    assert_eq!(files_under(&again), expected);
    for file in &expected {
        assert_eq!(
            std::fs::read(again.join(file)).unwrap(),
            std::fs::read(reference.join(file)).unwrap(),
            "{file:?}"
        );
    }
    // Killed at several moments of the sweep, then run again.
    let mut kept_some = false;
    for share in [0.1, 0.3, 0.5, 0.7, 0.9] {
        let out = dir.path().join(format!("killed-{share}"));
        let mut child = sweep(&out);
        std::thread::sleep(full.mul_f64(share));
        let _ = child.kill();
        child.wait().unwrap();
        if !out.exists() {
            continue;
        }
        for file in files_under(&out) {
            let name = file.file_name().unwrap().to_string_lossy().into_owned();
            let bytes = std::fs::read(out.join(&file)).unwrap();
            if name.ends_with(".partial") {
                continue;
            }
            if name == "sweep.json" {
                let json: serde_json::Value = serde_json::from_slice(&bytes)
                    .unwrap_or_else(|e| panic!("{share}: sweep.json is cut: {e}"));
                if json["complete"] == false {
                    assert!(!json["pending"].as_array().unwrap().is_empty());
                }
                continue;
            }
            // Every other file is whole: the very bytes a full sweep writes.
            assert_eq!(
                bytes,
                std::fs::read(reference.join(&file)).unwrap(),
                "{share}: {file:?}"
            );
            kept_some |= name == "results.json";
        }
        assert!(sweep(&out).wait().unwrap().success());
        assert_eq!(files_under(&out), expected, "{share}: after the rerun");
        for file in &expected {
            assert_eq!(
                std::fs::read(out.join(file)).unwrap(),
                std::fs::read(reference.join(file)).unwrap(),
                "{share}: {file:?} after the rerun"
            );
        }
    }
    assert!(
        kept_some,
        "no kill left a finished run to resume (full sweep {full:?})"
    );
}

/// A rerun after a code change must not hand back the old numbers: a run is kept only when
/// `producer.json` says this very build (and the same feature programs) wrote it.
#[test]
fn a_sweep_resumes_only_runs_this_build_wrote() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = dir.path().join("kill.toml");
    let two_variants = KILL_SCENARIO.replace("[1.0, 2.0, 3.0, 4.0, 5.0, 6.0]", "[1.0, 2.0]");
    std::fs::write(&scenario, two_variants).unwrap();
    let out = dir.path().join("out");
    let sweep = || {
        let output = std::process::Command::new(env!("CARGO_BIN_EXE_evitrack"))
            .args(["sweep", scenario.to_str().unwrap(), "--out"])
            .arg(&out)
            .output()
            .unwrap();
        assert!(output.status.success());
        String::from_utf8(output.stderr).unwrap()
    };
    sweep();
    let producers: Vec<_> = files_under(&out)
        .into_iter()
        .filter(|f| f.ends_with("producer.json"))
        .collect();
    assert_eq!(producers.len(), 2, "{producers:?}");
    let text = std::fs::read_to_string(out.join(&producers[0])).unwrap();
    let json: serde_json::Value = serde_json::from_str(&text).unwrap();
    assert_eq!(json["evitrack"], env!("CARGO_PKG_VERSION"));
    assert_eq!(json["build"].as_str().unwrap().len(), 32, "{text}");
    let again = sweep();
    assert!(again.contains("resuming: 2 of 2 runs"), "{again}");
    // One run as another build wrote it, one from before runs recorded their producer.
    let build = json["build"].as_str().unwrap();
    std::fs::write(
        out.join(&producers[0]),
        text.replace(build, "0123456789abcdef0123456789abcdef"),
    )
    .unwrap();
    std::fs::remove_file(out.join(&producers[1])).unwrap();
    let rerun = sweep();
    assert!(rerun.contains("running again 2 runs"), "{rerun}");
    assert!(
        rerun.contains("written by another build of evitrack"),
        "{rerun}"
    );
    assert!(rerun.contains("written before runs recorded"), "{rerun}");
    assert!(!rerun.contains("resuming"), "{rerun}");
    assert_eq!(
        std::fs::read_to_string(out.join(&producers[0])).unwrap(),
        text
    );
}

#[test]
fn every_write_failure_of_a_sweep_is_named_and_an_unwritable_out_is_refused_first() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = dir.path().join("kill.toml");
    std::fs::write(&scenario, KILL_SCENARIO).unwrap();
    let scenario = scenario.to_str().unwrap();
    // A file where two run folders and the sweep's CSV should go.
    let out = dir.path().join("out");
    std::fs::create_dir_all(out.join("sweep.csv")).unwrap();
    for variant in ["kill-noise.sigma=1.0", "kill-noise.sigma=4.0"] {
        std::fs::write(out.join(variant), "in the way").unwrap();
    }
    let result = evitrack(&["sweep", scenario, "--out", out.to_str().unwrap()], "");
    let stderr = String::from_utf8_lossy(&result.stderr);
    assert_eq!(result.status.code(), Some(2), "{stderr}");
    for needle in [
        "failed: kill-noise.sigma=1.0",
        "failed: kill-noise.sigma=4.0",
        "sweep.csv",
    ] {
        assert!(stderr.contains(needle), "{needle:?} not in {stderr}");
    }
    // The other runs are written, and the sweep file says which are not.
    assert!(out
        .join("kill-noise.sigma=2.0")
        .join("results.json")
        .is_file());
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("sweep.json")).unwrap()).unwrap();
    assert_eq!(json["complete"], false);
    assert_eq!(
        json["pending"],
        serde_json::json!(["kill-noise.sigma=1.0", "kill-noise.sigma=4.0"])
    );
    // An --out that cannot be created fails at once, before any variant runs: on a 0.25 mm
    // sample mesh a run takes over 5 s (measured), the refusal well under 2 s.
    let slow = dir.path().join("slow.toml");
    std::fs::write(
        &slow,
        KILL_SCENARIO
            .replace("spacing = 1.0", "spacing = 0.25")
            .replace(
                "[sweep.grid]\n\"sim.noise.sigma\" = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]\n",
                "",
            ),
    )
    .unwrap();
    let blocked = out.join("kill-noise.sigma=1.0").join("sub");
    for command in ["sweep", "run"] {
        let clock = std::time::Instant::now();
        let result = evitrack(
            &[
                command,
                slow.to_str().unwrap(),
                "--out",
                blocked.to_str().unwrap(),
            ],
            "",
        );
        let stderr = String::from_utf8_lossy(&result.stderr);
        assert_eq!(result.status.code(), Some(2), "{stderr}");
        assert!(
            stderr.contains("cannot create the output folder"),
            "{stderr}"
        );
        assert!(
            clock.elapsed().as_secs_f64() < 2.0,
            "{command} computed first"
        );
    }
}

#[test]
fn smaller_messages_say_what_happened() {
    let dir = tempfile::tempdir().unwrap();
    // `simulate --out FILE` names the file.
    let file = dir.path().join("a-file");
    std::fs::write(&file, "x").unwrap();
    let out = evitrack(&["simulate", "--out", file.to_str().unwrap()], "");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2));
    assert!(
        stderr.contains(&format!("{} is a file, not a folder", file.display())),
        "{stderr}"
    );
    // `train` says its cause once.
    let data = small_dataset(dir.path());
    let data = data.to_str().unwrap();
    let model = dir.path().join("m.json");
    let out = evitrack(
        &[
            "train",
            data,
            "--out",
            model.to_str().unwrap(),
            "--validation",
            data,
            "--threshold",
            "quantile:2",
        ],
        "",
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2));
    assert_eq!(stderr.matches("is not in (0, 1]").count(), 1, "{stderr}");
    // `track` on frames with truth but without a silhouette says no frame had an estimate,
    // not that there is no ground truth.
    let out = evitrack(&["train", data, "--out", model.to_str().unwrap()], "");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let frames = std::path::Path::new(data).join("frames");
    for entry in std::fs::read_dir(&frames).unwrap() {
        let path = entry.unwrap().path();
        let blank = image::open(&path).unwrap().to_luma8();
        image::GrayImage::from_pixel(blank.width(), blank.height(), image::Luma([30]))
            .save(&path)
            .unwrap();
    }
    let out = evitrack(&["track", "--model", model.to_str().unwrap(), data], "");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(stderr.contains("none with an estimate"), "{stderr}");
    assert!(!stderr.contains("no ground truth"), "{stderr}");
}

#[test]
fn the_library_refuses_features_of_the_other_polarity() {
    use evitrack::estimator::DatasetFeatures;
    use evitrack::features::{FeatureConfig, Polarity};
    let dir = tempfile::tempdir().unwrap();
    let mut dataset = Dataset::read(small_dataset(dir.path())).unwrap();
    let set = FeatureConfig::default().check().unwrap();
    assert!(DatasetFeatures::extract(&dataset, &set, "data").is_ok());
    dataset.manifest.camera.polarity = Polarity::DarkOnBright;
    let error = DatasetFeatures::extract(&dataset, &set, "data")
        .expect_err("the other polarity is refused")
        .to_string();
    assert!(error.contains("polarity"), "{error}");
    let dark = FeatureConfig {
        polarity: Polarity::DarkOnBright,
        ..FeatureConfig::default()
    };
    assert!(DatasetFeatures::extract(&dataset, &dark.check().unwrap(), "data").is_ok());
}
