//! A method added from outside the crate, touching only this file and the registry: a toy
//! nearest-sample estimator is registered, run by a scenario beside the built-in methods (its
//! settings from `[methods.toy_nearest]`), written with the run, loaded back by `load`, and put
//! through the whole conformance suite.

use std::path::Path;

use evitrack::estimator::{
    register, EstimatorError, EstimatorSettings, Method, MethodEntry, PoseEstimate, PoseEstimator,
    SettingsContext, TrainingSet,
};
use evitrack::features::FeatureConfig;
use evitrack::model_file::{self, Header, ModelFileError};
use serde::{Deserialize, Serialize};

const NAME: &str = "toy_nearest";

/// The toy's settings, read from its scenario section.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
struct ToySettings {
    /// Features count as far apart as |Δ| / scale.
    scale: f64,
}

impl Default for ToySettings {
    fn default() -> Self {
        Self { scale: 1.0 }
    }
}

impl ToySettings {
    fn of(settings: &EstimatorSettings) -> Result<Self, String> {
        let toy: Self = toml::Value::Table(settings.registered_section(NAME))
            .try_into()
            .map_err(|e| format!("[methods.{NAME}]: {e}"))?;
        if !(toy.scale.is_finite() && toy.scale > 0.0) {
            return Err(format!(
                "[methods.{NAME}]: `scale` must be a positive number, not {}",
                toy.scale
            ));
        }
        Ok(toy)
    }
}

/// The fitted toy: the sample poses and their feature rows (its model file is itself, opened
/// by the shared header).
#[derive(Debug, Clone, Serialize, Deserialize)]
struct Toy {
    #[serde(flatten)]
    header: Header,
    scale: f64,
    poses: Vec<[f64; 2]>,
    rows: Vec<Vec<Option<f64>>>,
}

impl Toy {
    fn fit(settings: &EstimatorSettings, data: &TrainingSet) -> Result<Self, EstimatorError> {
        let toy = ToySettings::of(settings).map_err(EstimatorError::Training)?;
        Ok(Self {
            header: Header {
                format_version: 1,
                method: NAME.into(),
                provenance: data.provenance.clone(),
                feature_config: data.feature_config.cloned(),
                feature_names: data.feature_names.to_vec(),
            },
            scale: toy.scale,
            poses: data.sample.poses.to_vec(),
            rows: data.sample.rows.to_vec(),
        })
    }

    fn from_text(path: &Path, text: &str) -> Result<Self, EstimatorError> {
        let toy = model_file::parse_at(path, text, |text| {
            let toy: Toy = model_file::parse(text, NAME, 1)?;
            toy.header.provenance.check_poses("poses", &toy.poses)?;
            Ok::<_, ModelFileError>(toy)
        })?;
        Ok(toy)
    }
}

impl PoseEstimator for Toy {
    fn method(&self) -> &'static str {
        NAME
    }

    fn feature_names(&self) -> &[String] {
        &self.header.feature_names
    }

    fn feature_config(&self) -> Option<&FeatureConfig> {
        self.header.feature_config.as_ref()
    }

    fn estimate(&self, features: &[Option<f64>]) -> Result<PoseEstimate, EstimatorError> {
        if features.len() != self.header.feature_names.len() {
            return Err(EstimatorError::FeatureCount {
                expected: self.header.feature_names.len(),
                found: features.len(),
            });
        }
        let usable = |v: &Option<f64>| v.filter(|x| x.is_finite());
        let distance = |row: &[Option<f64>]| -> f64 {
            row.iter()
                .zip(features)
                .filter_map(|(a, b)| Some(((*a)? - usable(b)?) / self.scale))
                .map(|d| d * d)
                .sum()
        };
        let any = features.iter().any(|v| usable(v).is_some());
        let nearest = (0..self.poses.len())
            .filter(|_| any)
            .min_by(|&a, &b| distance(&self.rows[a]).total_cmp(&distance(&self.rows[b])));
        Ok(PoseEstimate {
            pose: nearest.map(|k| self.poses[k]),
            uncertainty_radius: None,
            group: None,
            conflict_level: None,
            detection_score: None,
            region: None,
            covariance: None,
            flags: evitrack::estimator::EstimateFlags {
                missing: (0..features.len())
                    .filter(|&i| features[i].is_none())
                    .collect(),
                ..Default::default()
            },
        })
    }

    fn to_json(&self) -> Result<String, EstimatorError> {
        Ok(model_file::to_text(self)?)
    }
}

