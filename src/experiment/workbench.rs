//! Memoised datasets, feature rows and costly fits, shared by the variants of a sweep (and its
//! threads).
//!
//! Every dataset is a pure function of its settings and seed, and every shared fit a pure
//! function of its settings and training data, so results do not depend on which variant asked
//! first.

use std::collections::HashMap;
use std::convert::Infallible;
use std::hash::Hash;
use std::sync::{Arc, Mutex, OnceLock};

use super::render_check::Learned;
use super::ExperimentError;
use crate::dataset::Dataset;
use crate::estimator::{
    ConfidenceSettings, EstimatorError, EstimatorSettings, Labelled, Method, PoseEstimator,
    RenderSource, TrainingSet,
};
use crate::external::ExternalError;
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
    features: Mutex<HashMap<String, Shared<FeatureRows, Arc<ExternalError>>>>,
    /// Fits of the methods that share them (`gp`, `continuous`), keyed by [`fit_key`]; `None`
    /// when the fit failed (each later caller then fits again for its own error).
    fits: Mutex<HashMap<Vec<u8>, SharedFit>>,
    /// The render check's learned silhouettes, keyed by what they depend on; `None` where the
    /// sample frames show too few silhouettes.
    render_checks: Mutex<HashMap<String, SharedRenderCheck>>,
    /// Threads one simulation or extraction may use (0 and 1: the calling thread only).
    threads: usize,
}

type SharedFit = Arc<OnceLock<Option<Arc<dyn PoseEstimator>>>>;

type SharedRenderCheck = Shared<Option<Arc<Learned>>, Infallible>;

fn memo<K: Hash + Eq, T, E: Clone>(
    map: &Mutex<HashMap<K, Shared<T, E>>>,
    key: K,
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
    /// `set`, the checked form of `config` (its external programs run once per dataset).
    /// `progress(step, done, total)` counts frames.
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
        let key = |config: &FeatureConfig| {
            serde_json::json!({"sim": sim, "motion": motion, "seed": seed, "features": config})
                .to_string()
        };
        let extract = |set: &FeatureSet, progress: &mut dyn FnMut(usize, usize)| {
            crate::external::extract(set, &dataset, self.threads(), progress).map_err(Arc::new)
        };
        let parts = extractor_parts(config, set);
        let rows = memo(&self.features, key(config), || {
            if parts.len() < 2 {
                return extract(set, &mut |d, t| progress(Step::Extract, d, t));
            }
            // Each extractor's values depend on it and the image alone, so a row is its parts'
            // rows one after the other; a part that another variant extracts is taken from it.
            let count = parts.len();
            let mut joined: FeatureRows = Vec::new();
            for (k, (part, part_set)) in parts.iter().enumerate() {
                let rows = memo(&self.features, key(part), || {
                    extract(part_set, &mut |d, t| {
                        progress(Step::Extract, k * t + d, count * t)
                    })
                })?;
                if k == 0 {
                    joined = rows.as_ref().clone();
                } else {
                    joined.iter_mut().zip(rows.iter()).for_each(|(row, part)| {
                        row.extend_from_slice(part);
                    });
                }
            }
            Ok(joined)
        });
        rows.map_err(|source| ExperimentError::External {
            what: motion.name().to_string(),
            source,
        })
    }

    /// The render check's silhouettes learned by `learn` for `key` (the JSON of everything they
    /// depend on), learned once.
    pub(super) fn render_check(
        &self,
        key: String,
        learn: impl FnOnce() -> Option<Learned>,
    ) -> Option<Arc<Learned>> {
        let learned = memo(&self.render_checks, key, || Ok(learn().map(Arc::new)));
        match learned {
            Ok(learned) => learned.as_ref().clone(),
            Err(never) => match never {},
        }
    }

    /// How many distinct shared fits the workbench holds.
    pub fn shared_fits(&self) -> usize {
        self.fits.lock().unwrap_or_else(|e| e.into_inner()).len()
    }

    /// `method` fitted on `data` with `settings`. Methods that share fits are fitted once per
    /// distinct settings and training data and handed out with `data`'s provenance; the others
    /// are fitted on every call.
    ///
    /// # Errors
    /// The method's fitting errors.
    pub fn fit(
        &self,
        method: Method,
        settings: &EstimatorSettings,
        data: &TrainingSet,
    ) -> Result<Box<dyn PoseEstimator>, EstimatorError> {
        let Some(key) = fit_key(method, settings, data) else {
            return method.fit(settings, data);
        };
        let cell = {
            let mut guard = self.fits.lock().unwrap_or_else(|e| e.into_inner());
            guard.entry(key).or_default().clone()
        };
        let mut failure = None;
        let shared = cell.get_or_init(|| match method.fit(settings, data) {
            Ok(fitted) => Some(Arc::from(fitted)),
            Err(error) => {
                failure = Some(error);
                None
            }
        });
        if let Some(error) = failure {
            return Err(error);
        }
        match shared
            .as_ref()
            .and_then(|f| f.with_provenance(&data.provenance))
        {
            Some(fitted) => Ok(fitted),
            None => method.fit(settings, data),
        }
    }
}

