//! The continuous evidential tracker: the paper's conflict graph, selection policies and learned
//! threshold on features that are never cut into states.
//!
//! Fitting learns each feature as a smooth function of the pose over the sample trajectory (a
//! Gaussian-process surrogate, [`surrogate`]), its noise scale σ_i from held-out residuals (the
//! validation motion's, else the samples' leave-one-out residuals), then on the validation
//! motion the conflict threshold (§4.3, any [`ThresholdRule`]) and the plausibility level whose
//! region covers the chosen share of validation poses. Per frame ([`frame`]), feature i's value
//! y_i becomes the likelihood-based consonant belief function on poses with contour
//! pl_i(q) = exp(−½ ((y_i − f_i(q))/σ_i)²) (Shafer's construction; its height is below 1 when no
//! pose explains the value, so a value outside a feature's range conflicts even alone). Under
//! Dempster's rule contours multiply, so a group's combined contour is Π pl_i and its level of
//! conflict K_G = −log sup_q Π pl_i(q) = ½ min_q χ²_G(q), taken over the cells of the grid the
//! maps are tabulated on ([`grid_levels`]): it grows exactly as features are added, so groups
//! are found by the same pruned search as the paper's tracker. The estimate is the pose of highest
//! combined plausibility (Levenberg–Marquardt from the grid's minimum); the plausibility region
//! {q : Pl(q)/Pl(q̂) ≥ α} is reported as the ellipse of the contour's curvature there.
//!
//! Behaviour worth knowing: sample rows with a missing value are dropped; a frame's missing or
//! non-finite features take no part; at most [`MAX_CONTINUOUS_FEATURES`] features (groups are
//! 64-bit masks).
//! A frame whose chosen group cannot fix a pose (one feature: a level curve, not a point) has no
//! bounded region (`region` and `uncertainty_radius` are `None`).

mod checks;
pub(crate) use checks::{check_settings, check_temporal_settings};
mod file;
mod frame;
mod grid_levels;
mod grid_past;
mod grid_share;
mod rules;
mod surrogate;
mod temporal;

use crate::range::within;

use serde::{Deserialize, Serialize};

pub(crate) use surrogate::grid_nodes;
pub use surrogate::SurrogateHyperparameters;

/// The default threshold's factor over the largest validation level. Its noise scales are fitted
/// on the same validation frames, so those levels run low: held-out clean motions reached 2.4×
/// their largest (docs/results.md, "Faults"), against 1.8× for the paper's tracker, so 3 leaves a margin.
pub const CONTINUOUS_MAX_FACTOR: f64 = 3.0;

/// Largest number of features the continuous tracker takes: groups are 64-bit masks (over time,
/// the carried belief is one more bit, so 63).
pub const MAX_CONTINUOUS_FEATURES: usize = 64;

use super::inputs::{check_training, frame_values, training_header};
use super::samples::kept_samples;
use super::{
    EstimateFlags, EstimatorError, PlausibilityRegion, PoseEstimate, PoseEstimator, TrainingSet,
};
use crate::evidence::{ConflictLevel, Rule};
use crate::features::FeatureConfig;
use crate::model::ModelError;
use crate::model_file::{self, Provenance};
use crate::planar::{bounding_box, distance};
use crate::standardisation::Standardisation;
use crate::track::{quantile_threshold, Combine, Discount, SelectionPolicy, ThresholdRule};
use file::ContinuousFile;
use frame::{members, Frame};
use surrogate::{fit_hyperparameters, Surrogate};
pub use temporal::ContinuousTemporal;

