//! Confidence every method can be held to: regions calibrated on the validation motion by a
//! split-conformal quantile, and abstention where the method's own evidence says it cannot tell.
//!
//! Each method states a covariance Σ of its pose per frame ([`PoseEstimate::covariance`]: the
//! plausibility's spread plus the sample poses' cells, the Laplace covariance, the GP's
//! predictive variance, the neighbours' spread plus their cells, the particles' spread). Its
//! nonconformity score on a frame is the Mahalanobis distance r = √(dᵀ (Σ + f·I)⁻¹ d) of the
//! truth from the estimate, f a small floor so that a point-mass belief still has a region. On
//! the n validation frames the ⌈(n+1)·c⌉-th smallest r is the radius q, and a test frame's region
//! is {p : r(p) ≤ q}. If validation and test frames are exchangeable, the region holds the truth
//! with probability at least c (Vovk et al., split conformal prediction). That is the assumption:
//! a clean test motion like the validation motion; a fault breaks it, which is why abstention
//! exists.
//!
//! A method abstains (the pose stays, flagged `abstained`, with a region over the whole workspace)
//! when its detection score lies above the ⌈(n+1)(1 − a)⌉-th smallest validation score q (so about
//! a share a of clean frames like the validation motion's abstain) stretched to q + κ·(q − m), m
//! the median score (`detection_stretch`: a test motion that visits poses the validation passes
//! less scores a little above every validation frame, a fault far above); when the score is not
//! finite (total conflict); when it fell back to one feature or its combination failed; or when
//! its region would exceed `max_region_share` of the workspace.

use std::sync::Arc;

use serde::{Deserialize, Serialize};

use super::{MotionTracker, PlausibilityRegion, PoseEstimate, PoseEstimator, TrainingSet};
use crate::planar::{bounding_box, distance, Rect};
use crate::range::within;

#[path = "calibration_cells.rs"]
mod cells;
pub use cells::CellRadii;

#[path = "calibration_settings.rs"]
mod settings;
pub use settings::{ConfidenceSettings, RenderSource};

/// What a method learned of its own reliability on the validation motion (stored in its model
/// file as `calibration`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Calibration {
    /// The nominal coverage of the regions.
    pub coverage: f64,
    /// The split-conformal quantile of the Mahalanobis scores (`None`: too few validation frames
    /// for the coverage, so every region is the whole workspace).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub radius: Option<f64>,
    /// Added to Σ's diagonal (mm²): a hundredth of the median squared validation error.
    pub floor: f64,
    /// Detection scores above this make the method abstain (`None`: it has no score, or too few
    /// validation frames to set one).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub detection_limit: Option<f64>,
    /// Regions larger than this (mm²) make the method abstain.
    pub max_region_area: f64,
    /// The workspace an abstaining region covers.
    pub workspace: Rect,
    /// Validation frames it was learned on.
    pub validation_frames: usize,
    /// Share of those frames on which it abstained.
    pub validation_abstained: f64,
    /// With `[confidence] cells`: each cell's own quantile, which replaces `radius` for an
    /// estimate in that cell.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cell_radii: Option<CellRadii>,
    /// The render check's limit (pixels of mismatch) with silhouettes from the sample frames,
    /// learned in the run that wrote the file (`confidence.render_check`); `track --samples`
    /// applies it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub render_limit_px: Option<f64>,
    /// The render check's limit of stray pixels (the most any clean calibration frame showed),
    /// learned with `render_limit_px`; `track --samples` applies it too.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stray_limit_px: Option<f64>,
}

/// The poses a method estimated on its calibration frames, in order (`None`: no estimate).
pub type CalibrationPoses = Vec<Option<[f64; 2]>>;

/// ⌈(n+1)·share⌉, the rank of the split-conformal quantile at `share` of n values.
fn conformal_rank(n: usize, share: f64) -> usize {
    // Less a hair, so that 10 × 0.9 (9.000000000000002 in floating point) is rank 9.
    ((n + 1) as f64 * share - 1e-9).ceil() as usize
}

