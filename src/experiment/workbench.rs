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

/// Memoised datasets and feature matrices, keyed by their settings.
#[derive(Default)]
pub struct Workbench {
    datasets: Mutex<HashMap<String, Shared<Dataset, Arc<SimError>>>>,
    features: Mutex<HashMap<String, Shared<FeatureRows, Infallible>>>,
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
    /// A new, empty workbench.
    pub fn new() -> Self {
        Self::default()
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
            crate::sim::simulate(sim, motion, seed, progress).map_err(Arc::new)
        })
        .map_err(|source| ExperimentError::Simulate {
            what: motion.name().to_string(),
            source,
        })
    }

    /// The feature rows of a dataset obtained as in [`Workbench::dataset`], extracted with
    /// `set`, the checked form of `config`.
    pub fn features(
        &self,
        sim: &SimSettings,
        motion: &Motion,
        seed: u64,
        config: &FeatureConfig,
        set: &FeatureSet,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<Arc<FeatureRows>, ExperimentError> {
        let dataset = self.dataset(sim, motion, seed, progress)?;
        let key =
            serde_json::json!({"sim": sim, "motion": motion, "seed": seed, "features": config})
                .to_string();
        let rows = memo(&self.features, key, || {
            Ok::<_, Infallible>(set.extract_batch(dataset.images()))
        });
        Ok(rows.unwrap_or_else(|never| match never {}))
    }
}
