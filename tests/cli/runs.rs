//! Scenario runs from the command line: results, sweeps and their shards, seeds, the scale and
//! time scenarios.

use super::*;

#[test]
fn run_writes_results_table_model_and_plot() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = dir.path().join("small.toml");
    std::fs::write(
        &scenario,
        small_scenario("small", "[expect]\nmax_mean_error = 8.0\n"),
    )
    .unwrap();
    let out_dir = dir.path().join("out");
    let out = evitrack(
        &[
            "run",
            scenario.to_str().unwrap(),
            "--out",
            out_dir.to_str().unwrap(),
        ],
        "",
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let table = String::from_utf8_lossy(&out.stdout);
    assert!(table.contains("small") && table.contains("mean"), "{table}");
    for file in [
        "results.json",
        "frames.csv",
        "model-evidential.json",
        "track-test0-circle.png",
    ] {
        assert!(out_dir.join("small").join(file).is_file(), "{file} missing");
    }
    let results: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out_dir.join("small/results.json")).unwrap())
            .unwrap();
    assert_eq!(results["frames"], 20);
    assert_eq!(results["evidential"]["conflict_threshold"], "inf");
    // A typo in the scenario is an error with its line.
    std::fs::write(
        &scenario,
        "name = \"x\"\n[track]\nconstructer = \"bayesian\"\n",
    )
    .unwrap();
    let out = evitrack(&["run", scenario.to_str().unwrap()], "");
    assert_eq!(out.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("line 3") && stderr.contains("constructer"),
        "{stderr}"
    );
}

#[test]
fn sweep_check_fails_on_regression_and_shards_merge() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = dir.path().join("grid.toml");
    let extra = "[expect]\nmax_mean_error = 0.001\n[sweep.grid]\n\"model.states\" = [2, 3, 4]\n";
    std::fs::write(&scenario, small_scenario("grid", extra)).unwrap();
    let out_dir = dir.path().join("out");
    let (scenario, out_text) = (scenario.to_str().unwrap(), out_dir.to_str().unwrap());
    let out = evitrack(&["sweep", scenario, "--out", out_text, "--check"], "");
    assert_eq!(
        out.status.code(),
        Some(1),
        "an impossible expectation regresses"
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("grid-states=3") && stderr.contains("is above the expected maximum"),
        "{stderr}"
    );
    let table = String::from_utf8_lossy(&out.stdout);
    // One row per variant and method, 3 variants × (evidential, continuous, knn, gp, centre),
    // in the error table and again in the confidence table, and each variant's `limit` row.
    assert_eq!(table.lines().filter(|l| l.starts_with("grid-")).count(), 33);
    for file in [
        "sweep.json",
        "sweep.csv",
        "sweep-errors.png",
        "sweep-states.png",
    ] {
        assert!(out_dir.join(file).is_file(), "{file} missing");
    }
    // Two shards cover the three variants; merged, they give the same numbers.
    let mut shard_files = Vec::new();
    for shard in ["1/2", "2/2"] {
        let out = evitrack(
            &["sweep", scenario, "--out", out_text, "--shard", shard],
            "",
        );
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let i = &shard[..1];
        shard_files.push(out_dir.join(format!("sweep-shard-{i}-of-2.json")));
    }
    let merged_dir = dir.path().join("merged");
    let mut args = vec!["merge"];
    args.extend(shard_files.iter().map(|p| p.to_str().unwrap()));
    args.extend(["--out", merged_dir.to_str().unwrap()]);
    let out = evitrack(&args, "");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let read = |p: std::path::PathBuf| -> Vec<serde_json::Value> {
        let file: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap();
        file["runs"].as_array().unwrap().clone()
    };
    assert_eq!(
        read(merged_dir.join("sweep.json")),
        read(out_dir.join("sweep.json"))
    );
    // In the sweep's order, not shard by shard: the merged files are the sweep's, byte for byte.
    for file in ["sweep.json", "sweep.csv"] {
        assert_eq!(
            std::fs::read(merged_dir.join(file)).unwrap(),
            std::fs::read(out_dir.join(file)).unwrap(),
            "{file}"
        );
    }
    let out = evitrack(&["sweep", scenario, "--shard", "3/2"], "");
    assert_eq!(out.status.code(), Some(2));
}