/// The ⌈(n+1)·share⌉-th smallest of `values` (non-finite ones rank last); `None` past the end.
pub(crate) fn conformal_quantile(values: &[f64], share: f64) -> Option<f64> {
    let mut sorted: Vec<f64> = values
        .iter()
        .map(|&v| if v.is_nan() { f64::INFINITY } else { v })
        .collect();
    sorted.sort_by(f64::total_cmp);
    let rank = conformal_rank(sorted.len(), share);
    (rank >= 1)
        .then(|| sorted.get(rank - 1).copied())
        .flatten()
        .filter(|v| v.is_finite())
}

/// `limit` moved `stretch` times its distance from the median of `scores` (their conformal
/// quantile at one half) further out; left where that median is not finite.
fn stretched(limit: f64, scores: &[f64], stretch: f64) -> f64 {
    match conformal_quantile(scores, 0.5) {
        Some(median) => limit + stretch * (limit - median).max(0.0),
        None => limit,
    }
}

/// (Σ + f·I) with its inverse and determinant; `None` unless positive definite.
fn regularised(covariance: Option<[[f64; 2]; 2]>, floor: f64) -> Option<([[f64; 2]; 2], f64)> {
    let [[a, b], [c, d]] = covariance.unwrap_or([[0.0; 2]; 2]);
    let b = 0.5 * (b + c);
    let (a, d) = (a + floor, d + floor);
    let det = a * d - b * b;
    (det.is_finite() && det > 0.0 && a > 0.0)
        .then(|| ([[d / det, -b / det], [-b / det, a / det]], det))
}

fn mahalanobis(inverse: &[[f64; 2]; 2], e: [f64; 2], t: [f64; 2]) -> f64 {
    let v = [t[0] - e[0], t[1] - e[1]];
    let s = inverse;
    (v[0] * (s[0][0] * v[0] + s[0][1] * v[1]) + v[1] * (s[1][0] * v[0] + s[1][1] * v[1]))
        .max(0.0)
        .sqrt()
}

impl Calibration {
    /// Learns the calibration of `estimator` on `data`'s calibration motion, or else its
    /// validation motion (tracked in order, with its times); `None` without either.
    ///
    /// # Errors
    /// The estimator's own errors on a validation frame.
    pub fn learn(
        estimator: &dyn PoseEstimator,
        data: &TrainingSet,
        settings: &ConfidenceSettings,
    ) -> Result<Option<Self>, super::EstimatorError> {
        Ok(Self::learn_with_poses(estimator, data, settings)?.map(|(calibration, _)| calibration))
    }

    /// [`Calibration::learn`], with the poses the method estimated on those frames.
    ///
    /// # Errors
    /// The estimator's own errors on a validation frame.
    pub fn learn_with_poses(
        estimator: &dyn PoseEstimator,
        data: &TrainingSet,
        settings: &ConfidenceSettings,
    ) -> Result<Option<(Self, CalibrationPoses)>, super::EstimatorError> {
        let (validation, times) = match (&data.calibration, &data.validation) {
            (Some(calibration), _) => (calibration, data.calibration_times),
            (None, Some(validation)) => (validation, data.validation_times),
            (None, None) => return Ok(None),
        };
        let mut motion = estimator.start_motion();
        let mut estimates = Vec::with_capacity(validation.rows.len());
        for (i, row) in validation.rows.iter().enumerate() {
            let time = times.and_then(|t| t.get(i).copied());
            estimates.push(motion.next(time.unwrap_or(i as f64), row)?);
        }
        let workspace = data.provenance.workspace.unwrap_or_else(|| {
            // Without a declared workspace, the sample poses' box (at least a millimetre wide).
            let (lo, hi) = bounding_box(data.sample.poses);
            let pad = |a: f64, b: f64| 0.5 * (1.0 - (b - a)).max(0.0);
            Rect {
                x_min: lo[0] - pad(lo[0], hi[0]),
                x_max: hi[0] + pad(lo[0], hi[0]),
                y_min: lo[1] - pad(lo[1], hi[1]),
                y_max: hi[1] + pad(lo[1], hi[1]),
            }
        });
        let calibration = Self::from_validation(&estimates, validation.poses, workspace, settings);
        Ok(Some((
            calibration,
            estimates.iter().map(|e| e.pose).collect(),
        )))
    }