/// `config` split into one configuration per built-in extractor (size functions, barycentre,
/// tiles), each with its checked set, when it has two or more of them and no external program,
/// and the parts' names are the set's in order; otherwise nothing (extract it whole).
fn extractor_parts(config: &FeatureConfig, set: &FeatureSet) -> Vec<(FeatureConfig, FeatureSet)> {
    if !config.external.is_empty() {
        return Vec::new();
    }
    let alone = |part: usize| {
        let mut c = config.clone();
        c.size_functions.enabled = part == 0 && config.size_functions.enabled;
        c.barycentre.enabled = part == 1 && config.barycentre.enabled;
        c.tiles.enabled = part == 2 && config.tiles.enabled;
        c
    };
    let enabled = [
        config.size_functions.enabled,
        config.barycentre.enabled,
        config.tiles.enabled,
    ];
    let parts: Vec<(FeatureConfig, FeatureSet)> = (0..3)
        .filter(|&k| enabled[k])
        .filter_map(|k| {
            let part = alone(k);
            let checked = part.check().ok()?;
            Some((part, checked))
        })
        .collect();
    let names: Vec<String> = parts.iter().flat_map(|(_, s)| s.names()).collect();
    match parts.len() >= 2 && names == set.names() {
        true => parts,
        false => Vec::new(),
    }
}

/// Everything a shared fit depends on, as bytes: the method, its settings and the confidence
/// levels it is calibrated at, the features, the training, validation and calibration data and
/// their times bit for bit, and for a temporal method the training seed (not the rest of the
/// provenance). `None` for methods that do not share fits.
fn fit_key(method: Method, settings: &EstimatorSettings, data: &TrainingSet) -> Option<Vec<u8>> {
    let method_settings = (method.entry().shared_fit?)(settings)?;
    let confidence = &settings.confidence;
    let calibration = data.calibration.as_ref().or(data.validation.as_ref());
    let calibration_frames = calibration.map_or(0, |c| c.rows.len());
    let header = serde_json::json!({
        "method": method,
        "settings": method_settings,
        // The shared fit is calibrated (on the calibration or validation motion) at these levels;
        // the render check is the harness's, after the fit, and its settings reach the fit only
        // through the detection score's share.
        "confidence": ConfidenceSettings {
            abstain_share: confidence.detection_share(calibration_frames),
            render_check: None,
            render_from: RenderSource::Samples,
            render_share: ConfidenceSettings::default().render_share,
            ..confidence.clone()
        },
        "features": data.feature_names,
        "config": data.feature_config,
        "missing_penalty": data.missing_penalty.to_bits(),
        // A temporal method's fit draws from the training seed (the particle filter's) and
        // learns on the frames' times.
        "seed": method.entry().over_time.then_some(data.provenance.seed),
    });
    let mut key = serde_json::to_vec(&header).ok()?;
    append_labelled(&mut key, &data.sample);
    if let Some(validation) = &data.validation {
        key.push(b'V');
        append_labelled(&mut key, validation);
    }
    if let Some(calibration) = &data.calibration {
        key.push(b'C');
        append_labelled(&mut key, calibration);
    }
    for (tag, times) in [
        (b'v', data.validation_times),
        (b'c', data.calibration_times),
    ] {
        if let Some(times) = times {
            key.push(tag);
            key.extend((times.len() as u64).to_le_bytes());
            times
                .iter()
                .for_each(|t| key.extend(t.to_bits().to_le_bytes()));
        }
    }
    Some(key)
}

