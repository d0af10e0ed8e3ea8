//! Scenario files: TOML in, validated settings out.
//!
//! A scenario names everything a run needs — robot and camera, sample trajectory, validation and
//! test motions, features, model, tracker, seed — and what it is expected to achieve. A `[sweep]`
//! section turns one file into several *variants*: each variant is the base scenario with some
//! values replaced, addressed by dotted paths (`"model.states" = [2, 3, 3, 3, 3, 2]`). Variants are
//! listed (`[[sweep.variant]]`) or spanned by a grid (`[sweep.grid]`, the cartesian product of the
//! listed values). Every variant is deserialised and checked before anything runs.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::adaptive::AdaptiveSettings;
use crate::estimator::{
    ConfidenceSettings, ContinuousSettings, EstimatorSettings, EvidentialSettings, GpSettings,
    KnnSettings, Method, ParticleSettings, SettingsContext, TemporalSettings,
};
use crate::faults::{FaultPlan, FaultSpec};
use crate::features::{FeatureConfig, FeatureSet};
use crate::model::{ModelSettings, StateCounts, Tuning};
use crate::seed;
use crate::sim::{Motion, SimSettings};
use crate::track::{ThresholdRule, TrackSettings};

/// Failures while reading or checking a scenario.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ScenarioError {
    /// The file could not be read.
    #[error("cannot read scenario {path}: {source}")]
    Read {
        /// The file.
        path: String,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The TOML is malformed or has unknown or mistyped fields (the message has line and column).
    #[error("scenario {path} is not valid:\n{message}")]
    Parse {
        /// The file.
        path: String,
        /// The parser's message, with line, column and a snippet.
        message: String,
    },
    /// A sweep variant's replacements do not make a valid scenario.
    #[error("sweep variant `{variant}` of {path} is not valid: {message}")]
    Variant {
        /// The file.
        path: String,
        /// The variant's name.
        variant: String,
        /// What is wrong.
        message: String,
    },
    /// A value is out of range or inconsistent.
    #[error("scenario `{scenario}`: {message}")]
    Invalid {
        /// The scenario (or variant) name.
        scenario: String,
        /// What is wrong and how to fix it.
        message: String,
    },
}

/// How the sample trajectory is obtained.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SampleSettings {
    /// The motion the robot follows while the sample frames are taken.
    pub motion: Motion,
    /// Keep every k-th sample of that trajectory (1 keeps all): the paper's sparser trajectory
    /// "obtained by sampling" the dense one.
    pub keep_every: usize,
    /// Refine the trajectory where features change fast (§3.1); off when absent.
    pub adaptive: Option<AdaptiveSettings>,
}

impl Default for SampleSettings {
    fn default() -> Self {
        Self {
            motion: Motion::Mesh { spacing: 1.0 },
            keep_every: 1,
            adaptive: None,
        }
    }
}

