//! The time scenario from the command line: per-frame against temporal tracking (issue 17).

use super::*;

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
