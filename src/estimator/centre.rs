//! The workspace-centre baseline (the error of knowing nothing: every frame gets the centre of the
//! sample poses' bounding box), and the checks every baseline shares: training sets, frames and
//! the model-file header.

use std::path::Path;

use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

use super::{EstimateFlags, EstimatorError, PoseEstimate, PoseEstimator, TrainingSet};
use crate::features::FeatureConfig;
use crate::model::{ModelError, Provenance};

/// How the workspace-centre baseline is fitted: there is nothing to choose.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CentreSettings {}

impl CentreSettings {
    /// Always valid.
    ///
    /// # Errors
    /// None; the signature matches the other baselines'.
    pub fn check(&self) -> Result<(), EstimatorError> {
        Ok(())
    }
}

/// The centre of the sample poses' bounding box, given for every frame.
///
/// Features are only checked (count) and flagged (missing); a frame whose features are all
/// missing still gets the centre. Sample rows with missing values are kept: the baseline ignores
/// features, so only the poses count.
#[derive(Debug, Clone)]
pub struct Centre {
    file: CentreFile,
    centre: [f64; 2],
}

/// The model file, and the fitted state.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct CentreFile {
    format_version: u32,
    method: String,
    provenance: Provenance,
    feature_config: Option<FeatureConfig>,
    feature_names: Vec<String>,
    settings: CentreSettings,
    /// Smallest x and y of the sample poses (mm).
    min: [f64; 2],
    /// Largest x and y of the sample poses (mm).
    max: [f64; 2],
}

impl Centre {
    /// Version of the model file format this build writes and reads.
    pub const FORMAT_VERSION: u32 = 1;
    /// The `method` of its model files.
    pub const METHOD: &'static str = "centre";

    /// Fits on the sample poses of `data`.
    ///
    /// # Errors
    /// An inconsistent training set: no feature or a duplicate name, a feature configuration
    /// naming other features, no sample pose, a non-finite pose, or rows that do not have one
    /// value per feature for each pose.
    pub fn fit(settings: &CentreSettings, data: &TrainingSet) -> Result<Self, EstimatorError> {
        settings.check()?;
        check_training(data)?;
        let (mut min, mut max) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        for p in data.sample.poses {
            for k in 0..2 {
                min[k] = min[k].min(p[k]);
                max[k] = max[k].max(p[k]);
            }
        }
        Ok(Self::new(CentreFile {
            format_version: Self::FORMAT_VERSION,
            method: Self::METHOD.to_string(),
            provenance: data.provenance.clone(),
            feature_config: data.feature_config.cloned(),
            feature_names: data.feature_names.to_vec(),
            settings: settings.clone(),
            min,
            max,
        }))
    }

    fn new(file: CentreFile) -> Self {
        let (min, max) = (file.min, file.max);
        let centre = [0.5 * (min[0] + max[0]), 0.5 * (min[1] + max[1])];
        Self { file, centre }
    }

    /// The estimate of every frame (mm).
    pub fn centre(&self) -> [f64; 2] {
        self.centre
    }

    /// The sample poses' bounding box: smallest and largest x and y (mm).
    pub fn bounds(&self) -> ([f64; 2], [f64; 2]) {
        (self.file.min, self.file.max)
    }

    /// The settings it was fitted with.
    pub fn settings(&self) -> &CentreSettings {
        &self.file.settings
    }

    /// Reads a model file's text, checking the header, the features and the bounding box.
    ///
    /// # Errors
    /// [`EstimatorError::Model`] naming what is wrong.
    pub fn from_json(text: &str) -> Result<Self, EstimatorError> {
        let file: CentreFile = parse_file(text, Self::METHOD, Self::FORMAT_VERSION)?;
        check_features(&file.feature_names, file.feature_config.as_ref())
            .map_err(|e| corrupted(e.to_string()))?;
        for (k, axis) in ["x", "y"].iter().enumerate() {
            if !(file.min[k].is_finite() && file.max[k].is_finite()) {
                return Err(corrupted(format!("`min` or `max` {axis} is not finite")));
            }
            if file.min[k] > file.max[k] {
                return Err(corrupted(format!("`min` {axis} is above `max` {axis}")));
            }
        }
        file.provenance
            .check_poses("min, max", &[file.min, file.max])
            .map_err(corrupted)?;
        Ok(Self::new(file))
    }