    /// The calibration of these validation `estimates` against their `truth`.
    pub fn from_validation(
        estimates: &[PoseEstimate],
        truth: &[[f64; 2]],
        workspace: Rect,
        settings: &ConfidenceSettings,
    ) -> Self {
        let mut errors: Vec<f64> = (estimates.iter().zip(truth))
            .filter_map(|(e, t)| e.pose.map(|p| distance(p, *t)))
            .filter(|e| e.is_finite())
            .collect();
        errors.sort_by(f64::total_cmp);
        let median = errors.get(errors.len() / 2).copied().unwrap_or(0.0);
        let diagonal = workspace.diagonal();
        // A floor below a micrometre means nothing here, and keeps Σ invertible.
        let floor = (0.01 * median * median)
            .max(1e-6 * diagonal * diagonal)
            .max(1e-12);
        let scores: Vec<f64> = (estimates.iter().zip(truth))
            .map(|(e, t)| match (e.pose, regularised(e.covariance, floor)) {
                (Some(p), Some((inverse, _))) => mahalanobis(&inverse, p, *t),
                _ => f64::INFINITY,
            })
            .collect();
        let detections: Vec<f64> = estimates.iter().filter_map(|e| e.detection_score).collect();
        let detection_limit = (!detections.is_empty())
            .then(|| {
                let share = settings.detection_share(estimates.len());
                let limit = conformal_quantile(&detections, 1.0 - share)?;
                Some(stretched(limit, &detections, settings.detection_stretch))
            })
            .flatten();
        let cell_radii = settings.cells.map(|cells| {
            let poses: Vec<Option<[f64; 2]>> = estimates.iter().map(|e| e.pose).collect();
            CellRadii::learn(cells, &workspace, &poses, &scores, settings.coverage)
        });
        let mut calibration = Self {
            coverage: settings.coverage,
            radius: conformal_quantile(&scores, settings.coverage),
            floor,
            detection_limit,
            max_region_area: settings.max_region_share * workspace.area(),
            workspace,
            validation_frames: estimates.len(),
            validation_abstained: 0.0,
            cell_radii,
            render_limit_px: None,
            stray_limit_px: None,
        };
        let abstained = estimates
            .iter()
            .filter(|e| {
                let mut e = (*e).clone();
                calibration.apply(&mut e);
                e.flags.abstained
            })
            .count();
        calibration.validation_abstained = abstained as f64 / estimates.len().max(1) as f64;
        calibration
    }

    /// The region over the whole workspace: the disc through its corners.
    fn workspace_region(&self) -> PlausibilityRegion {
        let w = &self.workspace;
        let centre = [0.5 * (w.x_min + w.x_max), 0.5 * (w.y_min + w.y_max)];
        let radius = 0.5 * w.diagonal();
        let inverse = 1.0 / (radius * radius);
        PlausibilityRegion {
            centre,
            shape: [[inverse, 0.0], [0.0, inverse]],
            level: 1.0,
            area: std::f64::consts::PI * radius * radius,
            semi_major: radius,
        }
    }

    /// Makes `estimate` abstain: the pose stays, the region covers the whole workspace.
    pub fn abstain(&self, estimate: &mut PoseEstimate) {
        estimate.region = Some(self.workspace_region());
        estimate.flags.abstained = true;
    }

    /// Why the method should abstain on `estimate` before its region is drawn, if it should.
    fn evidence_fails(&self, estimate: &PoseEstimate) -> bool {
        let flags = &estimate.flags;
        let beyond = match (estimate.detection_score, self.detection_limit) {
            (Some(s), _) if !s.is_finite() => true,
            (Some(s), Some(limit)) => s > limit,
            _ => false,
        };
        beyond || flags.fallback || flags.combination_failed
    }

