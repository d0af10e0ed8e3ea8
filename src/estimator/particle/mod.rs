//! The filter baseline (issue 17): a bootstrap particle filter over the pose, with the
//! continuous tracker's Gaussian-process feature maps as its likelihood and the temporal
//! trackers' velocity line as its motion model.
//!
//! - Likelihood of feature i at pose q: (1 − ε)·N(fᵢ; μᵢ(q), σᵢ²) + ε/Wᵢ, with μᵢ the learned
//!   map, σᵢ its validation residual and Wᵢ the width of its range over the samples: the small
//!   uniform share ε (`outlier_share`) is what a practitioner adds so that one wild feature
//!   cannot wipe out every particle.
//! - Motion: a share `velocity_share` of the particles moves by the velocity of the line
//!   through the last estimates (`temporal.velocity_frames`) and a Gaussian step of σ·Δt per
//!   axis (`motion_noise` σ in mm/s); the others move to a uniform point of the disc of radius
//!   `temporal.max_speed` × Δt (the reach), so a pose that leaves the line is found again.
//!   Until there is a line, σ is at least half the reach. Particles stay inside the sample
//!   poses' bounding box.
//! - Recovery ([`recover`]): a share `recovery_share` of the particles is drawn about the
//!   frame's own estimate (the maps' single-frame fit) and every weight is multiplied by the
//!   predicted density over the mixture's, so that after struck frames the cloud finds the
//!   pose again within a frame.
//! - Detection score ([`FilterScore`]): how well the posterior explains the frame (its
//!   expected log-likelihood), or the filter's own predictive likelihood (the corrected
//!   weights' sum); either is the filter's, so a frame its posterior misses is not scored by
//!   the particles drawn about a right guess.
//! - σ and ε are learned on the validation motion as the temporal trackers learn α
//!   ([`learn`]), unless given.
//! - Systematic resampling when the effective sample size falls below half the particles.
//! - Estimate: the weighted mean; uncertainty: the radius holding 90 % of the weight; a frame
//!   without a usable feature is the prediction (`predicted`).
//! - Seeded: every motion starts from the model's seed, so a scenario and its seed give the
//!   same estimates, on one thread or two (`motion`, from 5,000 particles).

mod learn;
mod likelihood;
mod motion;
mod pool;
mod predict;
mod radius;
mod recover;

use learn::{DEFAULT_MOTION_NOISE, DEFAULT_OUTLIER_SHARE};

use std::path::Path;

use serde::{Deserialize, Serialize};

use super::{
    Continuous, ContinuousSettings, EstimatorError, MotionTracker, PoseEstimate, PoseEstimator,
    TemporalSettings, TrainingSet,
};
use crate::features::FeatureConfig;
use crate::model_file::{self, corrupted, Stamp};
use crate::range::within;

/// The particle filter's own settings (`[particle_filter]` in scenarios).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ParticleSettings {
    /// Number of particles. 20,000 by default: from there on more leave the error where it is,
    /// while with 2,000 (the default before) the occasional excursion of a few tenths of a
    /// millimetre stayed and the fast circle's error was 3× (docs/results.md, "Tracking over
    /// time"); a frame costs about 6× that of 2,000.
    pub particles: usize,
    /// σ (mm/s) of each particle's Gaussian step per axis (the step is σ·Δt); `None` learns it
    /// on the validation motion (`learn::MOTION_NOISE_CANDIDATES`), or takes
    /// `DEFAULT_MOTION_NOISE` without one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub motion_noise: Option<f64>,
    /// Share ε of each feature's likelihood that is uniform over its range; `None` learns it
    /// on the validation motion (`learn::OUTLIER_SHARE_CANDIDATES`), or takes
    /// `DEFAULT_OUTLIER_SHARE` without one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub outlier_share: Option<f64>,
    /// Mixed with the training seed.
    pub seed: u64,
    /// Share of the particles moved along the velocity line with the Gaussian step at each
    /// frame; the others move to a uniform point within the reach `temporal.max_speed` × Δt.
    /// Half by default: σ is learned on a clean validation motion, and the filter has no
    /// conflict check to keep occluded frames out of the line, so the reach's share is what
    /// finds a pose that left the line (docs/results.md, "Tracking over time").
    pub velocity_share: f64,
    /// Share β of the particles drawn each frame around the frame's own estimate (the maps'
    /// single-frame fit), their weights corrected by the mixture's density so that the
    /// posterior stays the filter's (`recover`): what brings the cloud back after struck
    /// frames. That fit is the continuous tracker's with the `[continuous]` settings, so with
    /// β > 0 `continuous.learn_threshold` (its subset search on struck frames) changes the
    /// filter's numbers; the other methods of a run do not. 0.3 by default (0 turns it off):
    /// with the posterior score it is what keeps the filter answering the clean frames after
    /// struck ones, right (docs/results.md, "Knowing when it is wrong"); it costs a frame about
    /// an eighth more and raises the error on some struck frames (occlusion bursts).
    pub recovery_share: f64,
    /// The detection score a frame is judged by (abstention, risk–coverage): how well the
    /// posterior explains the frame (`posterior`, the default) or how well the prediction
    /// foresaw it (`predictive`). Keep `predictive` with the recovery off: without it the
    /// clean frames after struck ones are a little off, beyond their regions, and only the
    /// prediction's miss says so (docs/results.md, "Knowing when it is wrong").
    pub score: FilterScore,
}

