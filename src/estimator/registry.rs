//! The registry of methods: every method once, with its name, the settings sections it reads,
//! its scenario checks, how to fit it and how to load its model file.
//!
//! The harness, the command line, scenario files and model files find methods here and nowhere
//! else. A new estimator is its own file plus one [`MethodEntry`]: built-in methods are listed in
//! [`BUILT_IN`]; a method defined outside the crate (a plug-in, a test's toy) is added at run time
//! with [`register`] and is then fitted, tracked, written, loaded and checked like the others.

use std::collections::BTreeMap;
use std::path::Path;
use std::sync::RwLock;

use crate::model_file::parse_at;

use serde::{Deserialize, Deserializer, Serialize, Serializer};

use super::{Calibrated, Calibration, ConfidenceSettings};
use super::{
    Centre, CentreSettings, Continuous, ContinuousTemporal, EstimatorError, Evidential, Gp, Knn,
    ParticleFilter, PoseEstimator, TemporalEvidential, TrainingSet,
};
use super::{ContinuousSettings, ParticleSettings, TemporalSettings};
use super::{EvidentialSettings, GpSettings, KnnSettings};

/// Failures of registering a method.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RegistryError {
    /// Another method already has the name.
    #[error("a method named `{0}` is already registered: give the new method another name")]
    Taken(String),
    /// The name cannot be written in scenario and model files.
    #[error("method name `{0}` may only hold lowercase letters, digits and `_`, and not be empty")]
    BadName(String),
}

/// The settings of every method, as a scenario gives them.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct EstimatorSettings {
    /// The evidential tracker's.
    pub evidential: EvidentialSettings,
    /// k-nearest neighbours'.
    pub knn: KnnSettings,
    /// The Gaussian process's.
    pub gp: GpSettings,
    /// The continuous evidential tracker's.
    pub continuous: ContinuousSettings,
    /// The motion model and the carried belief's reliability (temporal methods).
    pub temporal: TemporalSettings,
    /// The particle filter's.
    pub particle_filter: ParticleSettings,
    /// The levels every method's calibrated regions and abstentions are held to.
    pub confidence: ConfidenceSettings,
    /// The sections of registered methods that are not built in, by method name
    /// (`[methods.NAME]` in a scenario file), for their entries to read.
    pub registered: BTreeMap<String, toml::Table>,
}

impl EstimatorSettings {
    /// The section of a registered (not built-in) method, empty when the scenario gives none.
    pub fn registered_section(&self, method: &str) -> toml::Table {
        self.registered.get(method).cloned().unwrap_or_default()
    }
}

/// What a method's scenario checks see besides the settings.
#[derive(Debug, Clone)]
pub struct SettingsContext {
    /// The features the scenario extracts, in order.
    pub feature_names: Vec<String>,
    /// Whether the scenario has a validation motion.
    pub has_validation: bool,
}

/// Checks a method's settings against a scenario: `Err` is a sentence naming the section
/// (`"[knn]: …"`) and what to change.
pub type CheckFn = fn(&EstimatorSettings, &SettingsContext) -> Result<(), String>;
/// Fits a method on a training set.
pub type FitFn =
    fn(&EstimatorSettings, &TrainingSet) -> Result<Box<dyn PoseEstimator>, EstimatorError>;
/// Reads a method's model file from its text (the path names it in errors).
pub type LoadFn = fn(&Path, &str) -> Result<Box<dyn PoseEstimator>, EstimatorError>;
/// The settings a fit depends on, as text, for methods whose fits runs on identical training
/// data may share.
pub type SharedFitFn = fn(&EstimatorSettings) -> Option<String>;

/// One method: everything the harness, the command line and the files need to know of it.
#[derive(Debug)]
pub struct MethodEntry {
    /// The name scenario and model files use (`"knn"`).
    pub name: &'static str,
    /// One line for help texts.
    pub about: &'static str,
    /// The scenario sections whose settings it reads (`["knn"]`).
    pub sections: &'static [&'static str],
    /// Whether a scenario that lists no `estimators` runs it.
    pub runs_by_default: bool,
    /// Whether it tracks over time (carries the past frames through
    /// [`PoseEstimator::start_motion`]); a per-frame method estimates each frame alone.
    pub over_time: bool,
    /// Whether its fit is expensive (Gaussian processes): such runs start first in a sweep.
    pub heavy_fit: bool,
    /// Its scenario checks.
    pub check: CheckFn,
    /// Its fit.
    pub fit: FitFn,
    /// Its model-file reader.
    pub load: LoadFn,
    /// For methods whose fit may be shared between runs with identical settings and training
    /// data (their fitted estimator implements [`PoseEstimator::with_provenance`]).
    pub shared_fit: Option<SharedFitFn>,
}