/// How the continuous evidential tracker is fitted and run (`[continuous]` in a scenario).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ContinuousSettings {
    /// Group selection policy (§4.2), as the paper's tracker has it.
    pub selection: SelectionPolicy,
    /// Conflict threshold when it is not learned (`"inf"`: every group is eligible).
    pub conflict_threshold: ConflictLevel,
    /// Learn the threshold on the validation motion (§4.3); ignored without one.
    pub learn_threshold: bool,
    /// How it is learned (default: `CONTINUOUS_MAX_FACTOR` × the largest validation level;
    /// the 0.99 quantile left 10 of 200 clean frames without a feature).
    pub threshold_rule: ThresholdRule,
    /// Share of poses the plausibility region should cover, in (0, 1): the region's level is
    /// the one that covers this share of the validation poses (without a validation motion, the
    /// χ²₂ quantile, Wilks' asymptotic value).
    pub region_share: f64,
    /// At most this many samples (evenly spaced) fit the surrogate's hyperparameters.
    pub max_fit_samples: usize,
    /// Most optimiser iterations per start of the hyperparameter fit.
    pub iterations: usize,
    /// Spacing (mm) of the grid the feature maps are tabulated on and interpolated from (at
    /// most 1,000 nodes per axis).
    pub grid_spacing: f64,
    /// Every usable feature, or the selected group (default); left out of files when default.
    #[serde(skip_serializing_if = "rules::is_default")]
    pub combine: Combine,
    /// `dempster` (default) or `cautious` ([`rules`]: the rules that make sense for consonant contours).
    #[serde(skip_serializing_if = "rules::is_default")]
    pub rule: Rule,
    /// Shafer's discounting of each feature before the rule: none, learned or a reliability.
    #[serde(skip_serializing_if = "rules::is_default")]
    pub discount: Discount,
}

impl Default for ContinuousSettings {
    fn default() -> Self {
        Self {
            selection: SelectionPolicy::LargestSubset,
            conflict_threshold: ConflictLevel::Infinite,
            learn_threshold: false,
            threshold_rule: ThresholdRule::ValidationMax(CONTINUOUS_MAX_FACTOR),
            region_share: 0.9,
            max_fit_samples: 200,
            iterations: 100,
            grid_spacing: 0.25,
            combine: Combine::Selected,
            rule: Rule::Dempster,
            discount: Discount::None,
        }
    }
}

impl ContinuousSettings {
    /// Checks the settings on their own.
    ///
    /// # Errors
    /// [`ModelError::Settings`] naming the field (`continuous.…`) that is out of range.
    pub fn check(&self) -> Result<(), EstimatorError> {
        let bad = |field, reason: &str| {
            Err(ModelError::Settings {
                field,
                reason: reason.into(),
            }
            .into())
        };
        if !(self.region_share > 0.0 && self.region_share < 1.0) {
            return bad(
                "continuous.region_share",
                "must lie strictly between 0 and 1",
            );
        }
        within(self.grid_spacing, 0.02..=10.0).map_err(|reason| ModelError::Settings {
            field: "continuous.grid_spacing",
            reason: format!("{reason} mm"),
        })?;
        for (field, value, range) in [
            ("continuous.max_fit_samples", self.max_fit_samples, 2..=5000),
            ("continuous.iterations", self.iterations, 0..=10_000),
        ] {
            within(value, range).map_err(|reason| ModelError::Settings { field, reason })?;
        }
        if !self.conflict_threshold.is_valid() {
            return bad(
                "continuous.conflict_threshold",
                "must be a number ≥ 0 or \"inf\"",
            );
        }
        self.threshold_rule
            .check()
            .map_err(|e| ModelError::Settings {
                field: "continuous.threshold_rule",
                reason: e.to_string(),
            })?;
        rules::check(self)
    }
}

/// The continuous evidential tracker, fitted (see the module documentation).
#[derive(Debug, Clone)]
pub struct Continuous {
    file: ContinuousFile,
    surrogate: Surrogate,
    /// The surrogate at every sample pose (sample-major, one value per feature).
    sample_values: Vec<f64>,
    /// Each feature's range over the sample poses.
    ranges: Vec<(f64, f64)>,
    /// The sample poses' bounding box: estimates stay inside.
    bounds: ([f64; 2], [f64; 2]),
    /// Bounds of the maps over blocks of grid nodes, for the group levels.
    blocks: grid_levels::Blocks,
    /// The rule and each feature's reliability.
    fusion: rules::Fusion,
    /// Its maps' hyperparameters, held for later fits of the same maps (`surrogate::share`).
    shared_fits: Vec<std::sync::Arc<surrogate::share::Fitted>>,
}