/// The particle filter's detection score of a frame.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FilterScore {
    /// −Σ wᵢ lᵢ, the posterior's expected log-likelihood with a minus (wᵢ the posterior
    /// weights, lᵢ each particle's log-likelihood of the frame): low where the pose the filter
    /// settles on explains the features, whatever the prediction expected. A right estimate
    /// the prediction reached only thinly (the clean frame after a struck one) reads as good.
    #[default]
    Posterior,
    /// −ln Σ wᵢ⁻ Lᵢ, the frame's predictive likelihood with a minus (wᵢ⁻ the predicted
    /// weights): high also where the prediction missed a frame the posterior then explains.
    /// Without the recovery's mixture it is the posterior score plus the posterior's
    /// Kullback–Leibler divergence from the prediction.
    Predictive,
}

impl Default for ParticleSettings {
    fn default() -> Self {
        Self {
            particles: 20_000,
            motion_noise: None,
            outlier_share: None,
            seed: 0,
            velocity_share: 0.5,
            recovery_share: 0.3,
            score: FilterScore::Posterior,
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
        if let Some(sigma) = self.motion_noise {
            check_motion_noise(sigma).map_err(|e| {
                EstimatorError::Training(format!("`particle_filter.motion_noise`: {e}"))
            })?;
        }
        if let Some(eps) = self.outlier_share {
            within(eps, 0.0..=1.0).map_err(|e| {
                EstimatorError::Training(format!("`particle_filter.outlier_share`: {e}"))
            })?;
        }
        within(self.velocity_share, 0.0..=1.0).map_err(|e| {
            EstimatorError::Training(format!("`particle_filter.velocity_share`: {e}"))
        })?;
        // Below 1: the predicted particles must keep a share.
        within(self.recovery_share, 0.0..=0.9).map_err(|e| {
            EstimatorError::Training(format!("`particle_filter.recovery_share`: {e}"))
        })?;
        Ok(())
    }
}

/// σ must be a finite speed ≥ 0 below 10 m/s (far beyond any workspace crossing per frame).
fn check_motion_noise(sigma: f64) -> Result<(), String> {
    within(sigma, 0.0..=10_000.0).map_err(|e| format!("{e} (mm/s)"))
}

/// The particle filter, fitted: the feature maps and noise scales of a fitted continuous
/// tracker, with the filter's settings and its learned σ and ε.
#[derive(Debug, Clone)]
pub struct ParticleFilter {
    maps: Continuous,
    file: ParticleFile,
    /// The worker thread of the last motion on two threads, kept for the next one.
    workers: pool::Spare,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct ParticleFile {
    #[serde(flatten)]
    stamp: Stamp,
    /// The settings as given (`None` where learned).
    settings: ParticleSettings,
    /// σ of the Gaussian step (mm/s) in use, and whether it was learned.
    motion_noise: f64,
    motion_noise_learned: bool,
    /// ε in use, and whether it was learned.
    outlier_share: f64,
    outlier_share_learned: bool,
    /// The motion model's reach per second (mm/s), `temporal.max_speed`: the step's spread
    /// while there is no line yet.
    max_speed: f64,
    /// The estimates the velocity line is fitted through, `temporal.velocity_frames`.
    velocity_frames: usize,
    /// The seed every motion starts from.
    seed: u64,
    /// The continuous tracker's model file text: the feature maps and noise scales.
    feature_maps: String,
}

impl ParticleFilter {
    /// Version of the model file format this build writes and reads (3: σ and ε learned, the
    /// reach `max_speed` no longer used; 4: `recovery_share`, so that a file of 3 is not read
    /// with a recovery it did not have; 5: `score`, and the recovery on by default, so that a
    /// file of 4 without the field is not read with a recovery it did not have).
    pub const FORMAT_VERSION: u32 = 5;
    /// The `method` of its model files.
    pub const METHOD: &'static str = "particle_filter";

