//! Issue 15's reproducers: small inputs that once exhausted memory, printed non-finite numbers
//! with exit 0 or lost output. Each gives a correct answer or exit 2 with a clear message.

use crate::cli::evitrack;
use evitrack::dataset::{Dataset, Rect};
use evitrack::estimator::test_maps::{feature_row, workspace_mesh};
use evitrack::estimator::{load, EstimatorSettings, Labelled, Method, TrainingSet};
use evitrack::evidence::{
    dempster_all_within, EvidenceError, MassFunction, Subset, WorkLimit, WorkLimits,
};
use evitrack::model_file::Provenance;
use evitrack::scenario::{ScenarioSet, SeedList};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

mod sweeps;

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
    for method in Method::all() {
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
