//! One motion under the particle filter: predict ([`super::predict`]: the line's shift for a
//! share of the particles, then a Gaussian step), weigh by the frame's likelihood, resample
//! when degenerate.
//! From `PARALLEL_FROM` particles the per-particle work (moves, likelihood, weights; the
//! radius beside the covariance) runs on two threads ([`Pool`]); the random draws stay on one
//! thread and every sum on the caller, in the serial order, so the bits do not depend on the
//! threads.

use std::sync::atomic::AtomicUsize;
use std::sync::{Mutex, MutexGuard, PoisonError};

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::likelihood::{exp, BlockScratch, FrameLikelihood, BLOCK};
use super::pool::{Disjoint, Outcome, Pool};
use super::predict::{draw_blocks, wait_for, Draw, Prediction};
use super::radius::WeightedRadius;
use super::recover::{Guess, Mixture, Predicted};
use super::{FilterScore, ParticleFilter};
use crate::estimator::inputs::frame_values;
use crate::estimator::motion::VelocityLine;
use crate::estimator::{EstimateFlags, EstimatorError, MotionTracker, PoseEstimate, PoseEstimator};

/// From this many particles a motion weighs its particles on two threads (`pool`): below it,
/// handing chunks to a second thread costs more than it saves (measured in docs/results.md,
/// "Benchmarks").
const PARALLEL_FROM: usize = 5_000;
/// A frame in which the caller waited this long for the worker, or ran more than
/// `ALONE_SHARE` of the chunks itself, finds the second core busy (a loaded machine): the
/// next frames run on one thread, `BACKOFF_FROM` of them, doubling while it lasts, at most
/// `BACKOFF_TO`. The results are the same bits either way.
pub(super) const WAITED_AT_MOST: std::time::Duration = std::time::Duration::from_micros(150);
const ALONE_SHARE: f64 = 0.8;
const BACKOFF_FROM: u32 = 8;
const BACKOFF_TO: u32 = 512;
/// Particles per chunk of the weights' update (exponentials only: larger than a block).
const WEIGHT_CHUNK: usize = 4 * BLOCK;

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
    /// frame's likelihood terms, each particle's random draw and log-likelihood, each block's
    /// largest log-likelihood, each thread's block maps, the distance sort, and the resampled
    /// particles.
    likelihood: FrameLikelihood,
    draws: Vec<Draw>,
    logs: Vec<f64>,
    /// Each particle's p̂/q under the recovery's mixture (empty without one), beside its
    /// log-likelihood: the posterior's fit (`FilterScore::Posterior`) reads both.
    corrections: Vec<f64>,
    maxes: Vec<f64>,
    scratch: [Mutex<BlockScratch>; 2],
    radius: Mutex<WeightedRadius>,
    resampled: Vec<[f64; 2]>,
    /// The weighted mean and the sum of the squared weights, when the update took them.
    moments: Option<([f64; 2], f64)>,
    /// The last posterior's mean and covariance, and this frame's recovery mixture (`recover`).
    cloud: Option<([f64; 2], [[f64; 2]; 2])>,
    mixture: Option<Mixture>,
    /// The second thread, from `PARALLEL_FROM` particles; whether it is used this frame, and
    /// whether it goes unused after frames that found it slow (`adaptive`): for so many more
    /// frames (`serial_frames`), the last such pause (`backoff`), and the frame's jobs so far.
    pool: Option<Pool>,
    threads: bool,
    adaptive: bool,
    serial_frames: u32,
    backoff: u32,
    outcome: Outcome,
}

/// Runs `work(chunk, thread)` for each of `chunks`, on both threads where there is a pool,
/// adding how it went to `outcome`.
fn each_chunk(
    pool: Option<&Pool>,
    outcome: &mut Outcome,
    chunks: usize,
    work: &(dyn Fn(usize, usize) + Sync),
) {
    match pool {
        Some(pool) => *outcome = outcome.add(pool.run(chunks, work)),
        None => (0..chunks).for_each(|chunk| work(chunk, 0)),
    }
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(PoisonError::into_inner)
}

impl<'a> FilterMotion<'a> {
    /// Particles spread uniformly over the sample poses' bounding box, from the model's seed.
    pub(super) fn new(filter: &'a ParticleFilter) -> Self {
        let n = filter.file.settings.particles;
        let mut motion = Self::with_threads(filter, n >= PARALLEL_FROM);
        motion.adaptive = true;
        motion
    }