/// One runnable scenario (a file's base, or one of its sweep variants).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Scenario {
    /// Name used for output folders and tables (default: the file's name without `.toml`).
    pub name: String,
    /// Free text.
    pub description: String,
    /// Master seed: every random draw of the run derives from it.
    pub seed: u64,
    /// Robot geometry, camera and noise.
    pub sim: SimSettings,
    /// The sample trajectory.
    pub sample: SampleSettings,
    /// Validation motion: ranks the features for the fallback, learns the conflict threshold
    /// and tunes state counts. Default: a seeded random path, 10 s at 10 frames/s.
    pub validation: Option<Motion>,
    /// Calibration motion: every method's regions and abstentions are calibrated on it
    /// (split-conformal, so it should be a held-out motion of the tests' kind). Default: none,
    /// the validation motion calibrates them.
    pub calibration: Option<Motion>,
    /// Test motions: the reported errors are measured on them.
    pub tests: Vec<Motion>,
    /// Faults injected into every test motion (`[[faults]]`, applied in order; each test motion
    /// draws them from its own seed stream). The sample and validation motions stay clean.
    pub faults: Vec<FaultSpec>,
    /// Which features, with which parameters.
    pub features: FeatureConfig,
    /// HMM state counts and training settings.
    pub model: ModelSettings,
    /// Constructor, selection policy, conflict threshold, estimator.
    pub track: TrackSettings,
    /// Learn the conflict threshold on the validation motion (§4.3) instead of using
    /// `track.conflict_threshold`.
    pub learn_threshold: bool,
    /// How it is learned: `"error_weighted"` (the paper's, the default) or `{ quantile = q }`.
    pub threshold_rule: ThresholdRule,
    /// The estimation methods to fit and compare, in table order (default: every method).
    pub estimators: Vec<Method>,
    /// k-nearest neighbours' settings (`[knn]`).
    pub knn: KnnSettings,
    /// The Gaussian process's settings (`[gp]`).
    pub gp: GpSettings,
    /// The continuous evidential tracker's settings (`[continuous]`; the particle filter's
    /// feature maps are fitted with them too).
    pub continuous: ContinuousSettings,
    /// The temporal methods' motion model and the carried belief's reliability (`[temporal]`).
    pub temporal: TemporalSettings,
    /// The particle filter's settings (`[particle_filter]`).
    pub particle_filter: ParticleSettings,
    /// The levels every method's calibrated regions and abstentions are held to
    /// (`[confidence]`).
    pub confidence: ConfidenceSettings,
    /// The settings of methods registered at run time, by method name (`[methods.NAME]`).
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub methods: BTreeMap<String, toml::Table>,
    /// Regression expectations.
    pub expect: Expectations,
    /// The paper's figure for this setup, printed beside ours.
    pub paper_error: Option<f64>,
    /// Variants of this scenario (empty in the variants themselves).
    pub sweep: Sweep,
}

impl Default for Scenario {
    /// The settings of the paper's dense Bayesian setup, Figure 2(a), without a name: what a
    /// scenario file gets for every value it leaves out.
    fn default() -> Self {
        Self {
            name: String::new(),
            description: String::new(),
            seed: 1,
            sim: SimSettings::default(),
            sample: SampleSettings::default(),
            validation: Some(default_validation_motion()),
            calibration: None,
            tests: vec![default_test_motion()],
            faults: Vec::new(),
            features: FeatureConfig::default(),
            model: ModelSettings {
                states: StateCounts::PerFeature(vec![2, 2, 2, 3, 3, 2]),
                ..ModelSettings::default()
            },
            track: TrackSettings::default(),
            learn_threshold: false,
            threshold_rule: ThresholdRule::default(),
            estimators: Method::defaults(),
            knn: KnnSettings::default(),
            gp: GpSettings::default(),
            continuous: ContinuousSettings::default(),
            temporal: TemporalSettings::default(),
            particle_filter: ParticleSettings::default(),
            confidence: ConfidenceSettings::default(),
            methods: BTreeMap::new(),
            expect: Expectations::default(),
            paper_error: None,
            sweep: Sweep::default(),
        }
    }
}

/// The default validation motion: a smooth random path, 10 s at 10 frames/s, its seed derived
/// from the scenario's master seed.
pub fn default_validation_motion() -> Motion {
    Motion::RandomPath {
        seed: None,
        speed: 8.0,
        duration: 10.0,
        fps: 10.0,
        components: 4,
    }
}

/// The default test motion: a Lissajous figure over the workspace, 10 s at 20 frames/s.
pub fn default_test_motion() -> Motion {
    Motion::Lissajous {
        freq_x: 0.3,
        freq_y: 0.2,
        phase: std::f64::consts::FRAC_PI_2,
        amplitude: 0.9,
        duration: 10.0,
        fps: 20.0,
    }
}