fn no_check(_: &EstimatorSettings, _: &SettingsContext) -> Result<(), String> {
    Ok(())
}

/// The built-in methods, in the order tables list them.
pub static BUILT_IN: [MethodEntry; 8] = [
    MethodEntry {
        name: crate::model::METHOD,
        about: "the paper's evidential tracker (HMM frames of discernment, Dempster's rule)",
        sections: &["model", "track"],
        runs_by_default: true,
        over_time: false,
        heavy_fit: false,
        check: super::evidential::check_settings,
        fit: |s, data| Ok(Box::new(Evidential::fit(&s.evidential, data)?)),
        load: |path, text| {
            let model = parse_at(path, text, crate::model::EvidentialModel::from_json)?;
            Ok(Box::new(Evidential::from_model(model)?))
        },
        shared_fit: Some(|s| Some(format!("{:?}", s.evidential))),
    },
    MethodEntry {
        name: TemporalEvidential::METHOD,
        about: "the paper's tracker with the last frame's belief carried on by a motion model",
        sections: &["model", "track", "temporal"],
        runs_by_default: false,
        over_time: true,
        heavy_fit: false,
        check: super::temporal::check_settings,
        fit: |s, data| {
            Ok(Box::new(TemporalEvidential::fit(
                &s.evidential,
                &s.temporal,
                data,
            )?))
        },
        load: |path, text| {
            Ok(Box::new(parse_at(
                path,
                text,
                TemporalEvidential::from_json,
            )?))
        },
        shared_fit: Some(|s| Some(format!("{:?} {:?}", s.evidential, s.temporal))),
    },
    MethodEntry {
        name: Continuous::METHOD,
        about: "the continuous evidential tracker (feature maps as smooth functions of the pose)",
        sections: &["continuous"],
        runs_by_default: true,
        over_time: false,
        heavy_fit: true,
        check: super::continuous::check_settings,
        fit: |s, data| Ok(Box::new(Continuous::fit(&s.continuous, data)?)),
        load: |path, text| Ok(Box::new(parse_at(path, text, Continuous::from_json)?)),
        shared_fit: Some(|s| serde_json::to_string(&s.continuous).ok()),
    },
    MethodEntry {
        name: ContinuousTemporal::METHOD,
        about: "the continuous evidential tracker with the last frame's belief carried on",
        sections: &["continuous", "temporal"],
        runs_by_default: false,
        over_time: true,
        heavy_fit: false,
        check: super::continuous::check_temporal_settings,
        fit: |s, data| {
            Ok(Box::new(ContinuousTemporal::fit(
                &s.continuous,
                &s.temporal,
                data,
            )?))
        },
        load: |path, text| {
            Ok(Box::new(parse_at(
                path,
                text,
                ContinuousTemporal::from_json,
            )?))
        },
        shared_fit: Some(|s| serde_json::to_string(&(&s.continuous, &s.temporal)).ok()),
    },
    MethodEntry {
        name: Knn::METHOD,
        about: "k-nearest neighbours on standardised features",
        sections: &["knn"],
        runs_by_default: true,
        over_time: false,
        heavy_fit: false,
        check: super::knn::check_settings,
        fit: |s, data| Ok(Box::new(Knn::fit(&s.knn, data)?)),
        load: |path, text| Ok(Box::new(parse_at(path, text, Knn::from_json)?)),
        shared_fit: None,
    },
    MethodEntry {
        name: Gp::METHOD,
        about: "Gaussian-process regression (ARD kernel, marginal-likelihood hyperparameters)",
        sections: &["gp"],
        runs_by_default: true,
        over_time: false,
        heavy_fit: true,
        check: super::gp::check_settings,
        fit: |s, data| Ok(Box::new(Gp::fit(&s.gp, data)?)),
        load: |path, text| Ok(Box::new(parse_at(path, text, Gp::from_json)?)),
        shared_fit: Some(|s| serde_json::to_string(&s.gp).ok()),
    },
    MethodEntry {
        name: ParticleFilter::METHOD,
        about: "a particle filter on the continuous tracker's feature maps",
        sections: &["particle_filter", "temporal", "continuous"],
        runs_by_default: false,
        over_time: true,
        heavy_fit: false,
        check: super::particle::check_settings,
        fit: |s, data| {
            Ok(Box::new(ParticleFilter::fit(
                &s.particle_filter,
                &s.temporal,
                &s.continuous,
                data,
            )?))
        },
        load: |path, text| Ok(Box::new(parse_at(path, text, ParticleFilter::from_json)?)),
        shared_fit: Some(|s| {
            serde_json::to_string(&(&s.particle_filter, &s.temporal, &s.continuous)).ok()
        }),
    },
    MethodEntry {
        name: Centre::METHOD,
        about: "the workspace centre, whatever the frame: the error of knowing nothing",
        sections: &[],
        runs_by_default: true,
        over_time: false,
        heavy_fit: false,
        check: no_check,
        fit: |_, data| Ok(Box::new(Centre::fit(&CentreSettings::default(), data)?)),
        load: |path, text| Ok(Box::new(parse_at(path, text, Centre::from_json)?)),
        shared_fit: None,
    },
];

