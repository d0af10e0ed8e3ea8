//! Issue 15's reproducers: small inputs that once exhausted memory, printed non-finite numbers
//! with exit 0 or lost output. Each gives a correct answer or exit 2 with a clear message.

use crate::cli::evitrack;
use evitrack::dataset::{Dataset, Rect};
use evitrack::estimator::test_maps::{feature_row, workspace_mesh};
use evitrack::estimator::{load, EstimatorSettings, Labelled, Method, TrainingSet};
use evitrack::evidence::{
    dempster_all_within, EvidenceError, MassFunction, Subset, WorkLimit, WorkLimits,
};
use evitrack::model::Provenance;
use evitrack::scenario::{ScenarioSet, SeedList};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// A combine input of `functions`, each a list of (focal set, mass).
fn combine_input(frame: usize, functions: &[Vec<(Vec<usize>, f64)>]) -> String {
    let fs: Vec<serde_json::Value> = functions
        .iter()
        .map(|f| {
            let (focal, mass): (Vec<_>, Vec<_>) = f.iter().cloned().unzip();
            serde_json::json!({ "focal": focal, "mass": mass })
        })
        .collect();
    serde_json::json!({ "frame": frame, "rule": "dempster", "mass_functions": fs }).to_string()
}

/// Rows and columns of a 100 × 100 grid: 10⁴ distinct intersections, of 2 MB each on a frame of
/// 2²⁴ elements (20 GB unbounded).
fn grid_input(frame: usize) -> String {
    let rows = (0..100)
        .map(|i| ((0..100).map(|j| 100 * i + j).collect(), 0.01))
        .collect();
    let columns = (0..100)
        .map(|j| ((0..100).map(|i| 100 * i + j).collect(), 0.01))
        .collect();
    combine_input(frame, &[rows, columns])
}

/// 22 functions "all but element k, or all": the combination has 2^k focal sets after k steps.
fn exponential_input(functions: usize) -> String {
    let all: Vec<usize> = (0..functions).collect();
    let fs: Vec<_> = (0..functions)
        .map(|k| {
            let but_k = all.iter().copied().filter(|&e| e != k).collect();
            vec![(but_k, 0.5), (all.clone(), 0.5)]
        })
        .collect();
    combine_input(functions, &fs)
}

fn refused(args: &[&str], input: &str, names: &str) {
    let out = evitrack(args, input);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{args:?}: {stderr}");
    assert!(stderr.contains(names), "{names:?} not in {stderr}");
    assert!(stderr.contains("raise it with"), "{stderr}");
    assert!(out.stdout.is_empty());
}

#[test]
fn combine_stops_at_its_memory_limit_with_exit_2_and_the_flag_that_raises_it() {
    // On 2¹⁶ elements a set takes 8 KiB: the running result reaches 16 MiB at 2048 of its 10⁴
    // sets (the inputs, 800 KiB each, are within).
    let grid = grid_input(1 << 16);
    refused(
        &["combine", "--max-set-mib", "16", "-"],
        &grid,
        "--max-set-mib (now 16)",
    );
    // Raised far enough, the same grid combines: 10⁴ singletons of mass 10⁻⁴.
    let out = evitrack(&["combine", "--max-set-mib", "80", "-"], &grid);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let mass = json["mass"].as_array().unwrap();
    assert_eq!(mass.len(), 10_000);
    assert!(mass
        .iter()
        .all(|m| (m.as_f64().unwrap() - 1e-4).abs() < 1e-15));
}

#[test]
fn combine_stops_exponential_growth_at_the_focal_set_limit() {
    let input = exponential_input(22);
    refused(
        &["combine", "--max-focal-sets", "1000", "-"],
        &input,
        "--max-focal-sets (now 1000)",
    );
    // 10 functions make 2¹⁰ − 1 = 1023 non-empty sets: within a limit of 1023, not of 1022.
    let small = exponential_input(10);
    let out = evitrack(&["combine", "--max-focal-sets", "1023", "-"], &small);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(json["focal"].as_array().map(Vec::len), Some(1023));
    refused(
        &["combine", "--max-focal-sets", "1022", "-"],
        &small,
        "--max-focal-sets",
    );
}