impl Scenario {
    /// This scenario with the values at dotted paths replaced (`"knn.k"`, `"model.states"`), as a
    /// sweep variant replaces them; unknown or mistyped fields are errors. Not checked.
    ///
    /// # Errors
    /// [`ScenarioError::Invalid`] naming the path or the field that does not fit.
    pub fn with_values(&self, values: &[(String, toml::Value)]) -> Result<Scenario, ScenarioError> {
        let invalid = |message: String| ScenarioError::Invalid {
            scenario: self.name.clone(),
            message,
        };
        let mut value = toml::Value::try_from(self)
            .map_err(|e| invalid(format!("the settings do not serialise as TOML: {e}")))?;
        for (path, replacement) in values {
            sweep::set_path(&mut value, path, replacement.clone()).map_err(invalid)?;
        }
        value
            .try_into()
            .map_err(|e: toml::de::Error| invalid(e.to_string()))
    }

    /// Checks the settings of the scenario's `estimators` (and the `[model]` and `[track]`
    /// sections every scenario holds) against its features, through each method's registry
    /// entry; returns them. `train` builds its settings through the same check.
    ///
    /// # Errors
    /// [`ScenarioError::Invalid`] saying which section and what to change.
    pub fn check_estimators(
        &self,
        context: &SettingsContext,
    ) -> Result<EstimatorSettings, ScenarioError> {
        let invalid = |message: String| ScenarioError::Invalid {
            scenario: self.name.clone(),
            message,
        };
        self.model
            .check()
            .map_err(|e| invalid(format!("[model]: {e}")))?;
        let settings = self.estimator_settings();
        for method in &self.estimators {
            method.check(&settings, context).map_err(invalid)?;
        }
        if let Some(name) = self
            .methods
            .keys()
            .find(|name| !self.estimators.iter().any(|m| m.name() == *name))
        {
            return Err(invalid(format!(
                "[methods.{name}]: settings for `{name}`, which `estimators` does not list: \
                 add it there or remove the section"
            )));
        }
        self.track
            .clone()
            .check()
            .map_err(|e| invalid(format!("[track]: {e}")))?;
        self.track
            .clone()
            .check()
            .map_err(|e| invalid(format!("[track]: {e}")))?;
        self.threshold_rule
            .check()
            .map_err(|e| invalid(format!("`threshold_rule`: {e}")))?;
        Ok(settings)
    }

    /// Every method's settings as this scenario gives them (the evidential model's seed as
    /// written: a run derives its training stream from it and the master seed).
    pub fn estimator_settings(&self) -> EstimatorSettings {
        EstimatorSettings {
            evidential: EvidentialSettings {
                model: self.model.clone(),
                track: self.track.clone(),
                learn_threshold: self.learn_threshold,
                threshold_rule: self.threshold_rule,
            },
            knn: self.knn.clone(),
            gp: self.gp.clone(),
            continuous: self.continuous.clone(),
            temporal: self.temporal.clone(),
            particle_filter: self.particle_filter.clone(),
            confidence: self.confidence.clone(),
            registered: self.methods.clone(),
        }
    }

