//! The workspace-centre baseline (the error of knowing nothing: every frame gets the centre of the
//! sample poses' bounding box).

use std::path::Path;

use serde::{Deserialize, Serialize};

use super::inputs::{check_header_features, check_training, frame_values, training_header};
use super::{EstimateFlags, EstimatorError, PoseEstimate, PoseEstimator, TrainingSet};
use crate::features::FeatureConfig;
use crate::model_file::{self, corrupted, Header};

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
    #[serde(flatten)]
    header: Header,
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
            header: training_header(Self::METHOD, Self::FORMAT_VERSION, data),
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
    /// [`EstimatorError::File`] naming what is wrong.
    pub fn from_json(text: &str) -> Result<Self, EstimatorError> {
        let file: CentreFile = model_file::parse(text, Self::METHOD, Self::FORMAT_VERSION)?;
        check_header_features(&file.header)?;
        for (k, axis) in ["x", "y"].iter().enumerate() {
            if !(file.min[k].is_finite() && file.max[k].is_finite()) {
                return Err(corrupted(format!("`min` or `max` {axis} is not finite")).into());
            }
            if file.min[k] > file.max[k] {
                return Err(corrupted(format!("`min` {axis} is above `max` {axis}")).into());
            }
        }
        file.header
            .provenance
            .check_poses("min, max", &[file.min, file.max])?;
        Ok(Self::new(file))
    }

    /// Reads a model file written from [`PoseEstimator::to_json`].
    ///
    /// # Errors
    /// [`EstimatorError::Io`] when it cannot be read; [`EstimatorError::File`] naming the path
    /// and what is wrong otherwise.
    pub fn load(path: &Path) -> Result<Self, EstimatorError> {
        Ok(model_file::load(path, Self::from_json)?)
    }
}

impl PoseEstimator for Centre {
    fn method(&self) -> &'static str {
        Self::METHOD
    }

    fn feature_names(&self) -> &[String] {
        &self.file.header.feature_names
    }

    fn feature_config(&self) -> Option<&FeatureConfig> {
        self.file.header.feature_config.as_ref()
    }

    fn estimate(&self, features: &[Option<f64>]) -> Result<PoseEstimate, EstimatorError> {
        let (_, missing) = frame_values(features, self.file.header.feature_names.len())?;
        Ok(PoseEstimate {
            detection_score: None,
            pose: Some(self.centre),
            uncertainty_radius: None,
            group: None,
            conflict_level: None,
            region: None,
            // Nothing to say frame by frame: its calibrated region is one disc.
            covariance: None,
            flags: EstimateFlags {
                missing,
                ..EstimateFlags::default()
            },
        })
    }

    fn to_json(&self) -> Result<String, EstimatorError> {
        Ok(model_file::to_text(&self.file)?)
    }
}