/// Methods registered at run time, after the built-in ones.
static REGISTERED: RwLock<Vec<&'static MethodEntry>> = RwLock::new(Vec::new());

/// Adds a method to the registry: from then on scenario files may list it, [`super::load`]
/// reads its model files and [`Method::all`] includes it. Registering the very same entry again
/// is a no-op.
///
/// # Errors
/// [`RegistryError::Taken`] when another method has its name; [`RegistryError::BadName`] for a
/// name scenario files cannot hold.
pub fn register(entry: &'static MethodEntry) -> Result<Method, RegistryError> {
    let name = entry.name;
    if name.is_empty()
        || !name
            .chars()
            .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_')
    {
        return Err(RegistryError::BadName(name.to_string()));
    }
    let mut registered = REGISTERED.write().unwrap_or_else(|e| e.into_inner());
    let same_name = BUILT_IN
        .iter()
        .chain(registered.iter().copied())
        .find(|e| e.name == name);
    match same_name {
        Some(known) if std::ptr::eq(known, entry) => {}
        Some(_) => return Err(RegistryError::Taken(name.to_string())),
        None => registered.push(entry),
    }
    Ok(Method(entry))
}

/// A method of the registry, by its entry. Methods are equal when their names are.
#[derive(Clone, Copy)]
pub struct Method(&'static MethodEntry);

impl Method {
    /// The paper's evidential tracker ([`Evidential`]).
    pub const EVIDENTIAL: Method = Method(&BUILT_IN[0]);
    /// The paper's tracker with the belief of the last frame carried on ([`TemporalEvidential`]).
    pub const EVIDENTIAL_TEMPORAL: Method = Method(&BUILT_IN[1]);
    /// The continuous evidential tracker ([`Continuous`]).
    pub const CONTINUOUS: Method = Method(&BUILT_IN[2]);
    /// The continuous evidential tracker over time ([`ContinuousTemporal`]).
    pub const CONTINUOUS_TEMPORAL: Method = Method(&BUILT_IN[3]);
    /// k-nearest neighbours in standardised feature space ([`Knn`]).
    pub const KNN: Method = Method(&BUILT_IN[4]);
    /// Gaussian-process regression with an ARD kernel ([`Gp`]).
    pub const GP: Method = Method(&BUILT_IN[5]);
    /// A particle filter on the continuous tracker's feature maps ([`ParticleFilter`]).
    pub const PARTICLE_FILTER: Method = Method(&BUILT_IN[6]);
    /// The workspace centre ([`Centre`]).
    pub const CENTRE: Method = Method(&BUILT_IN[7]);

    /// Every method: the built-in ones in table order, then those registered at run time.
    pub fn all() -> Vec<Method> {
        let registered = REGISTERED.read().unwrap_or_else(|e| e.into_inner());
        BUILT_IN
            .iter()
            .chain(registered.iter().copied())
            .map(Method)
            .collect()
    }

    /// The methods a scenario runs unless it lists its own (the built-in per-frame ones).
    pub fn defaults() -> Vec<Method> {
        BUILT_IN
            .iter()
            .filter(|e| e.runs_by_default)
            .map(Method)
            .collect()
    }

    /// The method of that name, if registered.
    pub fn from_name(name: &str) -> Option<Method> {
        Method::all().into_iter().find(|m| m.name() == name)
    }

    /// The registered methods' names, for messages (`a`, `b` and `c`).
    pub fn names_sentence() -> String {
        let names: Vec<String> = Method::all()
            .iter()
            .map(|m| format!("`{}`", m.name()))
            .collect();
        match names.split_last() {
            Some((last, rest)) if !rest.is_empty() => format!("{} and {last}", rest.join(", ")),
            _ => names.concat(),
        }
    }

    /// The name scenario and model files use.
    pub fn name(self) -> &'static str {
        self.0.name
    }

    /// Its registry entry.
    pub fn entry(self) -> &'static MethodEntry {
        self.0
    }

    /// Checks its settings against a scenario.
    ///
    /// # Errors
    /// A sentence naming the section and what to change.
    pub fn check(
        self,
        settings: &EstimatorSettings,
        context: &SettingsContext,
    ) -> Result<(), String> {
        (self.0.check)(settings, context)
    }

    /// Fits this method on `data` and, with a validation motion, calibrates its regions and
    /// abstentions there ([`Calibration`]).
    ///
    /// # Errors
    /// The method's fitting errors, or its errors on a validation frame.
    pub fn fit(
        self,
        settings: &EstimatorSettings,
        data: &TrainingSet,
    ) -> Result<Box<dyn PoseEstimator>, EstimatorError> {
        let fitted = (self.0.fit)(settings, data)?;
        Ok(
            match Calibration::learn_with_poses(fitted.as_ref(), data, &settings.confidence)? {
                Some((calibration, poses)) => {
                    Box::new(Calibrated::new(fitted, calibration).with_poses(poses))
                }
                None => fitted,
            },
        )
    }
}