    /// Gives `estimate` its calibrated region, or flags it `abstained` with a region over the
    /// whole workspace. Frames without a pose are left alone.
    pub fn apply(&self, estimate: &mut PoseEstimate) {
        let Some(pose) = estimate.pose else { return };
        // A method that states no covariance (the centre) gives no region, but may abstain.
        let Some(covariance) = estimate.covariance else {
            if self.evidence_fails(estimate) {
                self.abstain(estimate);
            }
            return;
        };
        let radius = (self.cell_radii.as_ref())
            .and_then(|c| c.radius_at(&self.workspace, pose))
            .or(self.radius);
        let region = radius.and_then(|q| {
            let (inverse, det) = regularised(Some(covariance), self.floor)?;
            let scale = 1.0 / (q * q);
            let shape = inverse.map(|row| row.map(|v| v * scale));
            let [[a, b], [_, d]] = inverse;
            // The smallest eigenvalue of Σ⁻¹ gives the longest semi-axis.
            let smallest = 0.5 * (a + d - ((a - d) * (a - d) + 4.0 * b * b).sqrt());
            Some(PlausibilityRegion {
                centre: pose,
                shape,
                level: self.coverage,
                area: std::f64::consts::PI * q * q * det.sqrt(),
                semi_major: q / smallest.max(f64::MIN_POSITIVE).sqrt(),
            })
        });
        match region {
            Some(r) if r.area <= self.max_region_area && !self.evidence_fails(estimate) => {
                estimate.region = Some(r);
            }
            _ => self.abstain(estimate),
        }
    }
}

/// A fitted method with its calibration: estimates as the method, then the region and
/// abstention of [`Calibration::apply`]. Its model file is the method's with a `calibration`
/// field added.
#[derive(Debug)]
pub struct Calibrated {
    inner: Box<dyn PoseEstimator>,
    calibration: Calibration,
    /// The poses it estimated on the calibration frames, when it was fitted in this process
    /// (not in the model file): the harness's render check learns its limit on them.
    poses: Arc<[Option<[f64; 2]>]>,
}

impl Calibrated {
    /// `inner` with `calibration`.
    pub fn new(inner: Box<dyn PoseEstimator>, calibration: Calibration) -> Self {
        Self {
            inner,
            calibration,
            poses: Arc::new([]),
        }
    }

    /// The same with the `poses` it estimated on the calibration frames.
    pub fn with_poses(self, poses: Vec<Option<[f64; 2]>>) -> Self {
        Self {
            poses: poses.into(),
            ..self
        }
    }

    /// The poses it estimated on the calibration frames (empty when read from a model file).
    pub fn calibration_poses(&self) -> &[Option<[f64; 2]>] {
        &self.poses
    }

    /// The method it calibrates.
    pub fn inner(&self) -> &dyn PoseEstimator {
        self.inner.as_ref()
    }

    /// Its calibration.
    pub fn calibration(&self) -> &Calibration {
        &self.calibration
    }

    /// Keeps the render check's limits learned in a run (mismatch, stray pixels), so its model
    /// file carries them.
    pub fn set_render_limits(&mut self, (limit_px, stray_px): (Option<f64>, Option<f64>)) {
        self.calibration.render_limit_px = limit_px;
        self.calibration.stray_limit_px = stray_px;
    }
}

struct CalibratedMotion<'a> {
    inner: Box<dyn MotionTracker + 'a>,
    calibration: &'a Calibration,
}

impl MotionTracker for CalibratedMotion<'_> {
    fn next(
        &mut self,
        time: f64,
        features: &[Option<f64>],
    ) -> Result<PoseEstimate, super::EstimatorError> {
        let mut estimate = self.inner.next(time, features)?;
        self.calibration.apply(&mut estimate);
        Ok(estimate)
    }
}

impl PoseEstimator for Calibrated {
    fn method(&self) -> &'static str {
        self.inner.method()
    }

    fn feature_names(&self) -> &[String] {
        self.inner.feature_names()
    }

    fn feature_config(&self) -> Option<&crate::features::FeatureConfig> {
        self.inner.feature_config()
    }

    fn estimate(&self, features: &[Option<f64>]) -> Result<PoseEstimate, super::EstimatorError> {
        let mut estimate = self.inner.estimate(features)?;
        self.calibration.apply(&mut estimate);
        Ok(estimate)
    }

    fn to_json(&self) -> Result<String, super::EstimatorError> {
        let text = self.inner.to_json()?;
        with_calibration(&text, &self.calibration)
    }

    fn start_motion(&self) -> Box<dyn MotionTracker + '_> {
        Box::new(CalibratedMotion {
            inner: self.inner.start_motion(),
            calibration: &self.calibration,
        })
    }

    fn with_provenance(
        &self,
        provenance: &crate::model_file::Provenance,
    ) -> Option<Box<dyn PoseEstimator>> {
        let inner = self.inner.with_provenance(provenance)?;
        Some(Box::new(Self {
            inner,
            calibration: self.calibration.clone(),
            poses: Arc::clone(&self.poses),
        }))
    }
}

