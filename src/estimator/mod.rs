//! The pose-estimator seam: anything that learns from a sample trajectory of (features, pose) and
//! then estimates a pose per frame, with per-frame diagnostics where the method has them.
//!
//! The harness ([`crate::experiment`]) fits every configured estimator on the same
//! [`TrainingSet`] and runs it on identical feature rows; `evitrack train` and `evitrack track` go
//! through the same seam. The paper's evidential tracker ([`Evidential`]) is the first
//! implementation. A fitted estimator is self-contained: [`PoseEstimator::to_json`] writes a
//! model file that [`load`] reads back into an estimator giving the same estimates.

mod calibration;
mod centre;
mod continuous;
mod evidential;
mod gp;
mod inputs;
mod knn;
mod local_surface;
mod motion;
mod particle;
mod registry;
mod samples;
mod temporal;
pub mod test_maps;

pub(crate) use calibration::conformal_quantile;
pub use calibration::{
    underlying, Calibrated, Calibration, CellRadii, ConfidenceSettings, RenderSource,
};
pub use centre::{Centre, CentreSettings};
pub(crate) use continuous::grid_nodes;
pub use continuous::{
    Continuous, ContinuousSettings, ContinuousTemporal, SurrogateHyperparameters,
    MAX_CONTINUOUS_FEATURES,
};
pub use evidential::{Evidential, EvidentialSettings, MAX_FEATURES_GROUP_ERRORS};
pub use gp::{Gp, GpHyperparameters, GpSettings};
pub use knn::{Knn, KnnSettings, KnnWeights};
pub use motion::{IncoherentFrames, TemporalSettings, DEFAULT_RELIABILITY, RELIABILITY_CANDIDATES};
pub(crate) use motion::{REFINE_MAX_POINTS, REFINE_SUBDIVISIONS};
pub use particle::{FilterScore, ParticleFilter, ParticleSettings};
pub use registry::{
    register, CheckFn, EstimatorSettings, FitFn, LoadFn, Method, MethodEntry, RegistryError,
    SettingsContext, SharedFitFn, BUILT_IN,
};
pub(crate) use samples::check_exact_gp_samples;
pub use samples::MAX_EXACT_GP_SAMPLES;
pub use temporal::TemporalEvidential;

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::dataset::Dataset;
use crate::features::{FeatureConfig, FeatureError, FeatureRows, FeatureSet};
use crate::model::ModelError;
use crate::model_file::{ModelFileError, Provenance};
use crate::planar::bounding_diagonal;
use crate::track::TrackError;

