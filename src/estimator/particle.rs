//! The filter baseline (issue 17): a bootstrap particle filter over the pose, with the
//! continuous tracker's Gaussian-process feature maps as its likelihood and the temporal
//! evidential tracker's motion model.
//!
//! - Likelihood of feature i at pose q: (1 − ε)·N(fᵢ; μᵢ(q), σᵢ²) + ε/Wᵢ, with μᵢ the learned
//!   map, σᵢ its validation residual and Wᵢ the width of its range over the samples: the small
//!   uniform share ε (`outlier_share`) is what a practitioner adds so that one wild feature
//!   cannot wipe out every particle.
//! - Motion: a share `velocity_share` of the particles moves by the velocity of the line
//!   through the last estimates (`temporal.velocity_frames`), then every particle moves to a
//!   uniform point of the disc of radius `max_speed` × Δt, kept inside the sample poses'
//!   bounding box.
//! - Systematic resampling when the effective sample size falls below half the particles.
//! - Estimate: the weighted mean; uncertainty: the radius holding 90 % of the weight; a frame
//!   without a usable feature is the prediction (`predicted`).
//! - Seeded: every motion starts from the model's seed, so a scenario and its seed give the
//!   same estimates.

use std::path::Path;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::inputs::frame_values;
use super::motion::VelocityLine;
use super::{
    Continuous, ContinuousSettings, EstimateFlags, EstimatorError, MotionTracker, PoseEstimate,
    PoseEstimator, TemporalSettings, TrainingSet,
};
use crate::features::FeatureConfig;
use crate::model_file::{self, corrupted, Stamp};
use crate::range::within;

/// The particle filter's own settings (`[particle_filter]` in scenarios).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ParticleSettings {
    /// Number of particles.
    pub particles: usize,
    /// Share ε of each feature's likelihood that is uniform over its range.
    pub outlier_share: f64,
    /// Mixed with the training seed.
    pub seed: u64,
    /// Share of the particles moved by the velocity line at each frame; the others keep their
    /// position (before the reach). Half by default: the filter has no conflict check to keep
    /// occluded frames out of the line, and followed by every particle a wrong line loses the
    /// pose (README, "Tracking over time").
    pub velocity_share: f64,
}

impl Default for ParticleSettings {
    fn default() -> Self {
        Self {
            particles: 2000,
            outlier_share: 0.05,
            seed: 0,
            velocity_share: 0.5,
        }
    }
}

impl ParticleSettings {
    /// Checks the ranges.
    ///
    /// # Errors
    /// [`EstimatorError::Training`] naming the field.
    pub fn check(&self) -> Result<(), EstimatorError> {
        within(self.particles, 1..=1_000_000)
            .map_err(|e| EstimatorError::Training(format!("`particle_filter.particles`: {e}")))?;
        within(self.outlier_share, 0.0..=1.0).map_err(|e| {
            EstimatorError::Training(format!("`particle_filter.outlier_share`: {e}"))
        })?;
        within(self.velocity_share, 0.0..=1.0).map_err(|e| {
            EstimatorError::Training(format!("`particle_filter.velocity_share`: {e}"))
        })?;
        Ok(())
    }
}

/// The particle filter, fitted: the feature maps and noise scales of a fitted continuous
/// tracker, with the filter's settings.
#[derive(Debug, Clone)]
pub struct ParticleFilter {
    maps: Continuous,
    file: ParticleFile,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct ParticleFile {
    #[serde(flatten)]
    stamp: Stamp,
    settings: ParticleSettings,
    /// The motion model's reach per second (mm/s), `temporal.max_speed`.
    max_speed: f64,
    /// The estimates the velocity line is fitted through, `temporal.velocity_frames`.
    velocity_frames: usize,
    /// The seed every motion starts from.
    seed: u64,
    /// The continuous tracker's model file text: the feature maps and noise scales.
    feature_maps: String,
}

impl ParticleFilter {
    /// Version of the model file format this build writes and reads.
    pub const FORMAT_VERSION: u32 = 2;
    /// The `method` of its model files.
    pub const METHOD: &'static str = "particle_filter";