/// The method's model file `text` (a JSON object) with `calibration` as its last field, the rest
/// byte for byte.
fn with_calibration(
    text: &str,
    calibration: &Calibration,
) -> Result<String, super::EstimatorError> {
    let body = text.trim_end();
    let Some(open) = body.strip_suffix('}') else {
        return Err(super::EstimatorError::Training(
            "the method's model file is not a JSON object".into(),
        ));
    };
    let calibration = crate::model_file::to_text(calibration)?.replace('\n', "\n  ");
    let open = open.trim_end();
    let separator = if open.ends_with('{') { "" } else { "," };
    Ok(format!(
        "{open}{separator}\n  \"calibration\": {calibration}\n}}"
    ))
}

/// Splits a model file's text into the method's own text and its calibration, if it has one.
///
/// # Errors
/// A sentence when the calibration is not valid.
pub(super) fn split_calibration(text: &str) -> Result<(String, Option<Calibration>), String> {
    let Ok(serde_json::Value::Object(mut map)) = serde_json::from_str::<serde_json::Value>(text)
    else {
        return Ok((text.to_string(), None));
    };
    let Some(value) = map.remove("calibration") else {
        return Ok((text.to_string(), None));
    };
    let calibration: Calibration =
        serde_json::from_value(value).map_err(|e| format!("`calibration`: {e}"))?;
    calibration.check()?;
    let rest =
        serde_json::to_string_pretty(&serde_json::Value::Object(map)).map_err(|e| e.to_string())?;
    Ok((rest, Some(calibration)))
}

impl Calibration {
    /// Checks a calibration read from a file: finite, positive where it must be.
    ///
    /// # Errors
    /// A sentence naming the field.
    pub fn check(&self) -> Result<(), String> {
        let positive = |name: &str, v: f64| {
            (v.is_finite() && v > 0.0)
                .then_some(())
                .ok_or_else(|| format!("`calibration.{name}` is {v}: it must be a positive number"))
        };
        within(self.coverage, 0.5..=0.999).map_err(|e| format!("`calibration.coverage`: {e}"))?;
        if let Some(q) = self.radius {
            positive("radius", q)?;
        }
        positive("floor", self.floor)?;
        if let Some(cells) = &self.cell_radii {
            cells.check()?;
        }
        positive("max_region_area", self.max_region_area)?;
        for (name, limit) in [
            ("render_limit_px", self.render_limit_px),
            ("stray_limit_px", self.stray_limit_px),
        ] {
            if let Some(limit) = limit {
                (limit >= 0.0).then_some(()).ok_or_else(|| {
                    format!("`calibration.{name}` is {limit}: it must be a number of pixels")
                })?;
            }
        }
        if let Some(limit) = self.detection_limit {
            (!limit.is_nan())
                .then_some(())
                .ok_or("`calibration.detection_limit` is not a number")?;
        }
        let w = &self.workspace;
        let edges = [w.x_min, w.x_max, w.y_min, w.y_max];
        if !(edges.iter().all(|v| v.is_finite()) && w.x_min < w.x_max && w.y_min < w.y_max) {
            return Err("`calibration.workspace` is not a finite rectangle".into());
        }
        // A rectangle beyond the rig's ±10 m would give regions of infinite area.
        for corner in [[w.x_min, w.y_min], [w.x_max, w.y_max]] {
            crate::planar::check_position(corner, None)
                .map_err(|e| format!("`calibration.workspace`: {e}"))?;
        }
        Ok(())
    }
}

/// The calibrated method seen through its wrapper: `estimator` itself otherwise.
pub fn underlying(estimator: &dyn PoseEstimator) -> &dyn PoseEstimator {
    match (estimator as &dyn std::any::Any).downcast_ref::<Calibrated>() {
        Some(calibrated) => calibrated.inner(),
        None => estimator,
    }
}

#[cfg(test)]
#[path = "calibration_tests.rs"]
mod tests;