/// A guard is a band: a figure 4 % better than measured fails `--check` as a figure 4 % worse
/// does, and only on the seed it was measured on.
#[test]
fn a_figure_better_than_its_band_fails_the_check_too() {
    let dir = tempfile::tempdir().unwrap();
    let write = |name: &str, expect: &str| {
        let path = dir.path().join(format!("{name}.toml"));
        let text = small_scenario("band", "").replacen(
            "name = \"band\"\n",
            "name = \"band\"\nestimators = [\"knn\"]\n",
            1,
        ) + expect
            + "[sweep]\nseeds = [1, 2]\n";
        std::fs::write(&path, text).unwrap();
        path
    };
    let measured_at = |out: &std::path::Path| -> f64 {
        let sweep: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("sweep.json")).unwrap())
                .unwrap();
        let run = sweep["runs"]
            .as_array()
            .unwrap()
            .iter()
            .find(|r| r["seed"] == 1)
            .unwrap()
            .clone();
        run["methods"][0]["error"]["mean"].as_f64().unwrap()
    };
    let plain = write("plain", "");
    let out = dir.path().join("plain-out");
    run_expecting("sweep", &plain, &out, 0);
    let mean = measured_at(&out);
    for (factor, code) in [(1.0, 0), (1.029, 0), (0.971, 0), (1.04, 1), (0.96, 1)] {
        let expect = format!("[expect.methods.knn]\nmean_error = {}\n", mean * factor);
        let scenario = write(&format!("band-{factor}"), &expect);
        let out = dir.path().join(format!("out-{factor}"));
        let output = evitrack(
            &[
                "sweep",
                scenario.to_str().unwrap(),
                "--out",
                out.to_str().unwrap(),
                "--check",
            ],
            "",
        );
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(code), "{factor}: {stderr}");
        if factor > 1.0 && code == 1 {
            // Measured below the band: better than expected.
            assert!(
                stderr.contains("-3.8 %") && stderr.contains("deliberately"),
                "{stderr}"
            );
        }
        // Seed 2 runs too, but answers to no band: one miss at most.
        assert_eq!(
            stderr.matches("(knn): mean error").count(),
            code as usize,
            "{stderr}"
        );
    }
}