    /// Fits the feature maps (as the continuous tracker does) on `data`.
    ///
    /// # Errors
    /// Invalid settings; the continuous tracker's fitting errors.
    pub fn fit(
        settings: &ParticleSettings,
        motion: &TemporalSettings,
        continuous: &ContinuousSettings,
        data: &TrainingSet,
    ) -> Result<Self, EstimatorError> {
        Self::from_maps(
            settings,
            motion,
            Continuous::fit(continuous, data)?,
            data.provenance.seed,
        )
    }

    /// The filter on already fitted feature maps; `seed` is the training seed.
    ///
    /// # Errors
    /// Invalid settings.
    pub fn from_maps(
        settings: &ParticleSettings,
        motion: &TemporalSettings,
        maps: Continuous,
        seed: u64,
    ) -> Result<Self, EstimatorError> {
        settings.check()?;
        motion.check()?;
        let file = ParticleFile {
            stamp: Stamp::new(Self::METHOD, Self::FORMAT_VERSION),
            settings: settings.clone(),
            max_speed: motion.max_speed,
            velocity_frames: motion.velocity_frames,
            seed: crate::seed::derive(seed, &format!("particle_filter/{}", settings.seed)),
            feature_maps: maps.to_json()?,
        };
        Ok(Self { maps, file })
    }

    /// Reads a model file's text.
    ///
    /// # Errors
    /// [`EstimatorError::File`] naming what is wrong.
    pub fn from_json(text: &str) -> Result<Self, EstimatorError> {
        let file: ParticleFile = model_file::parse(text, Self::METHOD, Self::FORMAT_VERSION)?;
        file.settings
            .check()
            .and_then(|()| {
                TemporalSettings {
                    max_speed: file.max_speed,
                    ..TemporalSettings::default()
                }
                .check()
            })
            .map_err(|e| corrupted(format!("settings: {e}")))?;
        let maps = Continuous::from_json(&file.feature_maps).map_err(|e| match e {
            e @ (EstimatorError::Model(_) | EstimatorError::File(_)) => {
                corrupted(format!("feature_maps: {e}")).into()
            }
            other => other,
        })?;
        Ok(Self { maps, file })
    }

    /// Reads a model file.
    ///
    /// # Errors
    /// As [`ParticleFilter::from_json`], naming the path.
    pub fn load(path: &Path) -> Result<Self, EstimatorError> {
        Ok(model_file::load(path, Self::from_json)?)
    }

    /// log p(features | q) with the frame's usable `values`.
    fn log_likelihood(&self, values: &[Option<f64>], q: [f64; 2], mapped: &mut [f64]) -> f64 {
        self.maps.feature_map_into(q, mapped);
        let ranges = self.maps.feature_ranges();
        let scales = self.maps.residual_scales();
        let eps = self.file.settings.outlier_share;
        let mut total = 0.0;
        for (i, v) in values.iter().enumerate() {
            let (Some(v), sigma) = (v, scales[i]) else {
                continue;
            };
            let width = (ranges[i].1 - ranges[i].0).max(f64::MIN_POSITIVE);
            let z = (v - mapped[i]) / sigma;
            let gaussian = (-0.5 * z * z).exp() / (sigma * (2.0 * std::f64::consts::PI).sqrt());
            total += ((1.0 - eps) * gaussian + eps / width)
                .max(f64::MIN_POSITIVE)
                .ln();
        }
        total
    }
}

impl PoseEstimator for ParticleFilter {
    fn method(&self) -> &'static str {
        Self::METHOD
    }

    fn feature_names(&self) -> &[String] {
        self.maps.feature_names()
    }

    fn feature_config(&self) -> Option<&FeatureConfig> {
        self.maps.feature_config()
    }