impl PartialEq for Method {
    fn eq(&self, other: &Self) -> bool {
        self.name() == other.name()
    }
}

impl Eq for Method {}

impl std::hash::Hash for Method {
    fn hash<H: std::hash::Hasher>(&self, state: &mut H) {
        self.name().hash(state);
    }
}

impl std::fmt::Debug for Method {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Method({})", self.name())
    }
}

impl std::fmt::Display for Method {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Method {
    type Err = String;
    fn from_str(name: &str) -> Result<Self, String> {
        Method::from_name(name).ok_or_else(|| {
            format!(
                "unknown method `{name}`: this build knows {}",
                Method::names_sentence()
            )
        })
    }
}

impl Serialize for Method {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.serialize_str(self.name())
    }
}

impl<'de> Deserialize<'de> for Method {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        let name = String::deserialize(deserializer)?;
        name.parse().map_err(serde::de::Error::custom)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn built_in_names_are_distinct_and_found() {
        let all = Method::all();
        for (i, m) in all.iter().enumerate() {
            assert_eq!(Method::from_name(m.name()), Some(*m));
            assert!(all[..i].iter().all(|o| o.name() != m.name()));
        }
        assert_eq!(Method::defaults().len(), 5);
        assert!("kalman".parse::<Method>().unwrap_err().contains("`knn`"));
    }

    #[test]
    fn registering_refuses_taken_and_bad_names() {
        static TAKEN: MethodEntry = MethodEntry {
            name: "knn",
            ..copy_of(&BUILT_IN[7])
        };
        static BAD: MethodEntry = MethodEntry {
            name: "Not OK",
            ..copy_of(&BUILT_IN[7])
        };
        assert!(matches!(register(&TAKEN), Err(RegistryError::Taken(_))));
        assert!(matches!(register(&BAD), Err(RegistryError::BadName(_))));
        assert!(
            register(&BUILT_IN[0]).is_ok(),
            "the same entry again is a no-op"
        );
    }

    const fn copy_of(entry: &MethodEntry) -> MethodEntry {
        MethodEntry { ..*entry }
    }
}