    /// Reads a model file written from [`PoseEstimator::to_json`].
    ///
    /// # Errors
    /// [`EstimatorError::Io`] when it cannot be read; [`EstimatorError::Model`] naming the path
    /// and what is wrong otherwise.
    pub fn load(path: &Path) -> Result<Self, EstimatorError> {
        load_file(path, Self::from_json)
    }
}

impl PoseEstimator for Centre {
    fn method(&self) -> &'static str {
        Self::METHOD
    }

    fn feature_names(&self) -> &[String] {
        &self.file.feature_names
    }

    fn feature_config(&self) -> Option<&FeatureConfig> {
        self.file.feature_config.as_ref()
    }

    fn estimate(&self, features: &[Option<f64>]) -> Result<PoseEstimate, EstimatorError> {
        let (_, missing) = frame_values(features, self.file.feature_names.len())?;
        Ok(PoseEstimate {
            detection_score: None,
            pose: Some(self.centre),
            uncertainty_radius: None,
            group: None,
            conflict_level: None,
            region: None,
            flags: EstimateFlags {
                missing,
                ..EstimateFlags::default()
            },
        })
    }

    fn to_json(&self) -> Result<String, EstimatorError> {
        write_file(&self.file)
    }
}

// ---- Shared by the baselines ----

/// Checks what every baseline needs of a training set: feature names (at least one, unique,
/// matching the feature configuration when there is one), at least one sample pose, all finite,
/// and one row per pose with one value per feature.
pub(super) fn check_training(data: &TrainingSet) -> Result<(), EstimatorError> {
    check_features(data.feature_names, data.feature_config)?;
    let (poses, rows) = (data.sample.poses, data.sample.rows);
    if poses.is_empty() {
        return Err(ModelError::NoSamples.into());
    }
    if let Some(index) = poses.iter().position(|p| !p.iter().all(|v| v.is_finite())) {
        return Err(ModelError::NonFinitePose {
            index,
            pose: poses[index],
        }
        .into());
    }
    if rows.len() != poses.len() {
        return Err(ModelError::RowCount {
            rows: rows.len(),
            poses: poses.len(),
        }
        .into());
    }
    let expected = data.feature_names.len();
    if let Some(row) = rows.iter().position(|r| r.len() != expected) {
        return Err(ModelError::RowLength {
            row,
            expected,
            got: rows[row].len(),
        }
        .into());
    }
    Ok(())
}

/// Feature names are at least one and unique, and the configuration (if any) names exactly them.
pub(super) fn check_features(
    names: &[String],
    config: Option<&FeatureConfig>,
) -> Result<(), EstimatorError> {
    if names.is_empty() {
        return Err(ModelError::NoFeatures.into());
    }
    let mut sorted: Vec<&String> = names.iter().collect();
    sorted.sort();
    if let Some(w) = sorted.windows(2).find(|w| w[0] == w[1]) {
        return Err(ModelError::DuplicateFeature(w[0].clone()).into());
    }
    if let Some(config) = config {
        let configured = config.check()?.names();
        if configured != names {
            return Err(ModelError::InvalidInput {
                what: "feature configuration",
                reason: format!(
                    "it names the features {configured:?}, but the model has {names:?}"
                ),
            }
            .into());
        }
    }
    Ok(())
}

/// Indices of the samples whose every feature value is present and finite (the rows a method
/// that needs every feature can use). Errors when there is none.
pub(super) fn complete_samples(
    data: &TrainingSet,
    method: &str,
) -> Result<Vec<usize>, EstimatorError> {
    let kept: Vec<usize> = (0..data.sample.rows.len())
        .filter(|&i| {
            data.sample.rows[i]
                .iter()
                .all(|v| v.is_some_and(f64::is_finite))
        })
        .collect();
    if kept.is_empty() {
        return Err(EstimatorError::Training(format!(
            "no sample has every feature value present and finite, and {method} drops samples with a missing value"
        )));
    }
    Ok(kept)
}

