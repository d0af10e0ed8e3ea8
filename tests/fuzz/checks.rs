//! What every fuzz target checks, shared by the `cargo fuzz` targets beside this file and by the
//! bounded run in `cargo test` (`tests/fuzz_corpus.rs`): the input is read, and either refused
//! with an error that says something, or accepted with only finite numbers in what comes out.
//! A panic anywhere is a failure. Each check says whether the input was accepted.

use evitrack::dataset::Dataset;
use evitrack::estimator::{Centre, Continuous, Evidential, Gp, Knn, PoseEstimator};
use evitrack::evidence::exchange::{combine_json_within, CombineLimits};
use evitrack::evidence::WorkLimits;
use evitrack::model::EvidentialModel;
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

/// A model file of any method; a model that loads estimates a few frames.
pub fn model(data: &[u8]) -> bool {
    let Ok(text) = std::str::from_utf8(data) else {
        return false;
    };
    let mut accepted = false;
    let loaded: [Result<Box<dyn PoseEstimator>, String>; 5] = [
        EvidentialModel::from_json(text)
            .map_err(|e| e.to_string())
            .and_then(|m| Evidential::from_model(m).map_err(|e| e.to_string()))
            .map(|e| Box::new(e) as Box<dyn PoseEstimator>),
        Knn::from_json(text)
            .map(|e| Box::new(e) as _)
            .map_err(|e| e.to_string()),
        Gp::from_json(text)
            .map(|e| Box::new(e) as _)
            .map_err(|e| e.to_string()),
        Centre::from_json(text)
            .map(|e| Box::new(e) as _)
            .map_err(|e| e.to_string()),
        Continuous::from_json(text)
            .map(|e| Box::new(e) as _)
            .map_err(|e| e.to_string()),
    ];
    for estimator in loaded {
        match estimator {
            Err(e) => said_something(e),
            Ok(estimator) => {
                accepted = true;
                let n = estimator.feature_names().len();
                for row in [vec![Some(0.0); n], vec![None; n], vec![Some(1e300); n]] {
                    match estimator.estimate(&row) {
                        Err(e) => said_something(e),
                        Ok(estimate) => {
                            if let Some(p) = estimate.pose {
                                assert!(p.iter().all(|v| v.is_finite()), "pose {p:?}");
                            }
                        }
                    }
                }
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