/// Failures of fitting, loading or running an estimator.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum EstimatorError {
    /// Training or loading the evidential model failed.
    #[error(transparent)]
    Model(#[from] ModelError),
    /// A model file cannot be read: its format, method or a field (the path, when loaded).
    #[error(transparent)]
    File(ModelFileError),
    /// Building or running the evidential tracker failed.
    #[error("tracker: {0}")]
    Track(#[from] TrackError),
    /// The feature configuration is invalid.
    #[error("feature configuration: {0}")]
    Features(#[from] FeatureError),
    /// The training set is inconsistent.
    #[error("training set: {0}")]
    Training(String),
    /// A frame has the wrong number of feature values.
    #[error("the frame has {found} feature values but the estimator was trained on {expected}: pass one value per feature (None when missing)")]
    FeatureCount {
        /// Features the estimator was trained on.
        expected: usize,
        /// Values given.
        found: usize,
    },
    /// The features read frames the other way round from the dataset's manifest.
    #[error("{what} declares `camera.polarity = {declared:?}` in its manifest, but the features read frames as {configured:?}: set the feature configuration's `polarity` to the manifest's")]
    Polarity {
        /// The dataset.
        what: String,
        /// The manifest's polarity.
        declared: crate::features::Polarity,
        /// The feature configuration's.
        configured: crate::features::Polarity,
    },
    /// A dataset has no ground truth where it is needed.
    #[error("{0} has no ground-truth poses: training and validation need them")]
    NoTruth(String),
    /// The estimator has no feature configuration, so it cannot extract features from images.
    #[error("the model records no feature configuration (it was trained on features computed elsewhere): extract the features yourself and call `estimate`")]
    NoFeatureConfig,
    /// Reading or writing a model file failed.
    #[error("model file {path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The I/O error.
        source: std::io::Error,
    },
}

/// One frame's estimate and diagnostics. Diagnostics a method has no notion of are `None`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct PoseEstimate {
    /// Estimated pose (mm); `None` when the frame gives the method nothing to estimate from.
    pub pose: Option<[f64; 2]>,
    /// Radius around the estimate holding the method's stated share of its belief (mm).
    pub uncertainty_radius: Option<f64>,
    /// Features combined for the estimate (ascending indices), for methods that choose them.
    pub group: Option<Vec<usize>>,
    /// Level of conflict of the combined features, for evidential methods.
    pub conflict_level: Option<f64>,
    /// How unusual the frame's measurements look to the method, higher meaning more likely
    /// corrupted (+∞: impossible): the level of conflict of every usable feature for the
    /// evidential tracker, the standardised distance to the nearest sample for k-NN and the GP.
    pub detection_score: Option<f64>,
    /// The region of poses the method finds plausible: calibrated on the validation motion to
    /// hold the truth on the stated share of clean frames ([`Calibration`]), or the whole
    /// workspace when the method abstains; the continuous tracker's own χ² region when the
    /// model has no calibration.
    pub region: Option<PlausibilityRegion>,
    /// The method's own covariance of the pose (mm²): the shape its calibrated region takes
    /// (the plausibility's spread plus the sample poses' cells, the Laplace covariance, the
    /// GP's predictive variance, the neighbours' spread plus their cells, the particles' spread,
    /// the sample poses' for the centre).
    #[serde(default)]
    pub covariance: Option<[[f64; 2]; 2]>,
    /// What deserves attention in this frame.
    pub flags: EstimateFlags,
}

/// An elliptic region of poses: those q with (q − centre)ᵀ shape (q − centre) ≤ 1.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PlausibilityRegion {
    /// The estimate it is centred on (mm).
    pub centre: [f64; 2],
    /// Symmetric positive-definite shape matrix (mm⁻²).
    pub shape: [[f64; 2]; 2],
    /// The relative plausibility its boundary holds (Pl(q)/Pl(centre)) for the continuous
    /// tracker's own region; the nominal coverage for a calibrated one; 1 for the whole workspace.
    pub level: f64,
    /// Its area (mm²).
    pub area: f64,
    /// Its longest semi-axis (mm).
    pub semi_major: f64,
}

impl PlausibilityRegion {
    /// The region {q : (q − centre)ᵀ curvature (q − centre) ≤ chi2}, from the curvature of
    /// ½χ² at its minimum; `None` unless the curvature is positive definite and well conditioned.
    pub fn from_curvature(
        centre: [f64; 2],
        curvature: [[f64; 2]; 2],
        chi2: f64,
        level: f64,
    ) -> Option<Self> {
        let [[a, b], [_, c]] = curvature;
        let det = a * c - b * b;
        let trace = a + c;
        if !(det.is_finite() && trace.is_finite() && det > 1e-12 * trace * trace && chi2 > 0.0) {
            return None;
        }
        let smallest = 0.5 * (trace - ((a - c) * (a - c) + 4.0 * b * b).sqrt());
        let scale = 1.0 / chi2;
        Some(Self {
            centre,
            shape: [[a * scale, b * scale], [b * scale, c * scale]],
            level,
            area: std::f64::consts::PI * chi2 / det.sqrt(),
            semi_major: (chi2 / smallest.max(f64::MIN_POSITIVE)).sqrt(),
        })
    }

    /// (q − centre)ᵀ shape (q − centre): at most 1 inside the region.
    pub fn distance(&self, q: [f64; 2]) -> f64 {
        let d = [q[0] - self.centre[0], q[1] - self.centre[1]];
        let s = &self.shape;
        d[0] * (s[0][0] * d[0] + s[0][1] * d[1]) + d[1] * (s[1][0] * d[0] + s[1][1] * d[1])
    }

    /// Whether pose `q` lies inside.
    pub fn covers(&self, q: [f64; 2]) -> bool {
        self.distance(q) <= 1.0
    }
}

