//! `scenarios/time.toml` (issue 17): per-frame against temporal tracking. Seed 1 of each variant
//! meets its expectations (as `sweep --check` holds them), and the README's reading holds on
//! seeds 1 and 2 (means over both; the measured values are in the comments). The README's
//! figures rest on 5 seeds (`evitrack sweep scenarios/time.toml --seeds 5`); CI runs 2 to stay
//! short (issue 32), each figure held within 3 % of what those 2 seeds measured. Every reading
//! concerns one variant, so each test runs only the variants it reads; the fits, shared by every
//! variant of a seed, come once from the process's workbench (`crate::bench`).

use std::collections::HashMap;

use evitrack::experiment::{run_all, RunOutput};
use evitrack::report::MethodSummary;
use evitrack::scenario::SeedList;

const SEEDS: u64 = 2;

/// The runs of `variants` (names after `time-`) on seeds 1 to [`SEEDS`], keyed by (variant,
/// seed); seed 1 of each meets its expectations.
fn time_runs(variants: &[&str]) -> HashMap<(String, u64), RunOutput> {
    let set = crate::load_scenario("time.toml");
    let runs: Vec<_> = (set
        .seeded(Some(&SeedList::Count(SEEDS)))
        .unwrap()
        .into_iter())
    .filter(|r| variants.contains(&r.name().strip_prefix("time-").unwrap()))
    .collect();
    assert_eq!(runs.len(), variants.len() * SEEDS as usize, "{variants:?}");
    let mut out = HashMap::new();
    for (result, run) in run_all(&runs, 2, crate::bench(), &|_, _, _, _| {})
        .into_iter()
        .zip(&runs)
    {
        let output = result.unwrap_or_else(|e| panic!("{} failed: {e}", run.name()));
        if run.seed == 1 {
            let missed = output.summary.regressions();
            assert!(missed.is_empty(), "{}: {missed:#?}", run.name());
        }
        let variant = run.name().strip_prefix("time-").unwrap().to_string();
        out.insert((variant, run.seed), output);
    }
    assert_eq!(
        out.keys().map(|k| k.1).max(),
        Some(SEEDS),
        "seeds 1 to {SEEDS}"
    );
    out
}

struct Runs(HashMap<(String, u64), RunOutput>);

impl Runs {
    fn new(variants: &[&str]) -> Self {
        Self(time_runs(variants))
    }

    fn method(&self, variant: &str, seed: u64, name: &str) -> &MethodSummary {
        self.0[&(variant.to_string(), seed)]
            .summary
            .method(name)
            .unwrap_or_else(|| panic!("{variant}: no {name}"))
    }

    fn error(&self, variant: &str, seed: u64, name: &str) -> f64 {
        self.method(variant, seed, name).error.unwrap().mean
    }

    /// The mean error over the seeds.
    fn mean(&self, variant: &str, name: &str) -> f64 {
        (1..=SEEDS)
            .map(|s| self.error(variant, s, name))
            .sum::<f64>()
            / SEEDS as f64
    }

    /// The mean error on the frames a fault struck.
    fn struck(&self, variant: &str, seed: u64, name: &str) -> f64 {
        let faults = self.method(variant, seed, name).faults.as_ref().unwrap();
        faults.error_corrupted.as_ref().unwrap().mean
    }

    fn struck_mean(&self, variant: &str, name: &str) -> f64 {
        (1..=SEEDS)
            .map(|s| self.struck(variant, s, name))
            .sum::<f64>()
            / SEEDS as f64
    }
}

fn within(value: f64, measured: f64, what: &str) {
    assert!(
        (value / measured - 1.0).abs() <= 0.03,
        "{what}: {value}, measured {measured}"
    );
}

#[test]
fn the_time_scenario_under_occlusion_bursts_meets_the_readme_reading() {
    let runs = Runs::new(&["occlusion", "occlusion-v50"]);
    // The past divides the struck frames' error by 2.63 (5 seeds: 3.18), by 2.28 or more on
    // each seed (2.39 with a 50 mm/s reach).
    within(
        runs.struck_mean("occlusion", "evidential")
            / runs.struck_mean("occlusion", "evidential_temporal"),
        2.628,
        "occlusion, evidential over time",
    );
    for (variant, least) in [("occlusion", 2.21), ("occlusion-v50", 2.32)] {
        let lowest = (1..=SEEDS)
            .map(|seed| {
                runs.struck(variant, seed, "evidential")
                    / runs.struck(variant, seed, "evidential_temporal")
            })
            .fold(f64::INFINITY, f64::min);
        assert!(lowest >= least, "{variant}: lowest ratio {lowest}");
    }
    // On struck frames: the filter 4.471 mm (its recovery on; 3.923 without), the continuous
    // tracker over time 7.274, the evidential one 3.271.
    for (name, measured) in [
        ("particle_filter", 4.471),
        ("continuous_temporal", 7.274),
        ("evidential_temporal", 3.271),
    ] {
        within(runs.struck_mean("occlusion", name), measured, name);
    }
    // The continuous tracker over time: struck frames' error divided by 1.42 (5 seeds: 2.05),
    // by 1.12 or more on each seed with 50 mm/s.
    within(
        runs.struck_mean("occlusion", "continuous")
            / runs.struck_mean("occlusion", "continuous_temporal"),
        1.420,
        "occlusion, continuous over time",
    );
    for seed in 1..=SEEDS {
        let r = runs.struck("occlusion-v50", seed, "continuous")
            / runs.struck("occlusion-v50", seed, "continuous_temporal");
        assert!(r >= 1.09, "continuous, occlusion-v50 seed {seed}: {r}");
    }
}