    /// A frame alone: the filter's first frame (particles spread over the workspace).
    fn estimate(&self, features: &[Option<f64>]) -> Result<PoseEstimate, EstimatorError> {
        self.start_motion().next(0.0, features)
    }

    fn to_json(&self) -> Result<String, EstimatorError> {
        Ok(model_file::to_text(&self.file)?)
    }

    fn start_motion(&self) -> Box<dyn MotionTracker + '_> {
        let (lo, hi) = self.maps.sample_bounds();
        let mut rng = ChaCha8Rng::seed_from_u64(self.file.seed);
        let n = self.file.settings.particles;
        let particles = (0..n)
            .map(|_| {
                [
                    lo[0] + rng.random::<f64>() * (hi[0] - lo[0]),
                    lo[1] + rng.random::<f64>() * (hi[1] - lo[1]),
                ]
            })
            .collect();
        Box::new(FilterMotion {
            filter: self,
            rng,
            particles,
            weights: vec![1.0 / n as f64; n],
            last: None,
            line: VelocityLine::new(self.file.velocity_frames),
        })
    }
}

/// One motion under the particle filter.
struct FilterMotion<'a> {
    filter: &'a ParticleFilter,
    rng: ChaCha8Rng,
    particles: Vec<[f64; 2]>,
    /// Normalised.
    weights: Vec<f64>,
    last: Option<f64>,
    /// The line through the last measured estimates.
    line: VelocityLine,
}

impl FilterMotion<'_> {
    /// Moves every particle by `shift`, then to a uniform point of the disc of radius `reach`.
    fn predict(&mut self, reach: f64, shift: [f64; 2]) {
        if reach <= 0.0 && shift == [0.0; 2] {
            return;
        }
        let (lo, hi) = self.filter.maps.sample_bounds();
        for p in &mut self.particles {
            // Uniform in the disc: radius ∝ √u.
            let r = reach * self.rng.random::<f64>().sqrt();
            let angle = std::f64::consts::TAU * self.rng.random::<f64>();
            let moves = self.rng.random::<f64>() < self.filter.file.settings.velocity_share;
            let s = if moves { shift } else { [0.0; 2] };
            p[0] = (p[0] + s[0] + r * angle.cos()).clamp(lo[0], hi[0]);
            p[1] = (p[1] + s[1] + r * angle.sin()).clamp(lo[1], hi[1]);
        }
    }

    /// Weights by the frame's likelihood; −ln of the predictive likelihood (the detection
    /// score), or `None` when every particle's likelihood underflows (the weights then stay).
    fn update(&mut self, values: &[Option<f64>]) -> Option<f64> {
        let dim = self.filter.maps.feature_names().len();
        let mut mapped = vec![0.0; dim];
        let logs: Vec<f64> = self
            .particles
            .iter()
            .map(|&q| self.filter.log_likelihood(values, q, &mut mapped))
            .collect();
        let max = logs.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        if !max.is_finite() {
            return None;
        }
        let mut total = 0.0;
        for (w, l) in self.weights.iter_mut().zip(&logs) {
            *w *= (l - max).exp();
            total += *w;
        }
        if !(total > 0.0 && total.is_finite()) {
            return None;
        }
        self.weights.iter_mut().for_each(|w| *w /= total);
        Some(-(total.ln() + max))
    }

    fn resample_if_degenerate(&mut self) {
        let n = self.particles.len();
        let ess = 1.0 / self.weights.iter().map(|w| w * w).sum::<f64>();
        if ess >= 0.5 * n as f64 {
            return;
        }
        let step = 1.0 / n as f64;
        let mut u = self.rng.random::<f64>() * step;
        let mut cumulative = self.weights[0];
        let mut i = 0;
        let mut resampled = Vec::with_capacity(n);
        for _ in 0..n {
            while u > cumulative && i + 1 < n {
                i += 1;
                cumulative += self.weights[i];
            }
            resampled.push(self.particles[i]);
            u += step;
        }
        self.particles = resampled;
        self.weights = vec![step; n];
    }

    /// Weighted mean and the radius holding 90 % of the weight.
    fn estimate(&self) -> ([f64; 2], f64) {
        let mut mean = [0.0; 2];
        for (p, w) in self.particles.iter().zip(&self.weights) {
            mean[0] += w * p[0];
            mean[1] += w * p[1];
        }
        let mut by_distance: Vec<(f64, f64)> = self
            .particles
            .iter()
            .zip(&self.weights)
            .map(|(p, &w)| ((p[0] - mean[0]).hypot(p[1] - mean[1]), w))
            .collect();
        by_distance.sort_by(|a, b| a.0.total_cmp(&b.0));
        let mut held = 0.0;
        let radius = by_distance
            .iter()
            .find(|(_, w)| {
                held += w;
                held >= 0.9
            })
            .map_or(0.0, |(d, _)| *d);
        (mean, radius)
    }

    /// The particles' weighted second moments about `mean` (mm²).
    fn covariance(&self, mean: [f64; 2]) -> [[f64; 2]; 2] {
        let mut moments = [[0.0; 2]; 2];
        for (p, w) in self.particles.iter().zip(&self.weights) {
            let d = [p[0] - mean[0], p[1] - mean[1]];
            moments[0][0] += w * d[0] * d[0];
            moments[0][1] += w * d[0] * d[1];
            moments[1][1] += w * d[1] * d[1];
        }
        moments[1][0] = moments[0][1];
        moments
    }
}

