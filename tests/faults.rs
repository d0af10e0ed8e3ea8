//! Faults: the faults sweep meets its expectations and the README's claims, fault draws are
//! seeded (same scenario and seed, same frames, bit for bit), and the learned threshold acts.

use std::collections::HashMap;
use std::process::Command;

use evitrack::experiment::RunOutput;
use evitrack::report::{FaultSummary, MethodSummary};

fn faults_sweep() -> HashMap<String, RunOutput> {
    crate::run_every_variant("faults.toml")
        .into_iter()
        .collect()
}

fn method<'a>(
    runs: &'a HashMap<String, RunOutput>,
    variant: &str,
    name: &str,
) -> &'a MethodSummary {
    runs[&format!("faults-{variant}")]
        .summary
        .method(name)
        .unwrap_or_else(|| panic!("{variant} has no {name}"))
}

fn faults<'a>(runs: &'a HashMap<String, RunOutput>, variant: &str, name: &str) -> &'a FaultSummary {
    method(runs, variant, name)
        .faults
        .as_ref()
        .expect("a run with faults")
}

fn mean(stats: Option<evitrack::report::ErrorStats>) -> f64 {
    stats.expect("frames with an estimate").mean
}

#[test]
fn the_faults_sweep_meets_its_expectations_and_the_readme_claims() {
    let runs = faults_sweep();
    for (name, output) in &runs {
        let missed = output.summary.regressions();
        assert!(missed.is_empty(), "{name}: {missed:#?}");
    }
    crate::confidence::assert_regions_calibrated(runs.values().map(|run| &run.summary));
    let stuck = faults(&runs, "stuck", "evidential");
    let paper = faults(&runs, "stuck-paper", "evidential");
    let open = faults(&runs, "stuck-inf", "evidential");
    let q99 = faults(&runs, "stuck-q99", "evidential");
    // The level of conflict tells the corrupted frames apart.
    for f in [stuck, paper, open, q99] {
        assert!(f.detection_auc.unwrap() >= 0.95, "{f:?}");
        assert_eq!(f.corrupted_frames, 56);
    }
    // Combining everything degrades at least 3×; learning the threshold cuts that: to under a
    // quarter with the paper's rule and the 99th percentile, under 0.4 with the default (which
    // keeps one stuck feature beside six good ones more often).
    let ratio = |f: &FaultSummary| mean(f.error_corrupted) / mean(f.error_clean);
    assert!(ratio(open) >= 3.0, "{}", ratio(open));
    assert!(mean(paper.error_corrupted) < 0.25 * mean(open.error_corrupted));
    assert!(mean(q99.error_corrupted) < 0.25 * mean(open.error_corrupted));
    assert!(mean(stuck.error_corrupted) < 0.4 * mean(open.error_corrupted));
    // The issue's bound (1.5×) is missed: the paper's rule gives 2.0× while losing accuracy on
    // clean frames, the 99th percentile gives 2.5×, the default 4.07× with the clean frames of
    // no threshold, and the floor — the two features absent from every frame — is itself above
    // 1.5× the clean error.
    assert!(
        ratio(paper) > 1.95 && ratio(paper) < 2.1,
        "{}",
        ratio(paper)
    );
    assert!(mean(paper.error_clean) > 1.05 * mean(open.error_clean));
    assert!(ratio(q99) > 2.4, "{}", ratio(q99));
    assert!((4.0..4.15).contains(&ratio(stuck)), "{}", ratio(stuck));
    assert_eq!(mean(stuck.error_clean), mean(open.error_clean));
    let floor = method(&runs, "absent", "evidential").error.unwrap().mean;
    assert!(floor > 1.5 * mean(open.error_clean), "{floor}");
    // On the corrupted frames the evidential tracker beats both regressors (3.4× and 7.6×).
    for baseline in ["knn", "gp"] {
        let b = faults(&runs, "stuck", baseline);
        assert!(
            mean(stuck.error_corrupted) < 0.3 * mean(b.error_corrupted),
            "{baseline}: {b:?}"
        );
    }
    // The paper's rule costs clean accuracy (9 %); the 99th percentile keeps it within 2 %, the
    // default whole.
    let clean = |v: &str| method(&runs, v, "evidential").error.unwrap().mean;
    assert!(clean("clean-paper") > 1.08 * clean("clean-inf"));
    assert!(clean("clean-q99") < 1.02 * clean("clean-inf"));
    assert_eq!(clean("clean"), clean("clean-inf"));
    // Offset and noise bursts: lower error than 6-NN on the corrupted frames; the GP wins the
    // offset.
    for variant in ["offset", "noise-burst"] {
        let e = mean(faults(&runs, variant, "evidential").error_corrupted);
        assert!(
            e < 0.7 * mean(faults(&runs, variant, "knn").error_corrupted),
            "{variant}"
        );
    }
    // A feature fault leaves the other frames alone: every method's clean frames under the noise
    // bursts are the clean run's, estimate and region alike (so their coverage is the clean
    // run's on a subset of its frames; docs/results.md).
    let clean_run = &runs["faults-clean"].records;
    let mut compared = 0;
    for r in (runs["faults-noise-burst"].records.iter()).filter(|r| !r.corrupted()) {
        let same = (clean_run.iter())
            .find(|c| c.method == r.method && c.motion == r.motion && c.frame == r.frame)
            .unwrap();
        assert_eq!(
            (same.estimate, same.region_covers, same.region_area),
            (r.estimate, r.region_covers, r.region_area),
            "{} frame {}",
            r.method,
            r.frame
        );
        compared += 1;
    }
    assert_eq!(
        compared,
        5 * 160,
        "five methods, 160 clean frames on seed 1"
    );
    let offset_gp = mean(faults(&runs, "offset", "gp").error_corrupted);
    assert!(offset_gp < mean(faults(&runs, "offset", "evidential").error_corrupted));
    let left_out = |v: &str| method(&runs, v, "evidential").frames_with_features_left_out;
    assert_eq!((left_out("clean-paper"), left_out("clean")), (49, 0));
    // What the image faults change: a dark occluder all 8 features in 19 of its 31 corrupted
    // frames; salt and pepper the barycentre most.
    let changed = |variant: &str| -> Vec<Vec<usize>> {
        (runs[&format!("faults-{variant}")].records.iter())
            .filter(|r| r.method == "evidential" && r.corrupted())
            .map(|r| r.faults.as_ref().unwrap().changed.clone())
            .collect()
    };
    let dark_frames = changed("occluder-dark");
    assert_eq!(dark_frames.len(), 31);
    assert_eq!(dark_frames.iter().filter(|c| c.len() == 8).count(), 19);
    let salt = changed("salt-pepper");
    let count = |j: usize| salt.iter().filter(|c| c.contains(&j)).count();
    assert_eq!((salt.len(), count(7), count(6)), (56, 47, 43));
    assert!((0..6).all(|j| (6..=17).contains(&count(j))));
    // A dark occluder changes features coherently: most stay in.
    let dark = faults(&runs, "occluder-dark", "evidential");
    assert!(dark.left_out_recall.unwrap() < 0.6 && mean(dark.error_corrupted) > 5.0);
    // A missing feature takes no part: its frames do not look different.
    let missing = faults(&runs, "dropout", "evidential")
        .detection_auc
        .unwrap();
    assert!((0.4..0.6).contains(&missing), "{missing}");
    assert_eq!(
        faults(&runs, "dropout", "gp").corrupted_without_estimate,
        56
    );
    // Left-out features are mostly the stuck ones.
    assert!(q99.left_out_precision.unwrap() > 0.9 && q99.left_out_recall.unwrap() > 0.9);
    // Weighing splitting alternatives by clean-data reliability does not reject the stuck ones.
    let split = faults(&runs, "stuck-split", "evidential");
    assert!(mean(split.error_corrupted) > 2.0 * mean(stuck.error_corrupted));
    // The continuous evidential tracker (README, issue 13): with its learned threshold, lower
    // error on the stuck frames than every baseline and the paper's tracker, conflict AUC ≥ 0.95,
    // the stuck features found (recall and precision 1), and no clean frame losing a feature
    // (the 99th percentile took them from 10 of 200); a fixed threshold of 30 keeps every
    // clean frame whole too and still leaves the stuck features out.
    let continuous = faults(&runs, "stuck", "continuous");
    assert!(continuous.detection_auc.unwrap() >= 0.95);
    let region = method(&runs, "stuck", "continuous").region.clone().unwrap();
    assert!((region.coverage - 0.8472).abs() < 1e-3 && (region.mean_area - 0.00298).abs() < 1e-4);
    for other in ["evidential", "knn", "gp"] {
        let b = faults(&runs, "stuck", other);
        assert!(
            mean(continuous.error_corrupted) < 0.5 * mean(b.error_corrupted),
            "{other}: {b:?}"
        );
    }
    assert!(continuous.left_out_recall.unwrap() > 0.99);
    assert!(continuous.left_out_precision.unwrap() > 0.99);
    let floor = method(&runs, "absent", "continuous").error.unwrap().mean;
    assert!(mean(continuous.error_corrupted) < 1.0 * floor, "{floor}");
    let clean_continuous = |v: &str| method(&runs, v, "continuous");
    assert_eq!(clean_continuous("clean").frames_with_features_left_out, 0);
    assert_eq!(
        clean_continuous("clean-fixed30").frames_with_features_left_out,
        0
    );
    let fixed = faults(&runs, "stuck-fixed30", "continuous");
    assert_eq!(
        (fixed.left_out_precision, fixed.left_out_recall),
        (Some(1.0), Some(1.0))
    );
    let combined = faults(&runs, "stuck-inf", "continuous");
    assert!(mean(combined.error_corrupted) > 20.0 * mean(continuous.error_corrupted));
    // Occlusion stays the hard case: the dark occluder's corrupted frames, above the GP's.
    let dark = faults(&runs, "occluder-dark", "continuous");
    assert!(
        mean(dark.error_corrupted) > mean(faults(&runs, "occluder-dark", "gp").error_corrupted)
    );
    // Every frame the stuck fault struck records both features as changed.
    let records = &runs["faults-stuck"].records;
    let struck: Vec<_> = records
        .iter()
        .filter(|r| r.method == "evidential")
        .filter_map(|r| r.faults.as_ref())
        .filter(|f| f.faults == ["stuck"])
        .collect();
    assert_eq!(struck.len(), 56);
    assert!(struck.iter().all(|f| f.changed == [0, 6]), "{struck:?}");
}

