//! Memoised datasets and feature rows, shared by the variants of a sweep (and its threads).
//!
//! Every dataset is a pure function of its settings and seed, so results do not depend on which
//! variant asked first.

use std::collections::HashMap;
use std::convert::Infallible;
use std::sync::{Arc, Mutex, OnceLock};

use super::ExperimentError;
use crate::dataset::Dataset;
use crate::features::{FeatureConfig, FeatureRows, FeatureSet};
use crate::sim::{Motion, SimError, SimSettings};

type Shared<T, E> = Arc<OnceLock<Result<Arc<T>, E>>>;

/// What [`Workbench::features`] is doing when it reports progress.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Step {
    /// Simulating the dataset.
    Simulate,
    /// Extracting its features.
    Extract,
}

/// Memoised datasets and feature matrices, keyed by their settings.
#[derive(Default)]
pub struct Workbench {
    datasets: Mutex<HashMap<String, Shared<Dataset, Arc<SimError>>>>,
    features: Mutex<HashMap<String, Shared<FeatureRows, Infallible>>>,
    /// Threads one simulation or extraction may use (0 and 1: the calling thread only).
    threads: usize,
}

fn memo<T, E: Clone>(
    map: &Mutex<HashMap<String, Shared<T, E>>>,
    key: String,
    make: impl FnOnce() -> Result<T, E>,
) -> Result<Arc<T>, E> {
    let cell = {
        // A poisoned lock only means another thread panicked while inserting; the map is intact.
        let mut guard = map.lock().unwrap_or_else(|e| e.into_inner());
        guard.entry(key).or_default().clone()
    };
    cell.get_or_init(|| make().map(Arc::new)).clone()
}

impl Workbench {
    /// A new, empty workbench that simulates and extracts on the calling thread.
    pub fn new() -> Self {
        Self::default()
    }

    /// A new, empty workbench whose simulations and feature extractions each use up to
    /// `threads` threads ([`crate::sim::simulate_on`], [`FeatureSet::extract_on`]); with two or
    /// more, [`super::run`] also simulates a scenario's motions side by side. The datasets and
    /// rows are the same whatever `threads`.
    pub fn with_threads(threads: usize) -> Self {
        Self {
            threads,
            ..Self::default()
        }
    }

    /// The threads one simulation or extraction may use (at least 1).
    pub fn threads(&self) -> usize {
        self.threads.max(1)
    }

    /// The dataset `motion` produces on `sim` with `seed`, simulated once.
    pub fn dataset(
        &self,
        sim: &SimSettings,
        motion: &Motion,
        seed: u64,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<Arc<Dataset>, ExperimentError> {
        let key = serde_json::json!({"sim": sim, "motion": motion, "seed": seed}).to_string();
        memo(&self.datasets, key, || {
            crate::sim::simulate_on(sim, motion, seed, self.threads(), progress).map_err(Arc::new)
        })
        .map_err(|source| ExperimentError::Simulate {
            what: motion.name().to_string(),
            source,
        })
    }

    /// The feature rows of a dataset obtained as in [`Workbench::dataset`], extracted with
    /// `set`, the checked form of `config`. `progress(step, done, total)` counts frames.
    pub fn features(
        &self,
        sim: &SimSettings,
        motion: &Motion,
        seed: u64,
        config: &FeatureConfig,
        set: &FeatureSet,
        progress: &mut dyn FnMut(Step, usize, usize),
    ) -> Result<Arc<FeatureRows>, ExperimentError> {
        let dataset = self.dataset(sim, motion, seed, &mut |d, t| {
            progress(Step::Simulate, d, t)
        })?;
        let key =
            serde_json::json!({"sim": sim, "motion": motion, "seed": seed, "features": config})
                .to_string();
        let rows = memo(&self.features, key, || {
            let images: Vec<_> = dataset.images().collect();
            let rows = set.extract_on(&images, self.threads(), &mut |d, t| {
                progress(Step::Extract, d, t)
            });
            Ok::<_, Infallible>(rows)
        });
        Ok(rows.unwrap_or_else(|never| match never {}))
    }
}