impl MotionTracker for FilterMotion<'_> {
    fn next(
        &mut self,
        time: f64,
        features: &[Option<f64>],
    ) -> Result<PoseEstimate, EstimatorError> {
        let names = self.filter.maps.feature_names().len();
        let (values, missing) = frame_values(features, names)?;
        let scales = self.filter.maps.residual_scales();
        let values: Vec<Option<f64>> = (values.into_iter().enumerate())
            .map(|(i, v)| v.filter(|_| scales[i] > 0.0))
            .collect();
        if let Some(last) = self.last {
            let interval = (time - last).max(0.0);
            let shift = self.line.shift(interval);
            self.predict(self.filter.file.max_speed * interval, shift);
        }
        self.last = Some(time);
        let usable = values.iter().any(Option::is_some);
        let score = if usable { self.update(&values) } else { None };
        let (pose, radius) = self.estimate();
        let covariance = self.covariance(pose);
        self.line.remember(time, score.map(|_| pose), false);
        self.resample_if_degenerate();
        Ok(PoseEstimate {
            pose: Some(pose),
            uncertainty_radius: Some(radius),
            group: None,
            conflict_level: None,
            detection_score: score.or(usable.then_some(f64::INFINITY)),
            region: None,
            covariance: Some(covariance),
            flags: EstimateFlags {
                missing,
                predicted: score.is_none(),
                ..EstimateFlags::default()
            },
        })
    }
}

/// The scenario checks of the particle filter: its section, the `[temporal]` motion model and
/// the continuous tracker's (its feature maps are fitted with those settings).
pub(crate) fn check_settings(
    settings: &super::EstimatorSettings,
    context: &super::SettingsContext,
) -> Result<(), String> {
    super::motion::check_temporal(&settings.temporal, None)?;
    settings
        .particle_filter
        .check()
        .map_err(|e| format!("[particle_filter]: {e}"))?;
    super::continuous::check_settings(settings, context)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn settings_are_checked() {
        let bad = |s: ParticleSettings| s.check().unwrap_err().to_string();
        let default = ParticleSettings::default;
        assert!(bad(ParticleSettings {
            particles: 0,
            ..default()
        })
        .contains("particle_filter.particles"));
        assert!(bad(ParticleSettings {
            outlier_share: 1.5,
            ..default()
        })
        .contains("particle_filter.outlier_share"));
        assert!(bad(ParticleSettings {
            velocity_share: -0.1,
            ..default()
        })
        .contains("particle_filter.velocity_share"));
        assert!(default().check().is_ok());
    }
}