#[test]
fn the_time_scenario_on_clean_frames_and_the_fast_circle_meets_the_readme_reading() {
    let runs = Runs::new(&["clean", "fast", "fast-v50"]);
    // The filter (20,000 particles, σ and ε learned, its recovery on): 0.0196 mm on clean
    // frames, 0.0437 on the fast circle, over twice the continuous tracker over time there
    // (5 seeds: 0.0210, 0.0391, 2.2×; without the recovery 0.0220, 0.102, 5.5×).
    let filter = |variant: &str| runs.mean(variant, "particle_filter");
    within(filter("clean"), 0.01965, "filter, clean");
    within(filter("fast"), 0.04370, "filter, fast");
    assert!(runs.mean("fast", "continuous_temporal") * 2.0 < filter("fast"));
    assert!(filter("clean") * 10.0 < runs.mean("clean", "evidential_temporal"));
    assert!(filter("fast") < runs.mean("fast", "evidential_temporal"));
    assert!(runs.mean("clean", "continuous_temporal") < filter("clean"));
    // The continuous tracker over time gives the same estimates as per frame on clean frames
    // and on the fast circle.
    for variant in ["clean", "fast", "fast-v50"] {
        let r = runs.mean(variant, "continuous_temporal") / runs.mean(variant, "continuous");
        assert!((r - 1.0).abs() < 1e-3, "continuous, {variant}: {r}");
    }
    // Clean frames: 0.908× with the past, lower on each seed; the fast circle: 0.952× with the
    // 80 mm/s reach and 0.954× with 50 mm/s (no lag: the line's spread widens to its misses).
    within(
        runs.mean("clean", "evidential_temporal") / runs.mean("clean", "evidential"),
        0.9080,
        "clean, evidential over time",
    );
    for seed in 1..=SEEDS {
        let per_frame = runs.error("clean", seed, "evidential");
        let temporal = runs.error("clean", seed, "evidential_temporal");
        assert!(temporal < per_frame, "clean seed {seed}");
    }
    for (variant, measured) in [("fast", 0.9520), ("fast-v50", 0.9544)] {
        let r = runs.mean(variant, "evidential_temporal") / runs.mean(variant, "evidential");
        within(r, measured, variant);
    }
}

#[test]
fn the_time_scenario_predicts_lost_frames_as_the_readme_reads() {
    let runs = Runs::new(&["dropped"]);
    // Lost frames, predicted: 1.083 mm (evidential), 0.990 (continuous), 1.069 (filter).
    for (name, measured) in [
        ("evidential_temporal", 1.083),
        ("continuous_temporal", 0.990),
        ("particle_filter", 1.069),
    ] {
        within(runs.struck_mean("dropped", name), measured, name);
    }
    // A flagged prediction from the temporal methods, none from the per-frame ones.
    let per_frame = runs.method("dropped", 1, "evidential");
    let lost = per_frame.faults.as_ref().unwrap().corrupted_frames;
    assert!(lost > 0);
    assert_eq!(per_frame.frames_without_estimate, lost);
    for name in [
        "evidential_temporal",
        "continuous_temporal",
        "particle_filter",
    ] {
        let m = runs.method("dropped", 1, name);
        assert_eq!(m.frames_without_estimate, 0, "{name}");
    }
    // As `frames.csv` writes them.
    let output = &runs.0[&("dropped".to_string(), 1)];
    let mut frames = Vec::new();
    evitrack::report::write_frames_csv(&mut frames, &output.records, &output.summary.features)
        .unwrap();
    let predicted = String::from_utf8(frames)
        .unwrap()
        .lines()
        .filter(|l| {
            l.starts_with("evidential_temporal,")
                && l.contains("predicted")
                && l.contains("missing:")
        })
        .count();
    assert_eq!(predicted, lost);
}
