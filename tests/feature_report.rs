//! The feature author's report (issue 28, item 4): a constant or pure-noise feature carries no
//! information and leaving the constant one out changes nothing; a fault that cannot reach a
//! feature never changes it; without ground truth only what needs none is filled; the command
//! writes its JSON and plot, and refuses bad input with a clear error.

use std::path::Path;

use evitrack::dataset::Dataset;
use evitrack::estimator::Method;
use evitrack::faults::FaultSpec;
use evitrack::feature_report::{self, FaultChanges, Inputs, Options};
use evitrack::features::{FeatureConfig, TileConfig};
use evitrack::sim::{self, Motion, SimSettings};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

use crate::cli::evitrack;

/// The 2 mm mesh of the workspace: 100 frames.
fn mesh() -> Dataset {
    let motion = Motion::Mesh { spacing: 2.0 };
    sim::simulate(&SimSettings::default(), &motion, 5, &mut |_, _| {}).unwrap()
}

#[test]
fn constant_and_noise_features_carry_no_information() {
    let data = mesh();
    let set = FeatureConfig::default().check().unwrap();
    let mut names = set.names();
    names.extend(["constant".to_string(), "noise".to_string()]);
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let rows: Vec<Vec<Option<f64>>> = set
        .extract_batch(data.images())
        .into_iter()
        .map(|mut row| {
            row.push(Some(0.5));
            row.push(Some(StandardNormal.sample(&mut rng)));
            row
        })
        .collect();
    let poses = data.truth_positions().unwrap();
    let inputs = Inputs {
        names: &names,
        rows: &rows,
        poses: Some(&poses),
        validation: None,
        workspace: data.manifest.workspace,
    };
    let options = Options {
        methods: vec![Method::KNN],
        grid: 8,
    };
    let report = feature_report::build(
        &inputs,
        &options,
        &FaultChanges::default(),
        &mut |_, _, _| {},
    )
    .unwrap();
    let entry = |name: &str| report.features.iter().find(|e| e.name == name).unwrap();
    let shares: Vec<f64> = (report.features.iter())
        .map(|e| e.information_share.unwrap())
        .collect();
    assert!(
        (shares.iter().sum::<f64>() - 1.0).abs() < 1e-9,
        "{shares:?}"
    );
    let (constant, noise) = (entry("constant"), entry("noise"));
    assert_eq!(constant.information_share, Some(0.0));
    assert_eq!(constant.limit_increase, Some(0.0));
    assert_eq!(constant.ablation["knn"], 0.0, "k-NN ignores a constant");
    assert_eq!(constant.neighbour_max_change, Some(0.0));
    let most = shares.iter().copied().fold(0.0, f64::max);
    let weak = noise.information_share.unwrap();
    // The surrogate fits a little slope to noise: a few thousandths of the information.
    assert!(
        weak < 0.01 && weak < 0.05 * most,
        "noise carries {weak} against {most}"
    );
    // Leaving it out moves the limit only through its chance correlations with the others'
    // residuals over 50 held-out frames (measured 7 %).
    assert!(
        noise.limit_increase.unwrap() < 0.15,
        "{:?}",
        noise.limit_increase
    );
    // Pure noise separates no neighbours: well under one σ apart, against several for a line.
    assert!(noise.neighbour_median_sigmas.unwrap() < 1.5);
    assert!(entry("size_line0").neighbour_median_sigmas.unwrap() > 1.5);
    assert!(report.limit_rms.is_some_and(|l| l > 0.0));
    assert!(report.method_errors["knn"] > 0.0);
    assert_eq!(report.correlation[0][0], Some(1.0));
    assert_eq!(
        report.correlation[6][0], None,
        "a constant correlates with nothing"
    );
}

#[test]
fn without_ground_truth_only_what_needs_none() {
    let data = mesh();
    let set = FeatureConfig::default().check().unwrap();
    let names = set.names();
    let rows = set.extract_batch(data.images());
    let inputs = Inputs {
        names: &names,
        rows: &rows,
        poses: None,
        validation: None,
        workspace: None,
    };
    let report = feature_report::build(
        &inputs,
        &Options::default(),
        &FaultChanges::default(),
        &mut |_, _, _| {},
    )
    .unwrap();
    assert!(!report.ground_truth);
    for e in &report.features {
        assert!(e.sd.is_some_and(|s| s > 0.0), "{}", e.name);
        assert_eq!(e.missing_share, 0.0);
        assert!(e.most_correlated.is_some());
        assert!(e.sigma.is_none() && e.information_share.is_none() && e.ablation.is_empty());
    }
    assert!(report.notes.iter().any(|n| n.contains("no ground truth")));
}