impl Continuous {
    /// Version of the model file format this build writes and reads.
    pub const FORMAT_VERSION: u32 = 1;
    /// The `method` of its model files.
    pub const METHOD: &'static str = "continuous";

    /// Fits on `data` (see the module documentation).
    ///
    /// # Errors
    /// Invalid settings, more than [`MAX_CONTINUOUS_FEATURES`] features, an inconsistent training set, no
    /// complete sample, or a kernel matrix that stays singular.
    pub fn fit(settings: &ContinuousSettings, data: &TrainingSet) -> Result<Self, EstimatorError> {
        settings.check()?;
        check_training(data)?;
        let dim = data.feature_names.len();
        if dim > MAX_CONTINUOUS_FEATURES {
            return Err(EstimatorError::Training(format!(
                "{dim} features, but the continuous tracker takes at most {MAX_CONTINUOUS_FEATURES}"
            )));
        }
        let (poses, rows) = kept_samples(data, "the continuous tracker")?;
        let pose_standardisation =
            Standardisation::fit(&poses.iter().map(|p| p.to_vec()).collect::<Vec<_>>(), 2);
        let feature_standardisation = Standardisation::fit(&rows, dim);
        let fitted_maps = fit_hyperparameters(
            &pose_standardisation,
            &feature_standardisation,
            &poses,
            &rows,
            settings.max_fit_samples,
            settings.iterations,
        );
        let hyperparameters = (fitted_maps.iter().enumerate())
            .map(|(i, h)| {
                h.as_ref().clone().ok_or_else(|| {
                    EstimatorError::Training(format!(
                        "the continuous tracker's surrogate of `{}` has a singular kernel \
                         matrix at every start",
                        data.feature_names[i]
                    ))
                })
            })
            .collect::<Result<Vec<_>, _>>()?;
        let surrogate = Surrogate::new(
            pose_standardisation.clone(),
            feature_standardisation.clone(),
            &hyperparameters,
            &poses,
            &rows,
            settings.grid_spacing,
            data.validation.is_none(),
        )
        .map_err(EstimatorError::Training)?;
        let (residual_scales, residual_source) = match &data.validation {
            Some(v) => {
                let measured = validation_residuals(&surrogate, v.poses, v.rows, dim)?;
                let missing = measured.iter().position(Option::is_none);
                if let Some(i) = missing {
                    return Err(EstimatorError::Training(format!(
                        "feature `{}` has no value on any validation frame, so its noise scale \
                         cannot be measured: drop the feature or fix the validation motion",
                        data.feature_names[i]
                    )));
                }
                (measured.into_iter().flatten().collect(), "validation")
            }
            None => (
                surrogate.leave_one_out_rms().unwrap_or_default(),
                "leave_one_out",
            ),
        };
        // A residual of exactly 0 (noise-free, perfectly interpolated) would make z infinite.
        let residual_scales = (residual_scales.iter().zip(&feature_standardisation.scales))
            .map(|(&s, &scale): (&f64, &f64)| s.max(1e-9 * scale))
            .collect();
        let file = ContinuousFile {
            header: training_header(Self::METHOD, Self::FORMAT_VERSION, data),
            settings: settings.clone(),
            pose_standardisation,
            feature_standardisation,
            hyperparameters,
            residual_scales,
            residual_source: residual_source.to_string(),
            conflict_threshold: ConflictLevel::Infinite,
            threshold_learned: false,
            region_chi2: wilks_chi2(settings.region_share),
            sample_poses: poses,
            sample_features: rows,
        };
        let mut fitted = Self::assemble(file, surrogate);
        fitted.shared_fits = fitted_maps;
        if let Some(validation) = &data.validation {
            fitted.learn_on_validation(validation.poses, validation.rows, data.missing_penalty)?;
        } else {
            fitted.file.conflict_threshold = settings.conflict_threshold;
        }
        Ok(fitted)
    }