#[test]
fn combine_refuses_an_input_over_the_limits_before_building_it() {
    // Two functions of 100 sets that all meet in one set R: the combination has one focal set,
    // so only the inputs held together (200 sets; on 2²⁴ elements 200 MiB each, 400 MiB in all)
    // break the limits, and the refusal comes before the sets are built.
    let shared: Vec<usize> = (0..10).collect();
    let side = |offset: usize| {
        (0..100)
            .map(|i| {
                let mut set = shared.clone();
                set.push(offset + i);
                (set, 0.01)
            })
            .collect::<Vec<_>>()
    };
    let merging = |frame| combine_input(frame, &[side(100), side(200)]);
    for (args, frame, names) in [
        (
            ["--max-focal-sets", "150"],
            1000,
            "--max-focal-sets (now 150)",
        ),
        (["--max-set-mib", "300"], 1 << 24, "--max-set-mib (now 300)"),
    ] {
        let mut command = vec!["combine"];
        command.extend(args);
        command.push("-");
        refused(&command, &merging(frame), names);
        // Either input alone is within the limit, and so is their combination (below).
        let alone = combine_input(frame, &[side(100)]);
        let out = evitrack(&command, &alone);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
    let out = evitrack(&["combine", "--max-focal-sets", "200", "-"], &merging(1000));
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(json["focal"], serde_json::json!([shared]));
    refused(
        &["combine", "--max-output-elements", "9999", "-"],
        &combine_input(10_000, &[vec![((0..10).collect(), 1.0)]]),
        "--max-output-elements (now 9999)",
    );
}

#[test]
fn the_library_reports_which_limit_a_combination_reached() {
    let n = 12;
    let fs: Vec<MassFunction> = (0..n)
        .map(|k| {
            let but_k = Subset::from_indices(n, (0..n).filter(|&e| e != k)).unwrap();
            MassFunction::new(n, vec![(but_k, 0.5), (Subset::full(n), 0.5)]).unwrap()
        })
        .collect();
    // 2¹² − 1 non-empty sets (the empty one is the conflict 2⁻¹²).
    let reached = |limits: WorkLimits| match dempster_all_within(&fs, &limits) {
        Err(EvidenceError::WorkLimit { limit, max }) => Some((limit, max)),
        Ok(c) => {
            assert_eq!(c.mass.map(|m| m.focal().count()), Some(4095));
            assert!((c.conflict_mass - 2f64.powi(-12)).abs() < 1e-15);
            None
        }
        Err(e) => panic!("{e}"),
    };
    let sets = |focal_sets| WorkLimits {
        focal_sets,
        ..WorkLimits::DEFAULT
    };
    let bytes = |set_bytes| WorkLimits {
        set_bytes,
        ..WorkLimits::DEFAULT
    };
    assert_eq!(reached(sets(4094)), Some((WorkLimit::FocalSets, 4094)));
    assert_eq!(
        reached(bytes(8 * 4094)),
        Some((WorkLimit::SetBytes, 8 * 4094))
    );
    assert_eq!(reached(sets(4095)), None);
    assert_eq!(reached(bytes(8 * 4095)), None);
}

/// A 25-frame dataset of the default rig (workspace x −9.5..9.5, y 38..57 mm) in `dir`.
fn small_dataset(dir: &std::path::Path) -> std::path::PathBuf {
    let path = dir.join("data");
    let out = evitrack(
        &[
            "simulate",
            "--out",
            path.to_str().unwrap(),
            "--motion",
            r#"kind = "mesh", spacing = 4.75"#,
        ],
        "",
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    path
}

/// `poses.csv` of `dataset` with field `column` of its first frame set to `value`.
fn set_first_pose(dataset: &std::path::Path, column: usize, value: &str) {
    let path = dataset.join("poses.csv");
    let text = std::fs::read_to_string(&path).unwrap();
    let mut lines: Vec<String> = text.lines().map(String::from).collect();
    let mut fields: Vec<&str> = lines[1].split(',').collect();
    fields[column] = value;
    lines[1] = fields.join(",");
    std::fs::write(&path, lines.join("\n") + "\n").unwrap();
}

#[test]
fn datasets_refuse_poses_beyond_their_declared_workspace() {
    let dir = tempfile::tempdir().unwrap();
    let data = small_dataset(dir.path());
    let original = std::fs::read(data.join("poses.csv")).unwrap();
    // Columns: file, t, x, y, theta1, theta2. The workspace's slack is 5 % of 19 mm.
    for (column, value, needle) in [
        (2, "1e300", "beyond ±10000 mm"),
        (2, "30", "outside the declared workspace x -9.5..9.5"),
        (3, "37", "outside the declared workspace"),
        (4, "100", "joint angles (100"),
    ] {
        std::fs::write(data.join("poses.csv"), &original).unwrap();
        set_first_pose(&data, column, value);
        let error = Dataset::read(&data).unwrap_err().to_string();
        assert!(error.contains("poses.csv line 2"), "{error}");
        assert!(error.contains(needle), "{needle:?} not in {error}");
    }
    // The CLI says so with exit 2: `train` on x = 1e300 once trained and tracked with exit 0.
    std::fs::write(data.join("poses.csv"), &original).unwrap();
    set_first_pose(&data, 2, "1e300");
    let model = dir.path().join("model.json");
    let out = evitrack(
        &[
            "train",
            data.to_str().unwrap(),
            "--out",
            model.to_str().unwrap(),
        ],
        "",
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("beyond ±10000 mm"), "{stderr}");
    assert!(!model.exists());
    // Within the slack (0.95 mm past x_max) a pose is read.
    set_first_pose(&data, 2, "10.4");
    Dataset::read(&data).unwrap();
}

#[test]
fn model_files_of_every_method_refuse_poses_beyond_their_workspace() {
    let poses = workspace_mesh(8);
    let mut rng = ChaCha8Rng::seed_from_u64(15);
    let rows: Vec<_> = poses
        .iter()
        .map(|&q| feature_row(3, q, 0.01, &mut rng))
        .collect();
    let names: Vec<String> = (0..3).map(|i| format!("f{i}")).collect();
    let mut data = TrainingSet::new(
        &names,
        Labelled {
            poses: &poses,
            rows: &rows,
        },
    );
    let workspace = Rect {
        x_min: -9.5,
        x_max: 9.5,
        y_min: 38.0,
        y_max: 57.0,
    };
    data.provenance = Provenance::new(None, 15).with_workspace(Some(workspace));
    let dir = tempfile::tempdir().unwrap();
    for method in Method::ALL {
        let estimator = method.fit(&EstimatorSettings::default(), &data).unwrap();
        let text = estimator.to_json().unwrap();
        let outer: serde_json::Value = serde_json::from_str(&text).unwrap();
        // The temporal methods hold the model of the method they build on as text.
        let nested = ["evidential_model", "feature_maps", "continuous_model"]
            .into_iter()
            .find(|k| outer.get(k).is_some());
        let json: serde_json::Value = match nested {
            Some(key) => serde_json::from_str(outer[key].as_str().unwrap()).unwrap(),
            None => outer.clone(),
        };
        assert_eq!(json["provenance"]["workspace"]["x_max"], 9.5, "{method}");
        let (pointer, field) = if json.get("sample_poses").is_some() {
            ("/sample_poses/3", "`sample_poses[3]`")
        } else {
            ("/max", "`min, max[1]`")
        };
        let path = dir.path().join(format!("{method}.json"));
        for (pose, needle) in [
            (serde_json::json!([1e308, 1e308]), "beyond ±10000 mm"),
            (
                serde_json::json!([30.0, 47.0]),
                "outside the declared workspace",
            ),
        ] {
            let mut bad = json.clone();
            *bad.pointer_mut(pointer).unwrap() = pose;
            let bad = match nested {
                Some(key) => {
                    let mut wrapped = outer.clone();
                    wrapped[key] = serde_json::Value::String(bad.to_string());
                    wrapped
                }
                None => bad,
            };
            std::fs::write(&path, bad.to_string()).unwrap();
            let error = match load(&path) {
                Ok(_) => panic!("{method}: a pose {pointer} outside the workspace was accepted"),
                Err(e) => e.to_string(),
            };
            assert!(
                error.contains(field) && error.contains(needle),
                "{method}: {error}"
            );
        }
        std::fs::write(&path, &text).unwrap();
        load(&path).unwrap();
    }
}

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
motion = { kind = "mesh", spacing = 1.0 }
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
            "--threshold-quantile",
            "2",
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