/// The covariance (mm²) of a Laplace approximation: the inverse of the curvature of ½χ² at its
/// minimum, with a ridge of a millionth of its trace so that a curvature along one direction
/// only (one feature: a level curve) gives a huge variance along the curve rather than none.
pub(crate) fn laplace_covariance(curvature: [[f64; 2]; 2]) -> Option<[[f64; 2]; 2]> {
    let [[a, b], [c, d]] = curvature;
    let b = 0.5 * (b + c);
    let ridge = 1e-6 * (a + d).abs();
    let (a, d) = (a + ridge, d + ridge);
    let det = a * d - b * b;
    (det.is_finite() && det > 0.0 && a > 0.0).then(|| [[d / det, -b / det], [-b / det, a / det]])
}

/// Flags of one frame's estimate (all empty or false on a clean frame).
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct EstimateFlags {
    /// Features with no value in this frame.
    pub missing: Vec<usize>,
    /// Usable features the method left out (the conflict graph's rejections).
    pub excluded: Vec<usize>,
    /// The method fell back to a reduced estimate (one feature).
    pub fallback: bool,
    /// Combining the chosen features gave no usable result.
    pub combination_failed: bool,
    /// The estimate is the motion model's prediction from the past frames (temporal methods):
    /// the frame had no usable measurement, or the past outweighed every feature.
    pub predicted: bool,
    /// The belief carried from the past frames conflicted with this frame's and was left out:
    /// the past was dropped and tracking restarts from this frame (temporal evidential tracker).
    pub past_rejected: bool,
    /// The method's own evidence says it cannot tell (its detection score beyond what clean
    /// validation frames show, total conflict, no eligible group, or a region too large): the
    /// pose is kept for reference, the region covers the whole workspace.
    #[serde(default)]
    pub abstained: bool,
    /// The harness's render check (`[confidence] render_check`) made it abstain: the robot
    /// rendered at the estimate differs from the frame's silhouette by more pixels than on the
    /// method's clean calibration frames (`abstained` is set too).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub render_mismatch: bool,
    /// The render check made it abstain because the frame shows more stray pixels (on the body's
    /// side of the threshold, outside the silhouette) than any clean calibration frame: something
    /// no pose of the robot explains (`abstained` is set too).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub stray_pixels: bool,
    /// The splitting policy found more alternatives than its cap (`track.max_alternatives`):
    /// how many it found; the estimate is drawn from the first ones only.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub alternatives_capped: Option<usize>,
}

impl PoseEstimate {
    /// The flags as short words (`missing:…`, `excluded:…`, `fallback`, `combination_failed`,
    /// `predicted`, `past_rejected`, `abstained`, `render_mismatch`, `stray_pixels`,
    /// `alternatives_capped:N`, `no_estimate`) with feature `names`; empty when the frame is
    /// clean.
    pub fn flag_words(&self, names: &[String]) -> String {
        let joined = |list: &[usize]| {
            list.iter()
                .map(|&i| names[i].as_str())
                .collect::<Vec<_>>()
                .join("+")
        };
        let flags = &self.flags;
        let mut parts = Vec::new();
        if !flags.missing.is_empty() {
            parts.push(format!("missing:{}", joined(&flags.missing)));
        }
        if !flags.excluded.is_empty() {
            parts.push(format!("excluded:{}", joined(&flags.excluded)));
        }
        if flags.fallback {
            parts.push("fallback".into());
        }
        if flags.combination_failed {
            parts.push("combination_failed".into());
        }
        if flags.predicted {
            parts.push("predicted".into());
        }
        if flags.past_rejected {
            parts.push("past_rejected".into());
        }
        if flags.abstained {
            parts.push("abstained".into());
        }
        if flags.render_mismatch {
            parts.push("render_mismatch".into());
        }
        if flags.stray_pixels {
            parts.push("stray_pixels".into());
        }
        if let Some(found) = flags.alternatives_capped {
            parts.push(format!("alternatives_capped:{found}"));
        }
        if self.pose.is_none() {
            parts.push("no_estimate".into());
        }
        parts.join(" ")
    }
}

/// A fitted pose estimator.
pub trait PoseEstimator: Send + Sync + std::fmt::Debug + std::any::Any {
    /// The method's name, as written in scenario and model files (`"evidential"`).
    fn method(&self) -> &'static str;

