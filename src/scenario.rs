//! Scenario files: TOML in, validated settings out.
//!
//! A scenario names everything a run needs — robot and camera, sample trajectory, validation and
//! test motions, features, model, tracker, seed — and what it is expected to achieve. A `[sweep]`
//! section turns one file into several *variants*: each variant is the base scenario with some
//! values replaced, addressed by dotted paths (`"model.states" = [2, 3, 3, 3, 3, 2]`). Variants are
//! listed (`[[sweep.variant]]`) or spanned by a grid (`[sweep.grid]`, the cartesian product of the
//! listed values). Every variant is deserialised and checked before anything runs.

use std::collections::BTreeMap;
use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::adaptive::AdaptiveSettings;
use crate::estimator::{GpSettings, KnnSettings, Method, MAX_FEATURES_GROUP_ERRORS};
use crate::faults::{FaultPlan, FaultSpec};
use crate::features::{FeatureConfig, FeatureSet};
use crate::model::{ModelSettings, StateCounts, Tuning};
use crate::report::{Comparison, Side};
use crate::seed;
use crate::sim::{Motion, SimSettings};
use crate::track::{SelectionPolicy, ThresholdRule, TrackSettings, MAX_FEATURES};

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

/// What a run is expected to achieve; `sweep --check` fails when a variant misses it. The
/// top-level limits are the evidential tracker's; `[expect.methods.knn]` and so on give other
/// methods their own.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Expectations {
    /// Largest acceptable mean estimation error over all test frames, in mm.
    pub max_mean_error: Option<f64>,
    /// Largest acceptable share of test frames without an estimate (0 to 1).
    pub max_missing_share: Option<f64>,
    /// Largest acceptable mean error over the frames faults corrupted, in mm.
    pub max_corrupted_mean_error: Option<f64>,
    /// Smallest acceptable area under the ROC curve of the detection score (faults only).
    pub min_detection_auc: Option<f64>,
    /// Limits of other methods, by method name.
    pub methods: BTreeMap<String, MethodExpectations>,
}

impl Expectations {
    /// The top-level limits: the evidential tracker's.
    pub fn evidential(&self) -> MethodExpectations {
        MethodExpectations {
            max_mean_error: self.max_mean_error,
            max_missing_share: self.max_missing_share,
            max_corrupted_mean_error: self.max_corrupted_mean_error,
            min_detection_auc: self.min_detection_auc,
        }
    }
}

/// What one method is expected to achieve.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MethodExpectations {
    /// Largest acceptable mean estimation error over all test frames, in mm.
    pub max_mean_error: Option<f64>,
    /// Largest acceptable share of test frames without an estimate (0 to 1).
    pub max_missing_share: Option<f64>,
    /// Largest acceptable mean error over the frames faults corrupted, in mm.
    pub max_corrupted_mean_error: Option<f64>,
    /// Smallest acceptable area under the ROC curve of the detection score (faults only).
    pub min_detection_auc: Option<f64>,
}