    /// The §4.3 threshold (levels of every usable feature, no threshold, weighted by the
    /// estimation errors or their quantile) and the region level covering `region_share` of the
    /// validation poses under that threshold.
    fn learn_on_validation(
        &mut self,
        poses: &[[f64; 2]],
        rows: &[Vec<Option<f64>>],
        penalty: f64,
    ) -> Result<(), EstimatorError> {
        let settings = self.file.settings.clone();
        if settings.learn_threshold {
            self.file.conflict_threshold = ConflictLevel::Infinite;
            let (mut levels, mut errors) = (Vec::new(), Vec::new());
            for (row, truth) in rows.iter().zip(poses) {
                let estimate = self.estimate(row)?;
                levels.push(estimate.conflict_level.unwrap_or(f64::INFINITY));
                errors.push(estimate.pose.map_or(penalty, |p| distance(p, *truth)));
            }
            self.file.conflict_threshold = settings
                .threshold_rule
                .learn(&levels, &errors)
                .map_err(|e| EstimatorError::Training(format!("learning the threshold: {e}")))?;
            self.file.threshold_learned = true;
        } else {
            self.file.conflict_threshold = settings.conflict_threshold;
        }
        let mut excess = Vec::new();
        for (row, truth) in rows.iter().zip(poses) {
            if let Some(x) = self.region_distance(row, *truth)? {
                excess.push(x);
            }
        }
        if let ConflictLevel::Finite(cut) = quantile_threshold(&excess, settings.region_share) {
            self.file.region_chi2 = cut.max(f64::MIN_POSITIVE);
        }
        Ok(())
    }

    /// How far `truth` lies from the frame's estimate in the metric of the combined contour's
    /// curvature there, (q − q̂)ᵀ JᵀJ (q − q̂): the truth is inside the region of level α when
    /// this is at most −2 log α. `None` without an estimate or a bounded region.
    fn region_distance(
        &self,
        features: &[Option<f64>],
        truth: [f64; 2],
    ) -> Result<Option<f64>, EstimatorError> {
        let estimate = self.estimate(features)?;
        Ok(estimate
            .region
            .map(|r| self.file.region_chi2 * r.distance(truth)))
    }