    /// Checks everything before anything runs: every section's own `check()`, the state counts,
    /// the feature count and the selection sizes against the number of features, and the values
    /// deserialisation cannot check. Random paths without a seed get one derived from the master
    /// seed. Only a [`CheckedScenario`] can be run.
    pub fn check(&self) -> Result<CheckedScenario, ScenarioError> {
        let invalid = |message: String| ScenarioError::Invalid {
            scenario: self.name.clone(),
            message,
        };
        if self.name.trim().is_empty() {
            return Err(invalid("`name` is empty: give the scenario a name".into()));
        }
        if self.name.starts_with('.')
            || self
                .name
                .chars()
                .any(|c| !(c.is_ascii_alphanumeric() || "-_.=,".contains(c)))
        {
            return Err(invalid(format!(
                "name `{}` may only hold letters, digits and - _ . = , and may not start with `.` \
                 (it names an output folder)",
                self.name
            )));
        }
        if self.seed > MAX_SEED {
            return Err(invalid(seed_too_large(self.seed)));
        }
        let rig = self
            .sim
            .check()
            .map_err(|e| invalid(format!("[sim]: {e}")))?;
        let features = self
            .features
            .check()
            .map_err(|e| invalid(format!("[features]: {e}")))?;
        self.confidence
            .check()
            .map_err(|e| invalid(format!("[confidence]: {e}")))?;
        if self.confidence.render_check_required()
            && self.validation.is_none()
            && self.calibration.is_none()
        {
            return Err(invalid(
                "`confidence.render_check` learns each method's limit on the calibration motion: \
                 add a [calibration] or [validation] motion, or leave it out"
                    .into(),
            ));
        }
        self.check_estimators(&SettingsContext {
            feature_names: features.names(),
            has_validation: self.validation.is_some(),
        })?;
        if let Some(adaptive) = &self.sample.adaptive {
            adaptive
                .check()
                .map_err(|e| invalid(format!("[sample.adaptive]: {e}")))?;
        }
        if self.sample.keep_every == 0 {
            return Err(invalid("`sample.keep_every` must be at least 1".into()));
        }
        if self.tests.is_empty() {
            return Err(invalid(
                "no test motion: add at least one [[tests]] table".into(),
            ));
        }
        if self.learn_threshold && self.validation.is_none() {
            return Err(invalid(
                "`learn_threshold = true` needs a [validation] motion to learn it on".into(),
            ));
        }
        if matches!(self.model.tuning, Tuning::Validation { .. }) && self.validation.is_none() {
            return Err(invalid(
                "tuning state counts by validation error needs a [validation] motion".into(),
            ));
        }
        let positive = |value: Option<f64>, field: &str| match value {
            Some(v) if !(v.is_finite() && v > 0.0) => Err(invalid(format!(
                "`{field}` must be a positive number of mm, not {v}"
            ))),
            _ => Ok(()),
        };
        positive(self.paper_error, "paper_error")?;
        if self.estimators.is_empty() {
            return Err(invalid(
                "`estimators` is empty: name at least one method, e.g. [\"evidential\"]".into(),
            ));
        }
        if let Some(m) = self
            .estimators
            .iter()
            .enumerate()
            .find_map(|(i, m)| self.estimators[..i].contains(m).then_some(m))
        {
            return Err(invalid(format!("`estimators` names `{m}` twice")));
        }
        let top = self.expect.evidential();
        let named = self.expect.methods.iter().map(|(n, e)| (n.as_str(), e));
        for (name, limits) in std::iter::once(("evidential", &top)).chain(named) {
            let prefix = if name == "evidential" {
                "expect".to_string()
            } else {
                format!("expect.methods.{name}")
            };
            if (limits.any() || name != "evidential")
                && !self.estimators.iter().any(|m| m.name() == name)
            {
                {
                    return Err(invalid(format!(
                        "`{prefix}`: the scenario's estimators {:?} do not include `{name}`",
                        self.estimators.iter().map(|m| m.name()).collect::<Vec<_>>()
                    )));
                }
            }
            limits.check(&prefix).map_err(invalid)?;
            if limits.needs_faults() && self.faults.is_empty() {
                return Err(invalid(format!(
                    "`{prefix}`: limits on corrupted frames need [[faults]]"
                )));
            }
        }
        let faults = FaultPlan::check(
            &self.faults,
            &features.names(),
            [self.sim.camera.width, self.sim.camera.height],
        )
        .map_err(|e| invalid(format!("[[faults]]: {e}")))?;
        let mut scenario = self.clone();
        scenario.validation = self
            .validation
            .as_ref()
            .map(|m| m.with_default_seed(seed::for_validation_path(self.seed)));
        scenario.calibration = self
            .calibration
            .as_ref()
            .map(|m| m.with_default_seed(seed::derive(self.seed, "calibration-path")));
        scenario.tests = self
            .tests
            .iter()
            .enumerate()
            .map(|(k, m)| m.with_default_seed(seed::derive(self.seed, &format!("test{k}-path"))))
            .collect();
        // Motions are planned now (fps 0, points outside the workspace), not once the run starts.
        let motions = std::iter::once(("[sample] motion".to_string(), &scenario.sample.motion))
            .chain(
                scenario
                    .validation
                    .iter()
                    .map(|m| ("[validation]".to_string(), m)),
            )
            .chain(
                scenario
                    .calibration
                    .iter()
                    .map(|m| ("[calibration]".to_string(), m)),
            )
            .chain((scenario.tests.iter().enumerate()).map(|(k, m)| (format!("[[tests]] {k}"), m)));
        for (what, motion) in motions {
            motion
                .plan(&rig.five_bar)
                .map_err(|e| invalid(format!("{what}: {e}")))?;
        }
        // The sample poses, counted as the memory estimate counts them, against the exact GPs.
        let dense = (scenario.sample.motion.targets(&rig.five_bar))
            .map_err(|e| invalid(format!("[sample] motion: {e}")))?
            .len();
        let kept = dense.div_ceil(scenario.sample.keep_every);
        let samples = (scenario.sample.adaptive.as_ref()).map_or(kept, |a| a.max_samples.max(kept));
        crate::estimator::check_exact_gp_samples(&scenario.estimators, samples).map_err(invalid)?;
        Ok(CheckedScenario {
            raw: self.clone(),
            scenario,
            features,
            faults,
        })
    }
}