    /// Fits the feature maps (as the continuous tracker does) on `data`, then learns σ and ε
    /// on the validation motion where they are not given.
    ///
    /// # Errors
    /// Invalid settings; the continuous tracker's fitting errors.
    pub fn fit(
        settings: &ParticleSettings,
        motion: &TemporalSettings,
        continuous: &ContinuousSettings,
        data: &TrainingSet,
    ) -> Result<Self, EstimatorError> {
        settings.check()?;
        let mut fitted = Self::from_maps(
            settings,
            motion,
            Continuous::fit(continuous, data)?,
            data.provenance.seed,
        )?;
        learn::learn(&mut fitted, data)?;
        Ok(fitted)
    }

    /// The filter on already fitted feature maps, σ and ε as given or their defaults (nothing
    /// learned); `seed` is the training seed.
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
            motion_noise: settings.motion_noise.unwrap_or(DEFAULT_MOTION_NOISE),
            motion_noise_learned: false,
            outlier_share: settings.outlier_share.unwrap_or(DEFAULT_OUTLIER_SHARE),
            outlier_share_learned: false,
            max_speed: motion.max_speed,
            velocity_frames: motion.velocity_frames,
            seed: crate::seed::derive(seed, &format!("particle_filter/{}", settings.seed)),
            feature_maps: maps.to_json()?,
        };
        Ok(Self {
            maps,
            file,
            workers: pool::Spare::default(),
        })
    }

    /// σ of the Gaussian step (mm/s), and whether it was learned.
    pub fn motion_noise(&self) -> (f64, bool) {
        (self.file.motion_noise, self.file.motion_noise_learned)
    }

    /// ε, the uniform share of each feature's likelihood, and whether it was learned.
    pub fn outlier_share(&self) -> (f64, bool) {
        (self.file.outlier_share, self.file.outlier_share_learned)
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
        check_motion_noise(file.motion_noise)
            .map_err(|e| corrupted(format!("motion_noise: {e}")))?;
        within(file.outlier_share, 0.0..=1.0)
            .map_err(|e| corrupted(format!("outlier_share: {e}")))?;
        let maps = Continuous::from_json(&file.feature_maps).map_err(|e| match e {
            e @ (EstimatorError::Model(_) | EstimatorError::File(_)) => {
                corrupted(format!("feature_maps: {e}")).into()
            }
            other => other,
        })?;
        Ok(Self {
            maps,
            file,
            workers: pool::Spare::default(),
        })
    }

    /// Reads a model file.
    ///
    /// # Errors
    /// As [`ParticleFilter::from_json`], naming the path.
    pub fn load(path: &Path) -> Result<Self, EstimatorError> {
        Ok(model_file::load(path, Self::from_json)?)
    }

    /// Per feature, σ·√(2π) and ε/W: the constants of [`ParticleFilter::log_likelihood`].
    fn likelihood_constants(&self) -> (Vec<f64>, Vec<f64>) {
        let eps = self.file.outlier_share;
        let norms = (self.maps.residual_scales().iter())
            .map(|sigma| sigma * (2.0 * std::f64::consts::PI).sqrt())
            .collect();
        let uniforms = (self.maps.feature_ranges().iter())
            .map(|r| eps / (r.1 - r.0).max(f64::MIN_POSITIVE))
            .collect();
        (norms, uniforms)
    }