    /// Names of the features it expects per frame, in order.
    fn feature_names(&self) -> &[String];

    /// The feature configuration it was trained with, when recorded (needed to track images).
    fn feature_config(&self) -> Option<&FeatureConfig>;

    /// Estimates one frame from its feature values (one per feature, `None` when missing).
    ///
    /// # Errors
    /// [`EstimatorError::FeatureCount`] when `features` does not have one value per feature.
    fn estimate(&self, features: &[Option<f64>]) -> Result<PoseEstimate, EstimatorError>;

    /// The self-contained model file (JSON) that [`load`] reads back.
    fn to_json(&self) -> Result<String, EstimatorError>;

    /// A tracker of one motion, fed its frames in order: temporal methods carry what the past
    /// frames showed; the others estimate each frame alone (the default).
    fn start_motion(&self) -> Box<dyn MotionTracker + '_> {
        Box::new(FrameByFrame(self))
    }

    /// The same fitted estimator recording `provenance` instead, for methods whose fit does not
    /// depend on it (beyond the training seed, which a temporal method's fit key holds) and is
    /// worth sharing between runs on identical training data: every built-in method but k-NN
    /// and the centre, whose fits cost nothing (the variants of a sweep that differ only in
    /// their test motions or faults fit once; see [`crate::experiment::Workbench::fit`]);
    /// `None` for the others.
    fn with_provenance(&self, _provenance: &Provenance) -> Option<Box<dyn PoseEstimator>> {
        None
    }
}

/// One motion's frames, estimated in order by [`PoseEstimator::start_motion`]'s tracker.
pub trait MotionTracker {
    /// Estimates the next frame, taken at `time` (s), from its feature values.
    ///
    /// # Errors
    /// As [`PoseEstimator::estimate`].
    fn next(&mut self, time: f64, features: &[Option<f64>])
        -> Result<PoseEstimate, EstimatorError>;
}

/// The tracker of a per-frame method: every frame alone.
struct FrameByFrame<'a, E: ?Sized>(&'a E);

impl<E: PoseEstimator + ?Sized> MotionTracker for FrameByFrame<'_, E> {
    fn next(
        &mut self,
        _time: f64,
        features: &[Option<f64>],
    ) -> Result<PoseEstimate, EstimatorError> {
        self.0.estimate(features)
    }
}

/// Ground-truth poses and the feature rows measured at them.
#[derive(Debug, Clone, Copy)]
pub struct Labelled<'a> {
    /// One pose per row (mm).
    pub poses: &'a [[f64; 2]],
    /// Feature values, one row per pose.
    pub rows: &'a [Vec<Option<f64>>],
}

/// What every estimator is fitted on.
#[derive(Debug, Clone)]
pub struct TrainingSet<'a> {
    /// Feature names, one per column of the rows.
    pub feature_names: &'a [String],
    /// The configuration the features were extracted with (`None` for features computed
    /// elsewhere).
    pub feature_config: Option<&'a FeatureConfig>,
    /// The sample trajectory.
    pub sample: Labelled<'a>,
    /// A validation motion, for what a method learns on held-out frames.
    pub validation: Option<Labelled<'a>>,
    /// The validation frames' times (s), for what temporal methods learn there.
    pub validation_times: Option<&'a [f64]>,
    /// A calibration motion for the regions and abstentions ([`Calibration`]); `None`: the
    /// validation motion calibrates them.
    pub calibration: Option<Labelled<'a>>,
    /// The calibration frames' times (s).
    pub calibration_times: Option<&'a [f64]>,
    /// The error a validation frame without an estimate counts as (mm): the workspace diagonal.
    pub missing_penalty: f64,
    /// Where the model comes from.
    pub provenance: Provenance,
}

impl<'a> TrainingSet<'a> {
    /// A training set of a sample trajectory alone: no feature configuration, no validation
    /// motion, the diagonal of the sample poses' bounding box as the missing penalty, and a
    /// provenance with no scenario and seed 0. The `with_*` methods add the rest.
    pub fn new(feature_names: &'a [String], sample: Labelled<'a>) -> Self {
        Self {
            feature_names,
            feature_config: None,
            sample,
            validation: None,
            validation_times: None,
            calibration: None,
            calibration_times: None,
            missing_penalty: bounding_diagonal(sample.poses),
            provenance: Provenance::new(None, 0),
        }
    }