#[test]
fn simulate_a_scenario_part_gives_the_dataset_run_uses() {
    use evitrack::experiment::Workbench;
    use evitrack::seed::{for_part, ScenarioPart};
    let dir = tempfile::tempdir().unwrap();
    let scenario_path = dir.path().join("s.toml");
    std::fs::write(
        &scenario_path,
        "name = \"s\"\nseed = 9\n[[tests]]\nkind = \"circle\"\nradius = 3.0\nspeed = 5.0\n\
         duration = 1.0\nfps = 5.0\n",
    )
    .unwrap();
    let out_dir = dir.path().join("test0");
    let out = evitrack(
        &[
            "simulate",
            "--scenario",
            scenario_path.to_str().unwrap(),
            "--part",
            "test",
            "--out",
            out_dir.to_str().unwrap(),
        ],
        "",
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let written = evitrack::dataset::Dataset::read(&out_dir).unwrap();
    let scenario = evitrack::scenario::ScenarioSet::load(&scenario_path)
        .unwrap()
        .base;
    let in_run = Workbench::new()
        .dataset(
            &scenario.sim,
            &scenario.tests[0],
            for_part(9, ScenarioPart::Test(0)),
            &mut |_, _| {},
        )
        .unwrap();
    assert_eq!(written.len(), 5);
    for (a, b) in written.frames.iter().zip(&in_run.frames) {
        assert_eq!(a.image, b.image);
        assert_eq!(a.truth, b.truth);
    }
    let out = evitrack(
        &[
            "simulate",
            "--scenario",
            scenario_path.to_str().unwrap(),
            "--part",
            "test4",
            "--out",
            dir.path().join("x").to_str().unwrap(),
        ],
        "",
    );
    assert_eq!(out.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("1 test motion(s): use --part test0 … test0"),
        "{stderr}"
    );
    // One spelling, as frames.csv names the motions: `test0` is `test` (its alias).
    let zero = dir.path().join("zero");
    let args = [
        "simulate",
        "--scenario",
        scenario_path.to_str().unwrap(),
        "--part",
        "test0",
    ];
    let out = evitrack(
        &[&args[..], &["--out", zero.to_str().unwrap()]].concat(),
        "",
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(evitrack::dataset::Dataset::read(&zero).unwrap(), written);
    let out = evitrack(&[&args[..4], &["test-1", "--out", "unused"]].concat(), "");
    assert!(String::from_utf8_lossy(&out.stderr).contains("expected test0, test1, …"));
}

#[test]
fn the_readme_scenario_example_is_a_valid_scenario() {
    let readme =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/README.md")).unwrap();
    let section = &readme[readme.find("## Scenario files").expect("the section")..];
    let start = section.find("```toml\n").expect("a TOML block") + "```toml\n".len();
    let block = &section[start..start + section[start..].find("```").unwrap()];
    let set = evitrack::scenario::ScenarioSet::parse(block, "README.md")
        .unwrap_or_else(|e| panic!("{e}"));
    // One listed variant and a grid of three.
    assert_eq!(set.variants.len(), 4);
    assert!(!set.base.fault_plan().is_empty());
}

#[test]
fn sweeps_over_seeds_give_intervals_and_paired_findings_whatever_the_job_count() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = dir.path().join("seeds.toml");
    let extra = "[[sweep.variant]]\nname = \"n2\"\n[[sweep.variant]]\nname = \"n3\"\n\
                 set = { \"model.states\" = 3 }\n[[sweep.finding]]\nname = \"n3 < n2\"\n\
                 left = \"n3\"\nright = \"n2\"\n";
    std::fs::write(&scenario, small_scenario("seeds", extra)).unwrap();
    let sweep = |jobs: &str| {
        let out = dir.path().join(format!("out{jobs}"));
        let run = evitrack(
            &[
                "sweep",
                scenario.to_str().unwrap(),
                "--seeds",
                "3",
                "--jobs",
                jobs,
                "--out",
                out.to_str().unwrap(),
            ],
            "",
        );
        assert!(
            run.status.success(),
            "{}",
            String::from_utf8_lossy(&run.stderr)
        );
        let file: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("sweep.json")).unwrap())
                .unwrap();
        let frames = std::fs::read(out.join("seeds-n3/seed-3/frames.csv")).unwrap();
        (
            file,
            frames,
            String::from_utf8_lossy(&run.stdout).into_owned(),
            String::from_utf8_lossy(&run.stderr).into_owned(),
        )
    };
    let (one, frames_one, table, _) = sweep("1");
    let (two, frames_two, _, progress) = sweep("2");
    assert_progress_is_counted_and_bounded(&progress, 6);
    assert_eq!(
        one["across_seeds"], two["across_seeds"],
        "the job count changes nothing"
    );
    assert_eq!(frames_one, frames_two);
    assert_eq!(one["runs"].as_array().unwrap().len(), 6);
    let finding = &one["across_seeds"]["findings"][0];
    assert_eq!(finding["comparison"]["name"], "n3 < n2");
    assert_eq!(finding["difference"]["n"], 3);
    assert!(finding["difference"]["half_width"].as_f64().is_some());
    assert!(
        table.contains("n3 < n2") && table.contains(" ± "),
        "{table}"
    );
    // The finding says in words whether its claim holds, with the numbers.
    let line = table.lines().find(|l| l.contains("n3 < n2")).unwrap();
    assert!(
        ["holds: ", "does not hold: ", "not shown: "]
            .iter()
            .any(|words| line.contains(&format!("{words}left − right = ")))
            && line.contains(" mm, "),
        "{line}"
    );
    let variant = &one["across_seeds"]["variants"][0];
    assert_eq!(variant["seeds"], serde_json::json!([1, 2, 3]));
}