    /// As [`FilterMotion::new`], on two threads in every frame or on one.
    pub(super) fn with_threads(filter: &'a ParticleFilter, two: bool) -> Self {
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
            draws: Vec::with_capacity(n),
            logs: vec![0.0; n],
            corrections: Vec::new(),
            maxes: vec![f64::NEG_INFINITY; n.div_ceil(BLOCK)],
            scratch: Default::default(),
            radius: Mutex::new(WeightedRadius::with_capacity(n)),
            resampled: Vec::with_capacity(n),
            moments: None,
            cloud: None,
            mixture: None,
            pool: two.then(|| filter.workers.take()).flatten(),
            threads: false,
            adaptive: false,
            serial_frames: 0,
            backoff: 0,
            outcome: Outcome::default(),
        }
    }

    /// The pool if this frame uses it.
    fn pool(&self) -> Option<&Pool> {
        self.pool.as_ref().filter(|_| self.threads)
    }

    /// Decides whether this frame runs on two threads.
    fn start_frame(&mut self) {
        self.outcome = Outcome::default();
        self.threads = self.pool.is_some() && self.serial_frames == 0;
        self.serial_frames = self.serial_frames.saturating_sub(1);
    }

    /// After a frame on two threads: pauses the worker when it did not keep up.
    fn end_frame(&mut self) {
        let Outcome {
            own,
            chunks,
            waited,
        } = self.outcome;
        if !(self.threads && self.adaptive) {
            return;
        }
        if waited > WAITED_AT_MOST || own as f64 > ALONE_SHARE * chunks as f64 {
            self.backoff = (2 * self.backoff).clamp(BACKOFF_FROM, BACKOFF_TO);
            self.serial_frames = self.backoff;
        } else {
            self.backoff = 0;
        }
    }

    /// Moves the particles by their draws (with `prediction`), and with `weigh` takes each
    /// particle's log-likelihood of the frame (`likelihood`, prepared) and each block's largest.
    ///
    /// The draws are taken in the serial filter's order by one thread, in the job's first
    /// chunk ([`draw_blocks`]), so the random stream does not depend on the threads; each block
    /// of them is published as it is done, and a block's moves wait for its draws: on two
    /// threads the other thread moves and weighs the first blocks while the draws go on.
    fn move_and_weigh(&mut self, prediction: Option<&Prediction>, weigh: bool) {
        let maps = &self.filter.maps;
        let n = self.particles.len();
        let drawing = prediction.is_some();
        if drawing {
            self.draws.resize(n, Draw::Line([0.0; 2]));
        }
        let share = self.filter.file.settings.velocity_share;
        let recovery = self.mixture.as_ref().map_or(0.0, |m| m.share);
        let (rng, drawn) = (Mutex::new(&mut self.rng), AtomicUsize::new(0));
        let draws = Disjoint::new(&mut self.draws);
        let (particles, logs) = (
            Disjoint::new(&mut self.particles),
            Disjoint::new(&mut self.logs),
        );
        let maxes = Disjoint::new(&mut self.maxes);
        let (likelihood, scratch) = (&self.likelihood, &self.scratch);
        let pool = self.pool.as_ref().filter(|_| self.threads);
        let first = usize::from(drawing);
        each_chunk(
            pool,
            &mut self.outcome,
            first + n.div_ceil(BLOCK),
            &|chunk, thread| {
                if chunk < first {
                    draw_blocks(&mut lock(&rng), (share, recovery), &draws, n, &drawn);
                    return;
                }
                let block = chunk - first;
                let range = block * BLOCK..((block + 1) * BLOCK).min(n);
                // SAFETY: each chunk takes its own range of each slice.
                let (particles, logs, max) = unsafe {
                    (
                        particles.range(range.clone()),
                        logs.range(range.clone()),
                        maxes.range(block..block + 1),
                    )
                };
                if let Some(prediction) = prediction {
                    wait_for(&drawn, range.end);
                    // SAFETY: published (`drawn`), so no longer written; read by this chunk only.
                    let draws = unsafe { draws.range(range) };
                    for (p, &draw) in particles.iter_mut().zip(&*draws) {
                        *p = prediction.apply(*p, draw);
                    }
                }
                if weigh {
                    likelihood.block(maps, particles, &mut lock(&scratch[thread]), logs);
                    max[0] = logs.iter().copied().fold(f64::NEG_INFINITY, f64::max);
                }
            },
        );
    }

    /// Weights by the frame's likelihood (`logs`, with `maxes`); the detection score (the
    /// settings' [`FilterScore`]), or `None` when every particle's likelihood underflows (the
    /// weights then stay).
    fn update(&mut self) -> Option<f64> {
        // The largest of the blocks' largest: the largest, whatever the grouping (no −0 in a
        // sum from +0, and `max` passes over NaN).
        let max = self.maxes.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        if !max.is_finite() {
            return None;
        }
        let n = self.weights.len();
        if self.mixture.is_some() {
            self.corrections.resize(n, 0.0);
        }
        let pool = self.pool.as_ref().filter(|_| self.threads);
        let (weights, corrections) = (
            Disjoint::new(&mut self.weights),
            Disjoint::new(&mut self.corrections),
        );
        let (mixture, particles, logs) = (self.mixture.as_ref(), &self.particles, &self.logs);
        each_chunk(
            pool,
            &mut self.outcome,
            n.div_ceil(WEIGHT_CHUNK),
            &|chunk, _| {
                let range = chunk * WEIGHT_CHUNK..((chunk + 1) * WEIGHT_CHUNK).min(n);
                // SAFETY: each chunk takes its own range.
                let weights = unsafe { weights.range(range.clone()) };
                for (w, l) in weights.iter_mut().zip(&logs[range.clone()]) {
                    *w *= exp(l - max);
                }
                if let Some(mixture) = mixture {
                    // SAFETY: as above.
                    let corrections = unsafe { corrections.range(range.clone()) };
                    for (c, p) in corrections.iter_mut().zip(&particles[range]) {
                        *c = mixture.correction(*p);
                    }
                }
            },
        );
        let mut total = 0.0;
        for w in &self.weights {
            total += *w;
        }
        if !(total > 0.0 && total.is_finite()) {
            return None;
        }
        // The weights take p̂/q, normalised by the correction, so the posterior is the
        // filter's; so is the predictive score: −ln of the filter's own predictive likelihood,
        // not the mixture's (particles drawn about a right guess that the prediction does not
        // reach would otherwise make a frame the posterior misses read as a good one).
        let (divisor, total) = match &self.mixture {
            Some(_) => match Mixture::correct(&mut self.weights, &self.corrections) {
                Some(corrected) => (1.0, corrected),
                // Nothing left after p̂/q: the mixture's posterior, with its own score.
                None => (total, total),
            },
            None => (total, total),
        };
        // Normalised in the same pass as the estimate's sums (`moments`) and the posterior's
        // expected log-likelihood.
        let (mut mean, mut squares, mut fit) = ([0.0; 2], 0.0, 0.0);
        for ((w, p), l) in self.weights.iter_mut().zip(&self.particles).zip(&self.logs) {
            *w /= divisor;
            (mean, squares) = add_moments(mean, squares, *w, p);
            fit += *w * l;
        }
        self.moments = Some((mean, squares));
        Some(match self.filter.file.settings.score {
            FilterScore::Posterior => -fit,
            FilterScore::Predictive => -(total.ln() + max),
        })
    }

    /// p̂, the density the prediction moves the last posterior to (`recover`): uniform over the
    /// box before the first prediction.
    fn predicted(
        &self,
        prediction: Option<&Prediction>,
        bounds: ([f64; 2], [f64; 2]),
    ) -> Predicted {
        match (prediction, self.cloud) {
            (Some(p), Some((mean, covariance))) => Predicted::moved(
                mean,
                covariance,
                p.shift,
                p.step,
                p.reach,
                self.filter.file.settings.velocity_share,
            ),
            _ => {
                let (lo, hi) = bounds;
                Predicted::Uniform((hi[0] - lo[0]) * (hi[1] - lo[1]))
            }
        }
    }

    /// Resamples when the effective sample size 1/`squares` (the sum of the squared weights)
    /// is below half the particles.
    fn resample_if_degenerate(&mut self, squares: f64) {
        let n = self.particles.len();
        let ess = 1.0 / squares;
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

    /// Weighted mean, the radius holding 90 % of the weight, the weighted second moments about
    /// the mean (mm²), and the sum of the squared weights.
    fn estimate(&mut self) -> ([f64; 2], f64, [[f64; 2]; 2], f64) {
        let (particles, weights) = (&self.particles, &self.weights);
        // One pass for the mean and the squares (or the update's): separate sums, each in the
        // particles' order.
        let (mean, squares) = self.moments.take().unwrap_or_else(|| {
            let (mut mean, mut squares) = ([0.0; 2], 0.0);
            for (p, &w) in particles.iter().zip(weights) {
                (mean, squares) = add_moments(mean, squares, w, p);
            }
            (mean, squares)
        });
        let Some(pool) = self.pool() else {
            let radius = lock(&self.radius).radius(particles, weights, mean, 0.9);
            return (mean, radius, covariance(particles, weights, mean), squares);
        };
        // The radius on one thread, the covariance on the other.
        let (radius, moments) = (Mutex::new(0.0), Mutex::new([[0.0; 2]; 2]));
        let outcome = pool.run(2, &|chunk, _| match chunk {
            0 => *lock(&radius) = lock(&self.radius).radius(particles, weights, mean, 0.9),
            _ => *lock(&moments) = covariance(particles, weights, mean),
        });
        self.outcome = self.outcome.add(outcome);
        let radius = radius.into_inner().unwrap_or_else(PoisonError::into_inner);
        let moments = moments.into_inner().unwrap_or_else(PoisonError::into_inner);
        (mean, radius, moments, squares)
    }
}