    /// With the configuration the features were extracted with (so the model can track images).
    pub fn with_config(self, config: &'a FeatureConfig) -> Self {
        Self {
            feature_config: Some(config),
            ..self
        }
    }
}

/// Ground truth and features of a dataset's frames, extracted with one feature set.
#[derive(Debug, Clone, PartialEq)]
pub struct DatasetFeatures {
    /// Ground-truth poses (mm).
    pub poses: Vec<[f64; 2]>,
    /// Feature rows, one per frame.
    pub rows: FeatureRows,
}

impl DatasetFeatures {
    /// Extracts `set`'s features from every frame of `dataset`; `what` names it in errors.
    ///
    /// # Errors
    /// [`EstimatorError::NoTruth`] when the dataset has no ground-truth poses;
    /// [`EstimatorError::Polarity`] when the set reads frames the other way round from the one
    /// the dataset's manifest declares; an invalid input when the set has external programs,
    /// which `crate::external::extract` runs (this room runs no program).
    pub fn extract(
        dataset: &Dataset,
        set: &FeatureSet,
        what: &str,
    ) -> Result<Self, EstimatorError> {
        let declared = dataset.manifest.camera.polarity;
        if let Some(configured) = set.polarity().filter(|&p| p != declared) {
            return Err(EstimatorError::Polarity {
                what: what.to_string(),
                declared,
                configured,
            });
        }
        if let Some(program) = set.external().first() {
            return Err(ModelError::InvalidInput {
                what: "feature set",
                reason: format!(
                    "it runs the program `{}`: extract with `evitrack::external::extract`",
                    program.label()
                ),
            }
            .into());
        }
        let poses = dataset
            .truth_positions()
            .ok_or_else(|| EstimatorError::NoTruth(what.to_string()))?;
        Ok(Self {
            poses,
            rows: set.extract_batch(dataset.images()),
        })
    }

    /// Borrowed view for a [`TrainingSet`].
    pub fn labelled(&self) -> Labelled<'_> {
        Labelled {
            poses: &self.poses,
            rows: &self.rows,
        }
    }
}

/// Reads a model file written by any registered estimator's [`PoseEstimator::to_json`] and
/// returns the estimator it describes: its `method` field picks the registry entry that reads it
/// (`evidential` when absent, so that old evidential files are named as such); a `calibration`
/// field wraps it in [`Calibrated`].
///
/// # Errors
/// [`EstimatorError::Io`] when the file cannot be read; [`EstimatorError::File`] naming the
/// path and what is wrong (format version, method, a field) otherwise.
pub fn load(path: &Path) -> Result<Box<dyn PoseEstimator>, EstimatorError> {
    let text = crate::model_file::read_text(path)?;
    let name = serde_json::from_str::<serde_json::Value>(&text)
        .ok()
        .and_then(|v| v.get("method")?.as_str().map(String::from))
        .unwrap_or_else(|| crate::model::METHOD.to_string());
    match Method::from_name(&name) {
        Some(method) => load_text(method, path, &text),
        None => Err(ModelFileError::File {
            path: path.to_path_buf(),
            source: Box::new(crate::model_file::corrupted(format!(
                "unknown method `{name}`: this build reads {} model files",
                Method::names_sentence()
            ))),
        }
        .into()),
    }
}

/// Reads `text`, read from `path`, as a model file of `method`: its `calibration`, if any, split
/// off and checked, the rest read by the method's registry entry (which refuses another
/// method's file).
///
/// # Errors
/// [`EstimatorError::File`] naming the path and what is wrong.
pub fn load_text(
    method: Method,
    path: &Path,
    text: &str,
) -> Result<Box<dyn PoseEstimator>, EstimatorError> {
    let (text, calibration) =
        calibration::split_calibration(text).map_err(|e| ModelFileError::File {
            path: path.to_path_buf(),
            source: Box::new(crate::model_file::corrupted(e)),
        })?;
    let inner = (method.entry().load)(path, &text)?;
    Ok(match calibration {
        Some(c) => Box::new(Calibrated::new(inner, c)),
        None => inner,
    })
}