/// Appends the poses and feature rows bit for bit (missing values tagged apart from numbers).
fn append_labelled(key: &mut Vec<u8>, set: &Labelled) {
    key.extend((set.poses.len() as u64).to_le_bytes());
    for pose in set.poses {
        key.extend(pose[0].to_bits().to_le_bytes());
        key.extend(pose[1].to_bits().to_le_bytes());
    }
    for row in set.rows {
        key.push(b'|');
        for value in row {
            match value {
                Some(v) => {
                    key.push(1);
                    key.extend(v.to_bits().to_le_bytes());
                }
                None => key.push(0),
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_shared_fit_is_keyed_by_its_confidence_levels() {
        let names = vec!["f".to_string()];
        let poses = [[0.0, 0.0], [1.0, 1.0]];
        let rows = vec![vec![Some(0.0)], vec![Some(1.0)]];
        let data = TrainingSet::new(
            &names,
            Labelled {
                poses: &poses,
                rows: &rows,
            },
        );
        let settings = EstimatorSettings::default();
        let mut other = settings.clone();
        other.confidence.coverage = 0.8;
        let key = |s: &EstimatorSettings| fit_key(Method::GP, s, &data).expect("the GP shares");
        assert_eq!(key(&settings), key(&settings.clone()));
        assert_ne!(key(&settings), key(&other));
        assert!(fit_key(Method::KNN, &settings, &data).is_none());
    }

    #[test]
    fn a_shared_fit_sees_the_render_check_only_through_the_detection_share() {
        let names = vec!["f".to_string()];
        let poses: Vec<[f64; 2]> = (0..200).map(|i| [f64::from(i), 0.0]).collect();
        let rows: Vec<Vec<Option<f64>>> = (0..200).map(|i| vec![Some(f64::from(i))]).collect();
        let labelled = || Labelled {
            poses: &poses,
            rows: &rows,
        };
        let mut data = TrainingSet::new(&names, labelled());
        data.calibration = Some(labelled());
        let key = |change: &dyn Fn(&mut ConfidenceSettings)| {
            let mut settings = EstimatorSettings::default();
            change(&mut settings.confidence);
            fit_key(Method::GP, &settings, &data).expect("the GP shares")
        };
        // On by default on 200 calibration frames, so the score keeps 0.005 of the 0.01.
        let default = key(&|_| {});
        assert_eq!(default, key(&|c| c.render_check = Some(true)));
        assert_eq!(default, key(&|c| c.render_from = RenderSource::Simulator));
        assert_ne!(default, key(&|c| c.render_check = Some(false)));
        let halved = |c: &mut ConfidenceSettings| {
            c.render_check = Some(false);
            c.abstain_share = 0.005;
        };
        assert_eq!(default, key(&halved));
    }

    #[test]
    fn the_render_checks_silhouettes_are_learned_once_per_key() {
        let bench = Workbench::new();
        let calls = std::cell::Cell::new(0);
        let learn = || {
            calls.set(calls.get() + 1);
            None
        };
        assert!(bench.render_check("a".into(), learn).is_none());
        assert!(bench.render_check("a".into(), learn).is_none());
        assert_eq!(
            calls.get(),
            1,
            "the same key: learned once, too few silhouettes kept"
        );
        assert!(bench.render_check("b".into(), learn).is_none());
        assert_eq!(calls.get(), 2);
    }

    #[test]
    fn rows_joined_from_the_extractors_are_the_rows_of_the_whole_set() {
        let bench = Workbench::new();
        let sim = SimSettings::default();
        let w = sim.geometry.workspace;
        let points = vec![
            [w.x_min + 2.0, w.y_min + 3.0],
            [w.x_max - 4.0, w.y_max - 1.0],
        ];
        let motion = Motion::Points { points };
        let config = FeatureConfig::with_barycentre();
        let set = config.check().expect("a valid configuration");
        let rows = bench
            .features(&sim, &motion, 7, &config, &set, &mut |_, _, _| {})
            .expect("features");
        let data = bench
            .dataset(&sim, &motion, 7, &mut |_, _| {})
            .expect("simulated");
        let whole: FeatureRows = data.images().map(|image| set.extract(image)).collect();
        assert_eq!(*rows, whole);
        assert!(rows
            .iter()
            .all(|r| r.len() == 8 && r.iter().all(Option::is_some)));
        // The whole set and its two parts are kept: the size functions alone are the default
        // configuration's rows, which another variant then takes as they are.
        assert_eq!(bench.features.lock().map(|m| m.len()).unwrap_or(0), 3);
        let sizes = FeatureConfig::default();
        let alone = bench
            .features(
                &sim,
                &motion,
                7,
                &sizes,
                &sizes.check().expect("valid"),
                &mut |_, _, _| {},
            )
            .expect("features");
        assert_eq!(bench.features.lock().map(|m| m.len()).unwrap_or(0), 3);
        assert!((alone.iter().zip(rows.iter())).all(|(a, r)| a[..] == r[..6]));
        assert!(extractor_parts(&sizes, &sizes.check().expect("valid")).is_empty());
    }
}