/// A sweep's stderr through a pipe: one line per finished run counting them right, `runs` in
/// all and run now, a bounded size, and no counter past its total.
fn assert_progress_is_counted_and_bounded(stderr: &str, runs: usize) {
    for k in 1..=runs {
        assert!(
            stderr.contains(&format!("[{k}/{runs} runs] ")),
            "{k}: {stderr}"
        );
    }
    assert!(
        stderr.contains(&format!("{runs} runs, all run now, in ")),
        "{stderr}"
    );
    assert!(
        stderr.len() < 300 * runs + 1000,
        "{} bytes: {stderr}",
        stderr.len()
    );
    for word in stderr.split_whitespace() {
        let counter = word.trim_matches(|c: char| !c.is_ascii_digit() && c != '/');
        if let Some((done, total)) = counter.split_once('/') {
            if let (Ok(done), Ok(total)) = (done.parse::<u64>(), total.parse::<u64>()) {
                assert!(done <= total, "{word} in {stderr}");
            }
        }
    }
}

#[test]
fn the_scale_scenario_runs_end_to_end_within_its_expectations() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = concat!(env!("CARGO_MANIFEST_DIR"), "/scenarios/scale.toml");
    let out = evitrack(
        &[
            "sweep",
            scenario,
            "--out",
            dir.path().to_str().unwrap(),
            "--check",
        ],
        "",
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let results: serde_json::Value = serde_json::from_slice(
        &std::fs::read(dir.path().join("scale").join("results.json")).unwrap(),
    )
    .unwrap();
    // 10,000 sample poses, 32 features of 3 states, all combined on every frame.
    assert_eq!(results["samples"], 10_000);
    assert_eq!(results["features"].as_array().map(Vec::len), Some(32));
    assert_eq!(
        results["evidential"]["states"],
        serde_json::json!(vec![3; 32])
    );
    assert_eq!(results["methods"][0]["method"], "evidential");
    assert_eq!(results["methods"][0]["mean_group_size"], 32.0);
}