    /// The estimator of a fitted state: the same operations whether fitted or loaded.
    fn assemble(file: ContinuousFile, surrogate: Surrogate) -> Self {
        let dim = surrogate.dim();
        let mut sample_values = vec![0.0; file.sample_poses.len() * dim];
        for (out, p) in sample_values.chunks_exact_mut(dim).zip(&file.sample_poses) {
            surrogate.eval(*p, out, None);
        }
        let ranges = (0..dim)
            .map(|i| {
                let column = sample_values.chunks_exact(dim).map(|v| v[i]);
                column.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), x| {
                    (lo.min(x), hi.max(x))
                })
            })
            .collect();
        let bounds = bounding_box(&file.sample_poses);
        let blocks = grid_levels::Blocks::new(surrogate.grid(), dim);
        let fusion = rules::Fusion::new(&file, &surrogate);
        Self {
            file,
            surrogate,
            sample_values,
            ranges,
            bounds,
            blocks,
            fusion,
            shared_fits: Vec::new(),
        }
    }

    /// The same fitted maps recording `provenance` (their fit does not depend on it).
    pub(crate) fn reprovenanced(&self, provenance: &Provenance) -> Self {
        let mut copy = self.clone();
        copy.file.header.provenance = provenance.clone();
        copy
    }

    /// The settings it was fitted with.
    pub fn settings(&self) -> &ContinuousSettings {
        &self.file.settings
    }

    /// The surrogate's hyperparameters, one per feature (standardised units).
    pub fn hyperparameters(&self) -> &[SurrogateHyperparameters] {
        &self.file.hyperparameters
    }

    /// Each feature's noise scale σ_i (raw units).
    pub fn residual_scales(&self) -> &[f64] {
        &self.file.residual_scales
    }

    /// The conflict threshold it applies.
    pub fn threshold(&self) -> ConflictLevel {
        self.file.conflict_threshold
    }

    /// Whether the threshold was learned on a validation motion.
    pub fn threshold_learned(&self) -> bool {
        self.file.threshold_learned
    }

    /// The relative plausibility α the region holds (Pl(q)/Pl(q̂) ≥ α).
    pub fn region_level(&self) -> f64 {
        (-0.5 * self.file.region_chi2).exp()
    }

    /// The sample poses the surrogate was fitted on (mm).
    pub fn sample_poses(&self) -> &[[f64; 2]] {
        &self.file.sample_poses
    }

    /// Every feature's learned value at pose `q` (mm).
    pub fn feature_map(&self, q: [f64; 2]) -> Vec<f64> {
        let mut values = vec![0.0; self.surrogate.dim()];
        self.surrogate.eval(q, &mut values, None);
        values
    }

    /// [`Continuous::feature_map`] into `out` (one value per feature), without allocating.
    pub(crate) fn feature_map_into(&self, q: [f64; 2], out: &mut [f64]) {
        self.surrogate.eval(q, out, None);
    }

    /// Every feature's learned slope (∂f_i/∂x, ∂f_i/∂y) at pose `q` into `jacobian`, the
    /// values into `values`: the information limit's G (`crate::information`).
    pub fn feature_slopes_into(&self, q: [f64; 2], values: &mut [f64], jacobian: &mut [[f64; 2]]) {
        self.surrogate.eval(q, values, Some(jacobian));
    }

    /// Each feature's range over the sample poses.
    pub(crate) fn feature_ranges(&self) -> &[(f64, f64)] {
        &self.ranges
    }

    /// The sample poses' bounding box (lowest, highest corner).
    pub(crate) fn sample_bounds(&self) -> ([f64; 2], [f64; 2]) {
        self.bounds
    }

    /// The combined contour of the features in `group` (indices) at pose `q`, relative to its
    /// height over the poses: Pl(q)/sup Pl. `None` when a named feature is missing in the frame.
    ///
    /// # Errors
    /// [`EstimatorError::FeatureCount`].
    pub fn relative_plausibility(
        &self,
        features: &[Option<f64>],
        group: &[usize],
        q: [f64; 2],
    ) -> Result<Option<f64>, EstimatorError> {
        Ok(self.group_frame(features, group)?.map(|(mut frame, mask)| {
            let best = frame.fit(mask).chi2;
            (-0.5 * (frame.chi2_of(mask, q) - best)).exp()
        }))
    }

    /// Level of conflict of the features in `group` (indices) in this frame, ½ min_q χ² over
    /// the grid's cells (the level the selection uses); `None` when a named feature is missing.
    ///
    /// # Errors
    /// [`EstimatorError::FeatureCount`].
    pub fn group_level(
        &self,
        features: &[Option<f64>],
        group: &[usize],
    ) -> Result<Option<f64>, EstimatorError> {
        Ok(self
            .group_frame(features, group)?
            .map(|(mut frame, mask)| frame.grid_level(mask, f64::INFINITY).value))
    }

    /// The frame of `features` and the mask of `group`; `None` when the group is empty or a
    /// named feature is not usable in the frame.
    fn group_frame(
        &self,
        features: &[Option<f64>],
        group: &[usize],
    ) -> Result<Option<(Frame<'_>, crate::track::GroupMask)>, EstimatorError> {
        let (values, _) = frame_values(features, self.file.header.feature_names.len())?;
        let frame = Frame::new(self, self.usable(values));
        let mask = group
            .iter()
            .fold(0, |m: crate::track::GroupMask, &i| m | 1 << i.min(63));
        let known = group
            .iter()
            .all(|&i| i < self.file.header.feature_names.len());
        Ok((known && !group.is_empty() && mask & !frame.usable_mask == 0).then_some((frame, mask)))
    }

    /// The frame's values a feature with a usable noise scale can take part with.
    fn usable(&self, values: Vec<Option<f64>>) -> Vec<Option<f64>> {
        (values.into_iter().enumerate())
            .map(|(i, v)| v.filter(|_| self.file.residual_scales[i] > 0.0))
            .collect()
    }
}