/// The toy's one registry entry.
static TOY: MethodEntry = MethodEntry {
    name: NAME,
    about: "a toy: the nearest sample in feature space",
    sections: &["methods.toy_nearest"],
    runs_by_default: false,
    over_time: false,
    heavy_fit: false,
    check: |settings: &EstimatorSettings, _: &SettingsContext| {
        ToySettings::of(settings).map(|_| ())
    },
    fit: |settings, data| Ok(Box::new(Toy::fit(settings, data)?)),
    load: |path, text| Ok(Box::new(Toy::from_text(path, text)?)),
    shared_fit: None,
};

fn toy() -> Method {
    register(&TOY).expect("the toy's name is free")
}

#[test]
fn a_registered_toy_method_passes_the_conformance_suite() {
    let method = toy();
    assert_eq!(Method::from_name(NAME), Some(method));
    let data = crate::conformance::Data::new();
    crate::conformance::check_method(method, &crate::conformance::settings(), &data, Method::KNN);
}

#[test]
fn a_registered_toy_method_runs_in_a_scenario_and_its_file_loads() {
    toy();
    let text = r#"
name = "toy"
estimators = ["toy_nearest", "centre"]
[sample]
motion = { kind = "mesh", spacing = 2.0 }
[[tests]]
kind = "circle"
radius = 5.0
speed = 10.0
duration = 1.0
fps = 10.0
[methods.toy_nearest]
scale = 0.5
"#;
    let set = evitrack::scenario::ScenarioSet::parse(text, "toy.toml").unwrap();
    let bench = evitrack::experiment::Workbench::new();
    let output = evitrack::experiment::run(&set.variants[0], &bench, &mut |_, _, _| {}).unwrap();
    let methods: Vec<&str> = output
        .summary
        .methods
        .iter()
        .map(|m| m.method.as_str())
        .collect();
    assert_eq!(methods, [NAME, "centre"]);
    let toy_error = output.summary.methods[0].error.as_ref().unwrap().mean;
    let centre_error = output.summary.methods[1].error.as_ref().unwrap().mean;
    assert!(
        toy_error < 0.5 * centre_error,
        "{toy_error} against {centre_error}"
    );

    let dir = tempfile::tempdir().unwrap();
    let written = evitrack::report::write_run(dir.path(), &output, false).unwrap();
    let file = dir.path().join(format!("model-{NAME}.json"));
    assert!(written.contains(&file));
    let loaded = evitrack::estimator::load(&file).unwrap();
    assert_eq!(
        loaded.to_json().unwrap(),
        output.estimators[0].to_json().unwrap()
    );
    assert!(std::fs::read_to_string(dir.path().join("scenario.toml"))
        .unwrap()
        .contains("[methods.toy_nearest]"));

    // Its checks run with the scenario's.
    let bad = text.replace("scale = 0.5", "scale = -1.0");
    let error = evitrack::scenario::ScenarioSet::parse(&bad, "toy.toml").unwrap_err();
    assert!(
        error
            .to_string()
            .contains("[methods.toy_nearest]: `scale` must be"),
        "{error}"
    );
    let stray = text.replace(
        "estimators = [\"toy_nearest\", \"centre\"]",
        "estimators = [\"centre\"]",
    );
    let error = evitrack::scenario::ScenarioSet::parse(&stray, "toy.toml").unwrap_err();
    assert!(
        error
            .to_string()
            .contains("which `estimators` does not list"),
        "{error}"
    );
}
