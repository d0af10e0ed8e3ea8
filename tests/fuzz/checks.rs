//! What every fuzz target checks, shared by the `cargo fuzz` targets beside this file and by the
//! bounded run in `cargo test` (`tests/fuzz_corpus.rs`): the input is read, and either refused
//! with an error that says something, or accepted with only finite numbers in what comes out.
//! A panic anywhere is a failure. Each check says whether the input was accepted.

use evitrack::dataset::Dataset;
use evitrack::estimator::{load_text, Method, PoseEstimate};
use evitrack::evidence::exchange::{combine_json_within, CombineLimits};
use evitrack::evidence::WorkLimits;
use evitrack::scenario::ScenarioSet;

/// Small limits, so that a fuzzed input cannot spend the run's memory.
const LIMITS: CombineLimits = CombineLimits {
    work: WorkLimits {
        focal_sets: 4096,
        set_bytes: 1 << 22,
        tuples: 1 << 16,
    },
    output_elements: 1 << 16,
};

fn said_something(error: impl std::fmt::Display) {
    assert!(
        !error.to_string().trim().is_empty(),
        "an empty error message"
    );
}

/// `evitrack combine` on `data` as JSON.
pub fn combine(data: &[u8]) -> bool {
    let Ok(text) = std::str::from_utf8(data) else {
        return false;
    };
    match combine_json_within(text, &LIMITS) {
        Err(e) => said_something(e),
        Ok(report) => {
            let kappa = report.conflict_mass;
            assert!((0.0..=1.0).contains(&kappa), "conflict mass {kappa}");
            assert!(!report.conflict_level.value().is_nan());
            for &m in report.mass.iter().chain(&report.plausibility) {
                assert!(m.is_finite() && m >= 0.0, "mass or plausibility {m}");
            }
            serde_json::to_string(&report).expect("the report serialises");
            return true;
        }
    }
    false
}

/// A scenario file (`run` and `sweep` read it; nothing runs).
pub fn scenario(data: &[u8]) -> bool {
    let Ok(text) = std::str::from_utf8(data) else {
        return false;
    };
    match ScenarioSet::parse(text, "fuzz.toml") {
        Err(e) => said_something(e),
        Ok(set) => {
            assert!(!set.variants.is_empty());
            for variant in &set.variants {
                variant.to_toml().expect("a checked scenario serialises");
            }
            return true;
        }
    }
    false
}

/// Every number of an estimate: poses, radii, covariances and regions finite; a level or a
/// score finite or the documented +∞ (total conflict, no sample near), never NaN or −∞.
fn check_estimate(estimate: &PoseEstimate) {
    let finite = |what: &str, v: f64| assert!(v.is_finite(), "{what} {v}");
    if let Some(p) = estimate.pose {
        p.iter().for_each(|&v| finite("pose", v));
    }
    if let Some(r) = estimate.uncertainty_radius {
        assert!(r.is_finite() && r >= 0.0, "uncertainty radius {r}");
    }
    for (what, v) in [
        ("conflict level", estimate.conflict_level),
        ("detection score", estimate.detection_score),
    ] {
        if let Some(v) = v {
            assert!(!v.is_nan() && v != f64::NEG_INFINITY, "{what} {v}");
        }
    }
    if let Some(c) = estimate.covariance {
        c.iter().flatten().for_each(|&v| finite("covariance", v));
    }
    if let Some(region) = &estimate.region {
        region
            .centre
            .iter()
            .for_each(|&v| finite("region centre", v));
        region
            .shape
            .iter()
            .flatten()
            .for_each(|&v| finite("region shape", v));
        for (what, v) in [
            ("region level", region.level),
            ("region area", region.area),
            ("region semi-major axis", region.semi_major),
        ] {
            finite(what, v);
        }
    }
}

/// A model file of any registered method (as `track` reads it, calibration included); a model
/// that loads estimates a few frames alone and over a motion, and writes a file that loads.
pub fn model(data: &[u8]) -> bool {
    let Ok(text) = std::str::from_utf8(data) else {
        return false;
    };
    let mut accepted = false;
    let path = std::path::Path::new("fuzz.json");
    for method in Method::all() {
        let estimator = match load_text(method, path, text) {
            Err(e) => {
                said_something(e);
                continue;
            }
            Ok(estimator) => estimator,
        };
        accepted = true;
        let n = estimator.feature_names().len();
        let rows = [vec![Some(0.0); n], vec![None; n], vec![Some(1e300); n]];
        for row in &rows {
            match estimator.estimate(row) {
                Err(e) => said_something(e),
                Ok(estimate) => check_estimate(&estimate),
            }
        }
        let mut motion = estimator.start_motion();
        for (k, row) in rows.iter().chain(&rows).enumerate() {
            match motion.next(0.05 * k as f64, row) {
                Err(e) => said_something(e),
                Ok(estimate) => check_estimate(&estimate),
            }
        }
        drop(motion);
        match estimator.to_json() {
            Err(e) => said_something(e),
            Ok(written) => {
                load_text(method, path, &written).expect("a written model file loads again");
            }
        }
    }
    accepted
}

/// A dataset folder from `data`: the manifest, `poses.csv` and one frame's PNG bytes, separated
/// by NUL bytes (missing parts are left out of the folder).
pub fn dataset(data: &[u8]) -> bool {
    let mut parts = data.splitn(3, |&b| b == 0);
    let dir = tempfile::tempdir().expect("a temporary folder");
    for name in ["manifest.json", "poses.csv", "frames/00000.png"] {
        if let Some(part) = parts.next() {
            let path = dir.path().join(name);
            std::fs::create_dir_all(path.parent().expect("a parent")).expect("a folder");
            std::fs::write(path, part).expect("a file");
        }
    }
    match Dataset::read(dir.path()) {
        Err(e) => {
            said_something(e);
            false
        }
        Ok(dataset) => {
            for truth in dataset.frames.iter().filter_map(|f| f.truth) {
                truth
                    .check(dataset.manifest.workspace.as_ref())
                    .expect("a pose that was read is a pose of the rig");
            }
            true
        }
    }
}