impl MethodExpectations {
    /// Whether any limit is set.
    pub fn any(&self) -> bool {
        self.max_mean_error.is_some()
            || self.max_missing_share.is_some()
            || self.max_corrupted_mean_error.is_some()
            || self.min_detection_auc.is_some()
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
            estimators: Method::ALL.to_vec(),
            knn: KnnSettings::default(),
            gp: GpSettings::default(),
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
        self.sim
            .check()
            .map_err(|e| invalid(format!("[sim]: {e}")))?;
        let features = self
            .features
            .check()
            .map_err(|e| invalid(format!("[features]: {e}")))?;
        self.model
            .check()
            .map_err(|e| invalid(format!("[model]: {e}")))?;
        // What only the evidential tracker limits (its groups are bit masks, its states per
        // feature are listed per feature).
        if self.estimators.contains(&Method::Evidential) {
            if features.len() > MAX_FEATURES {
                return Err(invalid(format!(
                    "[features]: {} features, but the tracker takes at most {MAX_FEATURES}: use fewer \
                     size-function lines or drop the barycentre",
                    features.len()
                )));
            }
            let min_size = self.track.selection.min_size();
            if min_size > features.len() {
                return Err(invalid(format!(
                    "[track]: selection `min_size = {min_size}` is more than the {} features: no group \
                     could ever be chosen",
                    features.len()
                )));
            }
            self.model.state_ranges(features.len()).map_err(|e| {
                invalid(format!(
                    "[model]: {e} (the features are {})",
                    features.names().join(", ")
                ))
            })?;
        }
        self.track
            .clone()
            .check()
            .map_err(|e| invalid(format!("[track]: {e}")))?;
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
        self.threshold_rule
            .check()
            .map_err(|e| invalid(format!("`threshold_rule`: {e}")))?;
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
            positive(limits.max_mean_error, &format!("{prefix}.max_mean_error"))?;
            positive(
                limits.max_corrupted_mean_error,
                &format!("{prefix}.max_corrupted_mean_error"),
            )?;
            for (value, field) in [
                (limits.max_missing_share, "max_missing_share"),
                (limits.min_detection_auc, "min_detection_auc"),
            ] {
                if let Some(share) = value.filter(|v| !(0.0..=1.0).contains(v)) {
                    return Err(invalid(format!(
                        "`{prefix}.{field}` must lie in [0, 1], not {share}"
                    )));
                }
            }
            if (limits.max_corrupted_mean_error.is_some() || limits.min_detection_auc.is_some())
                && self.faults.is_empty()
            {
                return Err(invalid(format!(
                    "`{prefix}`: limits on corrupted frames need [[faults]]"
                )));
            }
        }
        if let SelectionPolicy::Splitting { .. } = self.track.selection {
            if self.estimators.contains(&Method::Evidential)
                && self.validation.is_some()
                && features.len() > MAX_FEATURES_GROUP_ERRORS
            {
                return Err(invalid(format!(
                    "[track]: the splitting policy learns a reliability for every group of \
                     features, which takes at most {MAX_FEATURES_GROUP_ERRORS} features (there are {}): \
                     use fewer features or another selection policy",
                    features.len()
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
        scenario.tests = self
            .tests
            .iter()
            .enumerate()
            .map(|(k, m)| m.with_default_seed(seed::derive(self.seed, &format!("test{k}-path"))))
            .collect();
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

    /// The same scenario with another master seed (checked again: seeds derive from it).
    pub fn with_seed(&self, seed: u64) -> Result<Self, ScenarioError> {
        Scenario {
            seed,
            ..self.raw.clone()
        }
        .check()
    }
}

/// The `[sweep]` section: variants of the base scenario.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Sweep {
    /// Listed variants (`[[sweep.variant]]`).
    pub variant: Vec<VariantSpec>,
    /// Dotted path → values; the variants are their cartesian product (`[sweep.grid]`).
    pub grid: BTreeMap<String, Vec<toml::Value>>,
    /// Master seeds every variant runs with (`seeds = 10`: its own seed and the next 9; or a
    /// list); default: the variant's own seed only.
    pub seeds: Option<SeedList>,
    /// Comparisons between variants, measured as paired differences across the seeds
    /// (`[[sweep.finding]]`).
    pub finding: Vec<FindingSpec>,
}

/// Master seeds: a count (from each variant's own seed on) or a list.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum SeedList {
    /// This many consecutive seeds, from the variant's own.
    Count(u64),
    /// These seeds.
    List(Vec<u64>),
}

impl SeedList {
    /// Reads `10` or `1,4,7` (the command line's form).
    ///
    /// # Errors
    /// What is wrong, as a sentence.
    pub fn parse(text: &str) -> Result<Self, String> {
        let list = if text.contains(',') {
            let seeds: Result<Vec<u64>, _> = text.split(',').map(|s| s.trim().parse()).collect();
            SeedList::List(seeds.map_err(|e| format!("`{text}`: {e}"))?)
        } else {
            SeedList::Count(text.trim().parse().map_err(|e| format!("`{text}`: {e}"))?)
        };
        list.check()?;
        Ok(list)
    }

    /// At least one seed, none twice, a count that does not overflow.
    ///
    /// # Errors
    /// What is wrong, as a sentence.
    pub fn check(&self) -> Result<(), String> {
        match self {
            SeedList::Count(0) => Err("seeds: give at least one".into()),
            SeedList::Count(n) if *n > 10_000 => Err(format!("seeds: {n} is more than 10000")),
            SeedList::Count(_) => Ok(()),
            SeedList::List(list) if list.is_empty() => Err("seeds: the list is empty".into()),
            SeedList::List(list) => match list
                .iter()
                .enumerate()
                .find(|(i, s)| list[..*i].contains(s))
            {
                Some((_, s)) => Err(format!("seeds: {s} is listed twice")),
                None => Ok(()),
            },
        }
    }

    /// The seeds of a variant whose own seed is `own`.
    pub fn expand(&self, own: u64) -> Vec<u64> {
        match self {
            SeedList::Count(n) => (0..*n).map(|k| own.wrapping_add(k)).collect(),
            SeedList::List(list) => list.clone(),
        }
    }
}

/// A comparison between two variants (or methods) of a file: `left − right` of the mean errors,
/// paired by seed.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FindingSpec {
    /// How the README states it (`b < a`).
    pub name: String,
    /// Left variant, by the name after the scenario's (`b`).
    pub left: String,
    /// Right variant.
    pub right: String,
    /// Method of the left side (default `evidential`).
    #[serde(default = "evidential_name")]
    pub method: String,
    /// Method of the right side (default: the left's).
    #[serde(default)]
    pub right_method: Option<String>,
}

fn evidential_name() -> String {
    "evidential".into()
}

/// One listed variant: a name and the values it replaces.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VariantSpec {
    /// Appended to the scenario's name.
    pub name: String,
    /// Dotted path → replacement value, e.g. `"model.states" = [2, 3, 3, 3, 3, 2]`.
    #[serde(default)]
    pub set: BTreeMap<String, toml::Value>,
}

/// A scenario file: the base scenario and the variants its sweep section spans.
#[derive(Debug, Clone)]
pub struct ScenarioSet {
    /// Where it came from (a path, or `built-in`).
    pub source: String,
    /// The base scenario.
    pub base: CheckedScenario,
    /// The variants, in file order (listed first, then the grid); a file without a sweep section
    /// has one variant, the base itself.
    pub variants: Vec<CheckedScenario>,
    /// The seeds `[sweep] seeds` asks for (`None`: each variant's own).
    pub seeds: Option<SeedList>,
    /// The comparisons of `[[sweep.finding]]`, with full variant names.
    pub comparisons: Vec<Comparison>,
}

impl ScenarioSet {
    /// The built-in default: the paper's dense Bayesian setup, run once.
    ///
    /// # Errors
    /// None expected: the default settings pass their check (a unit test guards it).
    pub fn builtin_default() -> Result<Self, ScenarioError> {
        let base = Scenario {
            name: "default".into(),
            description: "The paper's dense Bayesian setup (Figure 2a): 1 mm mesh, 6 size \
                          functions, n = 2,2,2,3,3,2"
                .into(),
            paper_error: Some(2.3585),
            ..Scenario::default()
        }
        .check()?;
        Ok(Self {
            source: "built-in".into(),
            variants: vec![base.clone()],
            base,
            seeds: None,
            comparisons: Vec::new(),
        })
    }