impl PoseEstimator for Continuous {
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
        let (values, missing) = frame_values(features, self.file.header.feature_names.len())?;
        let mut frame = Frame::new(self, self.usable(values));
        let usable = frame.usable_mask;
        let mut estimate = PoseEstimate {
            flags: EstimateFlags {
                missing,
                ..EstimateFlags::default()
            },
            ..PoseEstimate::default()
        };
        if usable == 0 {
            return Ok(estimate);
        }
        let selection = frame.select();
        let Some((level, group)) = selection.chosen else {
            return Ok(estimate);
        };
        let fit = frame.fit(group);
        let full = if group == usable {
            level
        } else {
            frame.grid_level(usable, f64::INFINITY).value
        };
        // One feature fixes a level curve, not a point: no bounded region.
        let region = (group.count_ones() >= 2)
            .then(|| {
                PlausibilityRegion::from_curvature(
                    fit.pose,
                    fit.curvature,
                    self.file.region_chi2,
                    self.region_level(),
                )
            })
            .flatten();
        estimate.pose = Some(fit.pose);
        estimate.covariance = super::laplace_covariance(fit.curvature);
        estimate.uncertainty_radius = region.as_ref().map(|r| r.semi_major);
        estimate.region = region;
        estimate.group = Some(members(group).collect());
        estimate.conflict_level = Some(level);
        estimate.detection_score = Some(full);
        estimate.flags.excluded = members(usable & !group).collect();
        estimate.flags.fallback = selection.fallback;
        Ok(estimate)
    }

    fn to_json(&self) -> Result<String, EstimatorError> {
        Ok(model_file::to_text(&self.file)?)
    }

    fn with_provenance(&self, provenance: &Provenance) -> Option<Box<dyn PoseEstimator>> {
        Some(Box::new(self.reprovenanced(provenance)))
    }
}

/// σ_i: the RMS over the validation frames of y_i − f_i(true pose) (frames where the feature is
/// present and finite); `None` for a feature present in no frame.
fn validation_residuals(
    surrogate: &Surrogate,
    poses: &[[f64; 2]],
    rows: &[Vec<Option<f64>>],
    dim: usize,
) -> Result<Vec<Option<f64>>, EstimatorError> {
    let mut sums = vec![(0.0, 0usize); dim];
    let mut f = vec![0.0; dim];
    for (row, p) in rows.iter().zip(poses) {
        if row.len() != dim {
            return Err(EstimatorError::Training(format!(
                "a validation row has {} values for {dim} features",
                row.len()
            )));
        }
        surrogate.eval(*p, &mut f, None);
        for i in 0..dim {
            if let Some(y) = row[i].filter(|y| y.is_finite()) {
                sums[i].0 += (y - f[i]) * (y - f[i]);
                sums[i].1 += 1;
            }
        }
    }
    Ok(sums
        .iter()
        .map(|&(s, n)| (n > 0).then(|| (s / n as f64).sqrt()))
        .collect())
}

/// The χ²₂ quantile of `share`: −2 ln(1 − share) (Wilks: the likelihood-ratio region at that
/// level covers `share` of poses asymptotically).
fn wilks_chi2(share: f64) -> f64 {
    -2.0 * (1.0 - share).ln()
}