impl Drop for FilterMotion<'_> {
    /// Hands the worker back to the filter for its next motion.
    fn drop(&mut self) {
        if let Some(pool) = self.pool.take() {
            self.filter.workers.keep(pool);
        }
    }
}

/// The weighted mean and the sum of the squared weights, with particle `p` of weight `w` added.
#[inline(always)]
fn add_moments(mean: [f64; 2], squares: f64, w: f64, p: &[f64; 2]) -> ([f64; 2], f64) {
    ([mean[0] + w * p[0], mean[1] + w * p[1]], squares + w * w)
}

/// The particles' weighted second moments about `mean` (mm²).
fn covariance(particles: &[[f64; 2]], weights: &[f64], mean: [f64; 2]) -> [[f64; 2]; 2] {
    let mut moments = [[0.0; 2]; 2];
    for (p, w) in particles.iter().zip(weights) {
        let d = [p[0] - mean[0], p[1] - mean[1]];
        moments[0][0] += w * d[0] * d[0];
        moments[0][1] += w * d[0] * d[1];
        moments[1][1] += w * d[1] * d[1];
    }
    moments[1][0] = moments[0][1];
    moments
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
        self.start_frame();
        let usable = values.iter().any(Option::is_some);
        let recovery = self.filter.file.settings.recovery_share;
        let guess = (recovery > 0.0 && usable)
            .then(|| Guess::of_frame(self.filter, features))
            .flatten();
        let bounds = self.filter.maps.sample_bounds();
        let mut prediction = self.last.map(|last| {
            let interval = (time - last).max(0.0);
            let shift = self.line.shift(interval);
            let mut noise = self.filter.file.motion_noise;
            if self.line.velocity().is_none() {
                // No line yet: the velocity is unknown within the reach.
                noise = noise.max(0.5 * self.filter.file.max_speed);
            }
            Prediction {
                step: noise * interval,
                reach: self.filter.file.max_speed * interval,
                shift,
                bounds,
                guess,
            }
        });
        self.mixture = guess.map(|guess| Mixture {
            guess,
            predicted: self.predicted(prediction.as_ref(), bounds),
            share: recovery,
        });
        if prediction.is_none() && guess.is_some() {
            // The first frame: the particles stay, but a share is drawn about the estimate.
            prediction = Some(Prediction {
                step: 0.0,
                reach: 0.0,
                shift: [0.0; 2],
                bounds,
                guess,
            });
        }
        self.last = Some(time);
        if usable {
            self.likelihood.prepare(
                &values,
                scales,
                (&self.norms, &self.uniforms),
                self.filter.file.outlier_share,
            );
        }
        if usable || prediction.is_some() {
            self.move_and_weigh(prediction.as_ref(), usable);
        }
        let score = if usable { self.update() } else { None };
        let (pose, radius, covariance, squares) = self.estimate();
        self.cloud = Some((pose, covariance));
        self.line.remember(time, score.map(|_| pose), false);
        self.resample_if_degenerate(squares);
        self.end_frame();
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

#[cfg(test)]
#[path = "motion_tests.rs"]
mod tests;