const SMALL: &str = r#"
name = "small-faults"
seed = 4
estimators = ["evidential", "knn"]
learn_threshold = true

[sample]
motion = { kind = "mesh", spacing = 2.0 }

[[tests]]
kind = "lissajous"
freq_x = 0.3
freq_y = 0.2
duration = 4.0
fps = 10.0

[features.barycentre]
enabled = true

[model]
states = 6

[[faults]]
kind = "occluder"
rect = [-10, 30, 12, 30]
intensity = 255
velocity = [5.0, 0.0]
share = 0.5

[[faults]]
kind = "salt_pepper"
density = 0.05
share = 0.3
burst = 2

[[faults]]
kind = "noise"
features = ["size_line1", "barycentre_y"]
sigma = 1.0
units = "sd"
share = 0.4

[[faults]]
kind = "dropped"
window = [30, 39]
share = 0.5
"#;

#[test]
fn fault_draws_are_bit_identical_for_a_scenario_and_seed() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = dir.path().join("small.toml");
    std::fs::write(&scenario, SMALL).unwrap();
    let frames = |out: &str, seed: &str| {
        let out = dir.path().join(out);
        let status = Command::new(env!("CARGO_BIN_EXE_evitrack"))
            .args([
                "run",
                scenario.to_str().unwrap(),
                "--out",
                out.to_str().unwrap(),
            ])
            .args(["--seed", seed])
            .output()
            .unwrap();
        assert!(
            status.status.success(),
            "{}",
            String::from_utf8_lossy(&status.stderr)
        );
        std::fs::read(out.join("small-faults/frames.csv")).unwrap()
    };
    let a = frames("a", "4");
    assert_eq!(a, frames("b", "4"), "same scenario and seed, same bytes");
    assert_ne!(a, frames("c", "5"), "another seed, other draws");
    let text = String::from_utf8(a).unwrap();
    let mut reader = csv::Reader::from_reader(text.as_bytes());
    let header = reader.headers().unwrap().clone();
    let column = |name: &str| header.iter().position(|h| h == name).unwrap();
    let (faults, changed) = (column("faults"), column("changed_features"));
    let rows: Vec<csv::StringRecord> = reader.records().map(|r| r.unwrap()).collect();
    let labelled = |needle: &str| rows.iter().filter(|r| r[faults].contains(needle)).count();
    assert!(labelled("occluder") > 0 && labelled("salt_pepper") > 0 && labelled("noise") > 0);
    for r in rows.iter().filter(|r| r[faults].contains("dropped")) {
        assert_eq!(&r[changed], "frame");
        assert!(
            r[column("est_x")].is_empty(),
            "a lost frame has no estimate"
        );
    }
    assert!(rows.iter().any(|r| r[faults].contains("dropped")));
    // Clean frames are clean for every method, and a frame's label is the same for both.
    for r in rows.iter().filter(|r| r[faults].is_empty()) {
        assert!(r[changed].is_empty());
    }
    let per_method = |m: &str| -> Vec<(String, String)> {
        (rows.iter().filter(|r| &r[0] == m))
            .map(|r| (r[faults].to_string(), r[changed].to_string()))
            .collect()
    };
    assert_eq!(per_method("evidential"), per_method("knn"));
}