/// `scenarios/time.toml` (issue 17): seed 1 meets its expectations, and the README's reading
/// holds on seeds 1 and 2 (means over both; the measured values are in the comments). The
/// README's figures rest on 5 seeds (`evitrack sweep scenarios/time.toml --seeds 5`); CI runs 2
/// to stay short (issue 32), each figure held within 3 % of what those 2 seeds measured.
#[test]
fn the_time_scenario_meets_its_expectations_and_the_readme_reading() {
    const SEEDS: u64 = 2;
    let scenario = concat!(env!("CARGO_MANIFEST_DIR"), "/scenarios/time.toml");
    let dir = tempfile::tempdir().unwrap();
    let seeds = SEEDS.to_string();
    let out = evitrack(
        &[
            "sweep",
            scenario,
            "--out",
            dir.path().to_str().unwrap(),
            "--jobs",
            "2",
            "--check",
            "--seeds",
            &seeds,
        ],
        "",
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let method = |variant: &str, seed: u64, name: &str| -> serde_json::Value {
        let path = dir
            .path()
            .join(format!("time-{variant}"))
            .join(format!("seed-{seed}"))
            .join("results.json");
        let results: serde_json::Value =
            serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap();
        results["methods"]
            .as_array()
            .unwrap()
            .iter()
            .find(|m| m["method"] == name)
            .unwrap_or_else(|| panic!("{variant}: no {name}"))
            .clone()
    };
    let mean = |variant: &str, name: &str| {
        (1..=SEEDS)
            .map(|s| method(variant, s, name)["error"]["mean"].as_f64().unwrap())
            .sum::<f64>()
            / SEEDS as f64
    };
    let struck = |variant: &str, seed: u64, name: &str| {
        method(variant, seed, name)["faults"]["error_corrupted"]["mean"]
            .as_f64()
            .unwrap()
    };
    let struck_mean = |variant: &str, name: &str| {
        (1..=SEEDS).map(|s| struck(variant, s, name)).sum::<f64>() / SEEDS as f64
    };
    let within = |value: f64, measured: f64, what: &str| {
        assert!(
            (value / measured - 1.0).abs() <= 0.03,
            "{what}: {value}, measured {measured}"
        );
    };
    // Occlusion bursts: the past divides the struck frames' error by 2.63 (5 seeds: 3.18), by
    // 2.28 or more on each seed (2.39 with a 50 mm/s reach).
    within(
        struck_mean("occlusion", "evidential") / struck_mean("occlusion", "evidential_temporal"),
        2.628,
        "occlusion, evidential over time",
    );
    for (variant, least) in [("occlusion", 2.21), ("occlusion-v50", 2.32)] {
        let lowest = (1..=SEEDS)
            .map(|seed| {
                struck(variant, seed, "evidential") / struck(variant, seed, "evidential_temporal")
            })
            .fold(f64::INFINITY, f64::min);
        assert!(lowest >= least, "{variant}: lowest ratio {lowest}");
    }
    // The filter (σ and ε learned): 0.0273 mm on clean frames, 4.037 on struck occlusion frames,
    // 1.081 on lost frames, 0.310 on the fast circle.
    let filter = |variant: &str| mean(variant, "particle_filter");
    within(filter("clean"), 0.02729, "filter, clean");
    within(filter("fast"), 0.3104, "filter, fast");
    for (name, measured) in [
        ("particle_filter", 4.037),
        ("continuous_temporal", 7.274),
        ("evidential_temporal", 3.271),
    ] {
        within(struck_mean("occlusion", name), measured, name);
    }
    assert!(mean("fast", "continuous_temporal") * 10.0 < filter("fast"));
    assert!(filter("clean") * 10.0 < mean("clean", "evidential_temporal"));
    assert!(filter("fast") < mean("fast", "evidential_temporal"));
    assert!(mean("clean", "continuous_temporal") < filter("clean"));
    // The continuous tracker over time: struck frames' error divided by 1.42 (5 seeds: 2.05),
    // by 1.12 or more on each seed with 50 mm/s; the same estimates as per frame on clean
    // frames and on the fast circle.
    within(
        struck_mean("occlusion", "continuous") / struck_mean("occlusion", "continuous_temporal"),
        1.420,
        "occlusion, continuous over time",
    );
    for seed in 1..=SEEDS {
        let r = struck("occlusion-v50", seed, "continuous")
            / struck("occlusion-v50", seed, "continuous_temporal");
        assert!(r >= 1.09, "continuous, occlusion-v50 seed {seed}: {r}");
    }
    for variant in ["clean", "fast", "fast-v50"] {
        let r = mean(variant, "continuous_temporal") / mean(variant, "continuous");
        assert!((r - 1.0).abs() < 1e-3, "continuous, {variant}: {r}");
    }
    // Clean frames: 0.908× with the past, lower on each seed; the fast circle: 0.952× with the
    // 80 mm/s reach and 0.954× with 50 mm/s (no lag: the line's spread widens to its misses).
    within(
        mean("clean", "evidential_temporal") / mean("clean", "evidential"),
        0.9080,
        "clean, evidential over time",
    );
    for seed in 1..=SEEDS {
        let per_frame = method("clean", seed, "evidential")["error"]["mean"].as_f64();
        let temporal = method("clean", seed, "evidential_temporal")["error"]["mean"].as_f64();
        assert!(temporal < per_frame, "clean seed {seed}");
    }
    for (variant, measured) in [("fast", 0.9520), ("fast-v50", 0.9544)] {
        let r = mean(variant, "evidential_temporal") / mean(variant, "evidential");
        within(r, measured, variant);
    }
    // Lost frames, predicted: 1.083 mm (evidential), 0.990 (continuous), 1.081 (filter).
    for (name, measured) in [
        ("evidential_temporal", 1.083),
        ("continuous_temporal", 0.990),
        ("particle_filter", 1.081),
    ] {
        within(struck_mean("dropped", name), measured, name);
    }
    // Lost frames: a flagged prediction from the temporal methods, none from the per-frame ones.
    let lost = method("dropped", 1, "evidential")["faults"]["corrupted_frames"].clone();
    assert!(lost.as_u64().unwrap() > 0);
    assert_eq!(
        method("dropped", 1, "evidential")["frames_without_estimate"],
        lost
    );
    for name in [
        "evidential_temporal",
        "continuous_temporal",
        "particle_filter",
    ] {
        assert_eq!(
            method("dropped", 1, name)["frames_without_estimate"],
            0,
            "{name}"
        );
    }
    let frames = std::fs::read_to_string(
        dir.path()
            .join("time-dropped")
            .join("seed-1")
            .join("frames.csv"),
    )
    .unwrap();
    let predicted = frames
        .lines()
        .filter(|l| {
            l.starts_with("evidential_temporal,")
                && l.contains("predicted")
                && l.contains("missing:")
        })
        .count();
    assert_eq!(predicted as u64, lost.as_u64().unwrap());
}