/// A scenario that passed [`Scenario::check`], with its random paths' seeds resolved and its
/// feature set built: what [`crate::experiment::run`] takes, so nothing downstream checks again.
#[derive(Debug, Clone)]
pub struct CheckedScenario {
    /// As written, before seeds were derived.
    raw: Scenario,
    scenario: Scenario,
    features: FeatureSet,
    faults: FaultPlan,
}

/// Read access to the checked settings (`checked.seed`, `checked.tests`, …).
impl std::ops::Deref for CheckedScenario {
    type Target = Scenario;
    fn deref(&self) -> &Scenario {
        &self.scenario
    }
}

/// Equal settings (the feature set is built from them).
impl PartialEq for CheckedScenario {
    fn eq(&self, other: &Self) -> bool {
        self.raw == other.raw && self.scenario == other.scenario
    }
}

impl CheckedScenario {
    /// The scenario's settings (random-path seeds resolved).
    pub fn get(&self) -> &Scenario {
        &self.scenario
    }

    /// The scenario (variant) name.
    pub fn name(&self) -> &str {
        &self.scenario.name
    }

    /// The checked feature set.
    pub fn feature_set(&self) -> &FeatureSet {
        &self.features
    }

    /// The checked faults of the test motions.
    pub fn fault_plan(&self) -> &FaultPlan {
        &self.faults
    }

    /// The scenario as TOML, as written (its seed included, its random paths' seeds still to be
    /// derived): `evitrack run` of this text is the same run. Each run folder keeps it as
    /// `scenario.toml`, and a sweep resumes a run only when the text is the same.
    ///
    /// # Errors
    /// [`ScenarioError::Invalid`] if a setting has no TOML form.
    pub fn to_toml(&self) -> Result<String, ScenarioError> {
        toml::to_string(&self.raw).map_err(|e| ScenarioError::Invalid {
            scenario: self.name().to_string(),
            message: format!("the settings do not serialise as TOML: {e}"),
        })
    }

    /// The same scenario with another master seed (checked again: seeds derive from it).
    pub fn with_seed(&self, seed: u64) -> Result<Self, ScenarioError> {
        Scenario {
            seed,
            ..self.raw.clone()
        }
        .check()
    }
}

/// The largest master seed: a run writes its seed into `scenario.toml`, and TOML integers are
/// signed 64-bit.
pub const MAX_SEED: u64 = i64::MAX as u64;

/// Why `seed` cannot be a master seed.
pub(crate) fn seed_too_large(seed: u64) -> String {
    format!(
        "seed {seed} is above {MAX_SEED} (2^63 − 1), the largest a scenario file (TOML) can hold: \
         use a smaller seed"
    )
}

mod annotate;
mod comments;
mod expect;
mod sweep;

pub use annotate::{annotate, comment_for};

pub use expect::{Expectations, MeasuredFigures, MethodExpectations, DEFAULT_TOLERANCE};
pub use sweep::{
    Comparison, FindingSpec, ScenarioSet, SeedList, Side, Sweep, VariantSpec, MAX_RUNS,
    MAX_VARIANTS,
};

#[cfg(test)]
mod tests;
