//! One motion under the particle filter: predict (the line's shift for a share of the
//! particles, then a Gaussian step), weigh by the frame's likelihood, resample when degenerate.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

use super::likelihood::{exp, FrameLikelihood};
use super::radius::WeightedRadius;
use super::ParticleFilter;
use crate::estimator::inputs::frame_values;
use crate::estimator::motion::VelocityLine;
use crate::estimator::{EstimateFlags, EstimatorError, MotionTracker, PoseEstimate, PoseEstimator};

/// One motion under the particle filter.
pub(super) struct FilterMotion<'a> {
    filter: &'a ParticleFilter,
    rng: ChaCha8Rng,
    particles: Vec<[f64; 2]>,
    /// Normalised.
    weights: Vec<f64>,
    last: Option<f64>,
    /// The line through the last measured estimates.
    line: VelocityLine,
    /// Per feature: σ·√(2π) and ε/W, the likelihood's constants.
    norms: Vec<f64>,
    uniforms: Vec<f64>,
    /// Scratch kept between frames, so that a frame allocates nothing per particle: the
    /// frame's likelihood terms and its blocks' maps, each particle's log-likelihood, the radius's sort and the resampled particles.
    likelihood: FrameLikelihood,
    logs: Vec<f64>,
    radius: WeightedRadius,
    resampled: Vec<[f64; 2]>,
}

impl<'a> FilterMotion<'a> {
    /// Particles spread uniformly over the sample poses' bounding box, from the model's seed.
    pub(super) fn new(filter: &'a ParticleFilter) -> Self {
        let (lo, hi) = filter.maps.sample_bounds();
        let mut rng = ChaCha8Rng::seed_from_u64(filter.file.seed);
        let n = filter.file.settings.particles;
        let particles = (0..n)
            .map(|_| {
                [
                    lo[0] + rng.random::<f64>() * (hi[0] - lo[0]),
                    lo[1] + rng.random::<f64>() * (hi[1] - lo[1]),
                ]
            })
            .collect();
        let (norms, uniforms) = filter.likelihood_constants();
        Self {
            filter,
            rng,
            particles,
            weights: vec![1.0 / n as f64; n],
            last: None,
            line: VelocityLine::new(filter.file.velocity_frames),
            likelihood: FrameLikelihood::default(),
            norms,
            uniforms,
            logs: Vec::with_capacity(n),
            radius: WeightedRadius::with_capacity(n),
            resampled: Vec::with_capacity(n),
        }
    }

    /// Moves the share `velocity_share` of the particles by `shift` and a Gaussian step of
    /// spread `step` (mm) per axis, and the others to a uniform point of the disc of radius
    /// `reach` (mm): the line's share is precise, the others keep the filter from losing a pose
    /// that leaves the line.
    fn predict(&mut self, step: f64, reach: f64, shift: [f64; 2]) {
        let (lo, hi) = self.filter.maps.sample_bounds();
        let share = self.filter.file.settings.velocity_share;
        for p in &mut self.particles {
            let moved = if self.rng.random::<f64>() < share {
                let dx: f64 = self.rng.sample(StandardNormal);
                let dy: f64 = self.rng.sample(StandardNormal);
                [p[0] + shift[0] + step * dx, p[1] + shift[1] + step * dy]
            } else {
                // Uniform in the disc: radius ∝ √u.
                let r = reach * self.rng.random::<f64>().sqrt();
                let angle = std::f64::consts::TAU * self.rng.random::<f64>();
                [p[0] + r * angle.cos(), p[1] + r * angle.sin()]
            };
            p[0] = moved[0].clamp(lo[0], hi[0]);
            p[1] = moved[1].clamp(lo[1], hi[1]);
        }
    }

    /// Weights by the frame's likelihood; −ln of the predictive likelihood (the detection
    /// score), or `None` when every particle's likelihood underflows (the weights then stay).
    fn update(&mut self, values: &[Option<f64>]) -> Option<f64> {
        let maps = &self.filter.maps;
        self.likelihood.prepare(
            values,
            maps.residual_scales(),
            (&self.norms, &self.uniforms),
            self.filter.file.outlier_share,
        );
        (self.likelihood).log_likelihoods(maps, &self.particles, &mut self.logs);
        let max = self.logs.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        if !max.is_finite() {
            return None;
        }
        let mut total = 0.0;
        for (w, l) in self.weights.iter_mut().zip(&self.logs) {
            *w *= exp(l - max);
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
        self.resampled.clear();
        for _ in 0..n {
            while u > cumulative && i + 1 < n {
                i += 1;
                cumulative += self.weights[i];
            }
            self.resampled.push(self.particles[i]);
            u += step;
        }
        std::mem::swap(&mut self.particles, &mut self.resampled);
        self.weights.fill(step);
    }

    /// Weighted mean and the radius holding 90 % of the weight.
    fn estimate(&mut self) -> ([f64; 2], f64) {
        let mut mean = [0.0; 2];
        for (p, w) in self.particles.iter().zip(&self.weights) {
            mean[0] += w * p[0];
            mean[1] += w * p[1];
        }
        let radius = (self.radius).radius(&self.particles, &self.weights, mean, 0.9);
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
            let mut noise = self.filter.file.motion_noise;
            if self.line.velocity().is_none() {
                // No line yet: the velocity is unknown within the reach.
                noise = noise.max(0.5 * self.filter.file.max_speed);
            }
            self.predict(
                noise * interval,
                self.filter.file.max_speed * interval,
                shift,
            );
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