    /// log p(features | q) with the frame's usable `values`; `constants` from
    /// [`ParticleFilter::likelihood_constants`]: the formula the blocks of `likelihood`
    /// reproduce.
    #[cfg(test)]
    fn log_likelihood(
        &self,
        values: &[Option<f64>],
        q: [f64; 2],
        mapped: &mut [f64],
        (norms, uniforms): (&[f64], &[f64]),
    ) -> f64 {
        self.maps.feature_map_into(q, mapped);
        let scales = self.maps.residual_scales();
        let keep = 1.0 - self.file.outlier_share;
        let mut total = 0.0;
        for (i, v) in values.iter().enumerate() {
            let (Some(v), sigma) = (v, scales[i]) else {
                continue;
            };
            let z = (v - mapped[i]) / sigma;
            let gaussian = (-0.5 * z * z).exp() / norms[i];
            total += (keep * gaussian + uniforms[i]).max(f64::MIN_POSITIVE).ln();
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
        Box::new(motion::FilterMotion::new(self))
    }

    /// Shared only between runs of one seed (the fit key holds it): the filter's own seed is
    /// derived from the training seed.
    fn with_provenance(
        &self,
        provenance: &crate::model_file::Provenance,
    ) -> Option<Box<dyn PoseEstimator>> {
        let maps = self.maps.reprovenanced(provenance);
        let mut file = self.file.clone();
        file.feature_maps = maps.to_json().ok()?;
        Some(Box::new(Self {
            maps,
            file,
            workers: pool::Spare::default(),
        }))
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
    fn the_likelihood_with_its_constants_is_the_direct_formula_bit_for_bit() {
        let maps = crate::estimator::test_maps::fitted_continuous(4, 8, 20, 0.01, false, 2);
        let settings = ParticleSettings {
            outlier_share: Some(0.05),
            ..ParticleSettings::default()
        };
        let filter =
            ParticleFilter::from_maps(&settings, &TemporalSettings::default(), maps, 1).unwrap();
        let (norms, uniforms) = filter.likelihood_constants();
        let mut mapped = vec![0.0; 4];
        // The formula as written before the constants were taken out of the particle loop.
        let direct = |values: &[Option<f64>], q: [f64; 2]| {
            let mapped = filter.maps.feature_map(q);
            let (ranges, scales) = (filter.maps.feature_ranges(), filter.maps.residual_scales());
            let eps = filter.file.outlier_share;
            let mut total = 0.0;
            for (i, v) in values.iter().enumerate() {
                let Some(v) = v else { continue };
                let (sigma, width) = (
                    scales[i],
                    (ranges[i].1 - ranges[i].0).max(f64::MIN_POSITIVE),
                );
                let z = (v - mapped[i]) / sigma;
                let gaussian = (-0.5 * z * z).exp() / (sigma * (2.0 * std::f64::consts::PI).sqrt());
                total += ((1.0 - eps) * gaussian + eps / width)
                    .max(f64::MIN_POSITIVE)
                    .ln();
            }
            total
        };
        for k in 0..50 {
            let q = [-9.0 + 0.37 * k as f64, 40.0 + 0.29 * k as f64];
            let mut values: Vec<Option<f64>> = filter
                .maps
                .feature_map([q[1] - 47.0, q[0] + 47.0])
                .into_iter()
                .map(Some)
                .collect();
            values[k % 4] = None;
            let fast = filter.log_likelihood(&values, q, &mut mapped, (&norms, &uniforms));
            assert_eq!(fast.to_bits(), direct(&values, q).to_bits(), "pose {q:?}");
        }
    }

    #[test]
    fn the_blocked_likelihood_is_the_formula_bit_for_bit() {
        use rand::{Rng, SeedableRng};
        let maps = crate::estimator::test_maps::fitted_continuous(12, 8, 20, 0.01, false, 3);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        // 600 particles: blocks of 256, 256 and 88; some far outside the grid (clamped maps,
        // terms at their floor).
        let particles: Vec<[f64; 2]> = (0..600)
            .map(|k| match k % 10 {
                0 => [rng.random_range(-60.0..60.0), rng.random_range(0.0..100.0)],
                _ => [rng.random_range(-9.5..9.5), rng.random_range(38.0..57.0)],
            })
            .collect();
        // ε = 0: far particles' terms at the formula's floor MIN_POSITIVE; ε = 1: no Gaussian part.
        for (eps, missing) in [(0.05, None), (0.0, Some(3)), (0.2, Some(11)), (1.0, None)] {
            let settings = ParticleSettings {
                outlier_share: Some(eps),
                ..ParticleSettings::default()
            };
            let filter =
                ParticleFilter::from_maps(&settings, &TemporalSettings::default(), maps.clone(), 1)
                    .unwrap();
            let (norms, uniforms) = filter.likelihood_constants();
            let mut values: Vec<Option<f64>> = filter
                .maps
                .feature_map([1.0, 46.0])
                .into_iter()
                .map(Some)
                .collect();
            if let Some(i) = missing {
                values[i] = None;
            }
            let mut frame = likelihood::FrameLikelihood::default();
            let scales = filter.maps.residual_scales();
            frame.prepare(&values, scales, (&norms, &uniforms), eps);
            let mut logs = Vec::new();
            let mut scratch = likelihood::BlockScratch::default();
            frame.log_likelihoods(&filter.maps, &particles, &mut scratch, &mut logs);
            assert_eq!(logs.len(), particles.len());
            let mut mapped = vec![0.0; 12];
            for (&q, fast) in particles.iter().zip(&logs) {
                let direct = filter.log_likelihood(&values, q, &mut mapped, (&norms, &uniforms));
                assert_eq!(fast.to_bits(), direct.to_bits(), "ε {eps} at {q:?}");
            }
        }
    }

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
            outlier_share: Some(1.5),
            ..default()
        })
        .contains("particle_filter.outlier_share"));
        for sigma in [-1.0, f64::NAN, f64::INFINITY] {
            assert!(bad(ParticleSettings {
                motion_noise: Some(sigma),
                ..default()
            })
            .contains("particle_filter.motion_noise"));
        }
        assert!(bad(ParticleSettings {
            velocity_share: -0.1,
            ..default()
        })
        .contains("particle_filter.velocity_share"));
        assert!(bad(ParticleSettings {
            recovery_share: 0.95,
            ..default()
        })
        .contains("particle_filter.recovery_share"));
        assert!(default().check().is_ok());
    }
}