/// A frame's values after the count check: non-finite values count as missing. Returns the
/// values and the ascending indices of the missing ones.
pub(super) fn frame_values(
    features: &[Option<f64>],
    expected: usize,
) -> Result<(Vec<Option<f64>>, Vec<usize>), EstimatorError> {
    if features.len() != expected {
        return Err(EstimatorError::FeatureCount {
            expected,
            found: features.len(),
        });
    }
    let values: Vec<Option<f64>> = features
        .iter()
        .map(|v| v.filter(|x| x.is_finite()))
        .collect();
    let missing = (0..expected).filter(|&i| values[i].is_none()).collect();
    Ok((values, missing))
}

/// A corrupted-file error.
pub(super) fn corrupted(what: impl Into<String>) -> EstimatorError {
    ModelError::Corrupted(what.into()).into()
}

/// Serialises a model file.
pub(super) fn write_file<T: Serialize>(file: &T) -> Result<String, EstimatorError> {
    serde_json::to_string_pretty(file)
        .map_err(|e| corrupted(format!("cannot serialise the model: {e}")))
}

/// Parses a model file of `method` at `version`: the header first (so a foreign or old file is
/// named as such), then any `null` outside the provenance and feature configuration (a number
/// that was not finite when written), then the typed fields.
pub(super) fn parse_file<T: DeserializeOwned>(
    text: &str,
    method: &'static str,
    version: u32,
) -> Result<T, EstimatorError> {
    let value: serde_json::Value =
        serde_json::from_str(text).map_err(|e| corrupted(e.to_string()))?;
    let object = value
        .as_object()
        .ok_or_else(|| corrupted("the top level is not a JSON object"))?;
    let found = object
        .get("format_version")
        .ok_or_else(|| corrupted(format!("no `format_version` field (expected {version})")))?;
    if found.as_u64() != Some(u64::from(version)) {
        return Err(ModelError::UnsupportedVersion {
            found: found.to_string(),
            supported: version,
        }
        .into());
    }
    match object.get("method").and_then(|m| m.as_str()) {
        Some(m) if m == method => {}
        Some(other) => {
            return Err(ModelError::WrongMethod {
                found: other.to_string(),
                expected: method,
            }
            .into())
        }
        None => {
            return Err(corrupted(
                "no `method` field (a string naming the estimation method)",
            ))
        }
    }
    for (key, v) in object {
        if key != "provenance" && key != "feature_config" {
            if let Some(path) = find_null(v, key.clone()) {
                return Err(corrupted(format!(
                    "`{path}` is null: it must be a finite number"
                )));
            }
        }
    }
    // Parsed again from the text so that errors carry line and column.
    serde_json::from_str(text).map_err(|e| corrupted(e.to_string()))
}

/// The path of the first `null` in `value`.
fn find_null(value: &serde_json::Value, path: String) -> Option<String> {
    match value {
        serde_json::Value::Null => Some(path),
        serde_json::Value::Array(items) => items
            .iter()
            .enumerate()
            .find_map(|(i, v)| find_null(v, format!("{path}[{i}]"))),
        serde_json::Value::Object(map) => map
            .iter()
            .find_map(|(k, v)| find_null(v, format!("{path}.{k}"))),
        _ => None,
    }
}

/// Reads a model file and parses it with `from_json`, naming the path in errors.
pub(super) fn load_file<T>(
    path: &Path,
    from_json: impl FnOnce(&str) -> Result<T, EstimatorError>,
) -> Result<T, EstimatorError> {
    let text = std::fs::read_to_string(path).map_err(|source| EstimatorError::Io {
        path: path.display().to_string(),
        source,
    })?;
    from_json(&text).map_err(|e| {
        let source = match e {
            EstimatorError::Model(m) => m,
            other => ModelError::Corrupted(other.to_string()),
        };
        ModelError::File {
            path: path.to_path_buf(),
            source: Box::new(source),
        }
        .into()
    })
}

/// Checks that every number of a fitted state is finite, naming the field otherwise.
pub(super) fn check_finite(field: &str, values: &[f64]) -> Result<(), EstimatorError> {
    match values.iter().position(|v| !v.is_finite()) {
        Some(i) => Err(corrupted(format!("`{field}[{i}]` is not finite"))),
        None => Ok(()),
    }
}