    /// Every variant once per seed (`seeds` replaces the file's `[sweep] seeds`), variant by
    /// variant, seeds in the order given.
    ///
    /// # Errors
    /// A variant that does not check with one of the seeds.
    pub fn seeded(&self, seeds: Option<&SeedList>) -> Result<Vec<CheckedScenario>, ScenarioError> {
        let Some(list) = seeds.or(self.seeds.as_ref()) else {
            return Ok(self.variants.clone());
        };
        let mut runs = Vec::new();
        for variant in &self.variants {
            for seed in list.expand(variant.seed) {
                runs.push(variant.with_seed(seed)?);
            }
        }
        Ok(runs)
    }

    /// Reads and checks a scenario file.
    pub fn load(path: &Path) -> Result<Self, ScenarioError> {
        let text = std::fs::read_to_string(path).map_err(|source| ScenarioError::Read {
            path: path.display().to_string(),
            source,
        })?;
        Self::parse(&text, &path.display().to_string())
    }

    /// Parses and checks scenario text; `source` names it in errors.
    pub fn parse(text: &str, source: &str) -> Result<Self, ScenarioError> {
        let parse_error = |message: String| ScenarioError::Parse {
            path: source.to_string(),
            message,
        };
        // First pass over the text itself, so unknown fields are reported with line and column.
        let sweep = toml::from_str::<Scenario>(text)
            .map_err(|e| parse_error(e.to_string()))?
            .sweep;
        // Second pass: the file's values laid over setup (a), so that a partial table (say
        // `[model]` with only a seed) keeps the defaults of the fields it leaves out.
        let mut file: toml::Table = toml::from_str(text).map_err(|e| parse_error(e.to_string()))?;
        file.remove("sweep");
        let mut table = match toml::Value::try_from(Scenario::default()) {
            Ok(toml::Value::Table(table)) => table,
            _ => {
                return Err(parse_error(
                    "the default scenario does not serialise".into(),
                ))
            }
        };
        table.remove("sweep");
        overlay(&mut table, file);
        let mut base: Scenario = toml::Value::Table(table.clone())
            .try_into()
            .map_err(|e: toml::de::Error| parse_error(e.to_string()))?;
        if base.name.is_empty() {
            // A file without a name is named after itself.
            base.name = Path::new(source)
                .file_stem()
                .map(|stem| stem.to_string_lossy().into_owned())
                .unwrap_or_default();
        }
        let base = base.check()?;
        if let Some((path, _)) = sweep.grid.iter().find(|(_, values)| values.is_empty()) {
            return Err(ScenarioError::Variant {
                path: source.to_string(),
                variant: format!("grid `{path}`"),
                message: "the list of values is empty: give at least one".into(),
            });
        }
        let mut specs = sweep.variant.clone();
        specs.extend(grid_variants(&sweep.grid));
        let variants = if specs.is_empty() {
            vec![base.clone()]
        } else {
            let mut seen = std::collections::HashSet::new();
            specs
                .iter()
                .map(|spec| {
                    let variant_error = |message: String| ScenarioError::Variant {
                        path: source.to_string(),
                        variant: spec.name.clone(),
                        message,
                    };
                    if !seen.insert(spec.name.clone()) {
                        return Err(variant_error("two variants have this name".into()));
                    }
                    let mut value = toml::Value::Table(table.clone());
                    for (path, replacement) in &spec.set {
                        set_path(&mut value, path, replacement.clone()).map_err(variant_error)?;
                    }
                    let mut scenario: Scenario = value
                        .try_into()
                        .map_err(|e: toml::de::Error| variant_error(e.to_string()))?;
                    scenario.name = format!("{}-{}", base.name(), spec.name);
                    scenario.check()
                })
                .collect::<Result<Vec<_>, _>>()?
        };
        let sweep_error = |message: String| ScenarioError::Variant {
            path: source.to_string(),
            variant: "[sweep]".into(),
            message,
        };
        if let Some(seeds) = &sweep.seeds {
            seeds.check().map_err(sweep_error)?;
        }
        let comparisons = sweep
            .finding
            .iter()
            .map(|f| {
                let side = |short: &str, method: &str| {
                    let full = format!("{}-{short}", base.name());
                    let variant = variants
                        .iter()
                        .find(|v| v.name() == full || v.name() == short)
                        .ok_or_else(|| {
                            sweep_error(format!("finding `{}`: no variant `{short}`", f.name))
                        })?;
                    if !variant.estimators.iter().any(|m| m.name() == method) {
                        return Err(sweep_error(format!(
                            "finding `{}`: variant `{short}` does not run method `{method}`",
                            f.name
                        )));
                    }
                    Ok(Side {
                        scenario: variant.name().to_string(),
                        method: method.to_string(),
                    })
                };
                Ok(Comparison {
                    name: f.name.clone(),
                    left: side(&f.left, &f.method)?,
                    right: side(&f.right, f.right_method.as_deref().unwrap_or(&f.method))?,
                })
            })
            .collect::<Result<Vec<_>, ScenarioError>>()?;
        Ok(Self {
            source: source.to_string(),
            base,
            variants,
            seeds: sweep.seeds.clone(),
            comparisons,
        })
    }
}

/// The cartesian product of a grid, each point a variant named `key=value,...` (the key without
/// its first segment).
fn grid_variants(grid: &BTreeMap<String, Vec<toml::Value>>) -> Vec<VariantSpec> {
    if grid.is_empty() {
        return Vec::new();
    }
    let mut points: Vec<VariantSpec> = vec![VariantSpec {
        name: String::new(),
        set: BTreeMap::new(),
    }];
    for (path, values) in grid {
        // The path without its room (`noise.sigma`, `states`) names the value.
        let short = path.split_once('.').map_or(path.as_str(), |(_, rest)| rest);
        points = points
            .into_iter()
            .flat_map(|point| {
                values.iter().map(move |value| {
                    let mut next = point.clone();
                    let label = format!("{short}={}", compact(value));
                    next.name = if next.name.is_empty() {
                        label
                    } else {
                        format!("{},{label}", next.name)
                    };
                    next.set.insert(path.clone(), value.clone());
                    next
                })
            })
            .collect();
    }
    points
}

/// A value as a short label for variant names (array items and table values joined with `_`).
fn compact(value: &toml::Value) -> String {
    match value {
        toml::Value::String(s) => s.clone(),
        toml::Value::Array(items) => items.iter().map(compact).collect::<Vec<_>>().join("_"),
        toml::Value::Table(table) => table.values().map(compact).collect::<Vec<_>>().join("_"),
        other => other.to_string(),
    }
}

/// Lays `top` over `base`: tables merge key by key, anything else replaces. A table that names
/// its variant (`kind`, `method` or `policy`, as motions, tunings and selection policies do) is
/// a different value, not an amendment, so it replaces too.
fn overlay(base: &mut toml::Table, top: toml::Table) {
    const TAGS: [&str; 3] = ["kind", "method", "policy"];
    for (key, value) in top {
        match (base.get_mut(&key), value) {
            (Some(toml::Value::Table(below)), toml::Value::Table(above))
                if !TAGS.iter().any(|tag| above.contains_key(*tag)) =>
            {
                overlay(below, above)
            }
            (_, value) => {
                base.insert(key, value);
            }
        }
    }
}

/// Replaces the value at a dotted path, creating missing tables along the way.
fn set_path(root: &mut toml::Value, path: &str, value: toml::Value) -> Result<(), String> {
    let keys: Vec<&str> = path.split('.').collect();
    if keys.iter().any(|k| k.is_empty()) {
        return Err(format!("`{path}` is not a dotted path like `model.states`"));
    }
    let mut node = root;
    for (depth, key) in keys.iter().enumerate() {
        let toml::Value::Table(table) = node else {
            return Err(format!(
                "`{}` is not a table, so `{path}` cannot be set",
                keys[..depth].join(".")
            ));
        };
        if depth + 1 == keys.len() {
            table.insert((*key).to_string(), value);
            return Ok(());
        }
        node = table
            .entry((*key).to_string())
            .or_insert_with(|| toml::Value::Table(toml::Table::new()));
    }
    Ok(())
}

#[cfg(test)]
#[path = "scenario_tests.rs"]
mod tests;