#[test]
fn a_box_in_one_corner_changes_that_tile_and_never_the_far_one() {
    let data = mesh();
    let mut config = FeatureConfig {
        tiles: TileConfig {
            enabled: true,
            ..TileConfig::default()
        },
        ..FeatureConfig::default()
    };
    config.size_functions.enabled = false;
    let set = config.check().unwrap();
    let rows = set.extract_batch(data.images());
    #[derive(serde::Deserialize)]
    struct Faults {
        faults: Vec<FaultSpec>,
    }
    let specs: Faults = toml::from_str(
        "[[faults]]\nkind = \"occluder\"\nname = \"corner\"\nrect = [5, 5, 15, 15]\nintensity = 255",
    )
    .unwrap();
    let changes =
        feature_report::fault_changes(&specs.faults, &set, &data, &rows, 20, 1, 2).unwrap();
    assert_eq!(changes.frames, 20);
    let share = |tile: &str| {
        let j = set.names().iter().position(|n| n == tile).unwrap();
        changes.per_feature[j]["corner"]
    };
    assert_eq!(share("tile_r0_c0"), 1.0);
    assert_eq!(share("tile_r3_c3"), 0.0);
}

fn write_mesh(dir: &Path, truth: bool) {
    let mut data = mesh();
    if !truth {
        data.frames.iter_mut().for_each(|f| f.truth = None);
    }
    data.write(dir).unwrap();
}

#[test]
fn the_command_writes_json_and_plot_with_and_without_truth() {
    let tmp = tempfile::tempdir().unwrap();
    for truth in [true, false] {
        let data = tmp.path().join(format!("data-{truth}"));
        let out = tmp.path().join(format!("out-{truth}"));
        write_mesh(&data, truth);
        let output = evitrack(
            &[
                "features",
                data.to_str().unwrap(),
                "--report",
                "--grid",
                "6",
                "--fault-frames",
                "10",
                "--out",
                out.to_str().unwrap(),
            ],
            "",
        );
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(0), "{stderr}");
        let stdout = String::from_utf8_lossy(&output.stdout);
        assert!(
            stdout.contains("size_line0") && stdout.contains("dark_box %"),
            "{stdout}"
        );
        let json: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(out.join(feature_report::JSON_FILE)).unwrap(),
        )
        .unwrap();
        assert_eq!(json["ground_truth"], truth);
        assert_eq!(json["features"].as_array().unwrap().len(), 6);
        assert_eq!(json["features"][0]["sigma"].is_number(), truth);
        assert_eq!(json["features"][0]["ablation"]["knn"].is_number(), truth);
        assert_eq!(out.join(feature_report::PLOT_FILE).exists(), truth);
    }
}

#[test]
fn bad_input_is_named() {
    let tmp = tempfile::tempdir().unwrap();
    let empty = tmp.path().join("empty");
    std::fs::create_dir(&empty).unwrap();
    let data = tmp.path().join("data");
    write_mesh(&data, true);
    let no_frames = tmp.path().join("no-frames");
    std::fs::create_dir(&no_frames).unwrap();
    let manifest = std::fs::read_to_string(data.join("manifest.json")).unwrap();
    let manifest = manifest.replace("\"frame_count\": 100", "\"frame_count\": 0");
    std::fs::write(no_frames.join("manifest.json"), manifest).unwrap();
    std::fs::write(no_frames.join("poses.csv"), "file,t,x,y,theta1,theta2\n").unwrap();
    for (args, expected) in [
        (vec![empty.to_str().unwrap()], "manifest"),
        (vec![no_frames.to_str().unwrap()], "no frames"),
        (
            vec![data.to_str().unwrap(), "--methods", "knn,nope"],
            "unknown method `nope`",
        ),
        (
            vec![data.to_str().unwrap(), "--methods", "evidential_temporal"],
            "tracks over time",
        ),
    ] {
        let mut full = vec!["features"];
        full.extend(&args);
        full.push("--report");
        let output = evitrack(&full, "");
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(2), "{args:?}: {stderr}");
        assert!(stderr.contains(expected), "{args:?}: {stderr}");
    }
}
