//! The information limit of a run's test frames (`crate::information`): the continuous
//! tracker's feature maps give the slopes at each true pose, the validation motion's residuals
//! the noise covariance. Every run measures it, whatever methods it lists: the continuous fit is
//! taken from the run's own estimators, else fitted through the workbench (shared between
//! variants with the same training data and settings).

use crate::estimator::{
    underlying, Continuous, EstimatorSettings, Method, PoseEstimator, TrainingSet,
};
use crate::information::{InformationError, NoiseModel};
use crate::report::{efficiency, FrameRecord, LimitNoise, LimitSummary, MethodSummary};

use super::Workbench;

/// Most sample poses the limit fits feature maps on by itself (when the run has no continuous
/// tracker): the fit factors a kernel matrix per feature on every sample, O(n³), and the 10,000
/// samples of `scale.toml` would cost (10,000 / 1,521)³ ≈ 280× `best.toml`'s per feature.
pub const LIMIT_MAX_SAMPLES: usize = 2000;

/// The bound tr I⁻¹ (mm²) of every test frame, per test motion, and the noise it assumed.
pub(super) struct Limits {
    pub per_motion: Vec<Vec<Option<f64>>>,
    pub noise: LimitNoise,
}

/// One test motion's true poses and feature rows.
pub(super) type TestFrames<'a> = (&'a [[f64; 2]], &'a [Vec<Option<f64>>]);

/// The limits of the test frames `tests` (true poses and feature rows per motion); `None` when
/// no continuous fit could be had (too many features or, for a fit of its own, more than
/// [`LIMIT_MAX_SAMPLES`] samples; a singular kernel): the run goes on without a limit.
pub(super) fn measure(
    estimators: &[Box<dyn PoseEstimator>],
    bench: &Workbench,
    settings: &EstimatorSettings,
    training: &TrainingSet,
    tests: &[TestFrames<'_>],
) -> Option<Limits> {
    let own = estimators.iter().find_map(|e| {
        (underlying(e.as_ref()) as &dyn std::any::Any)
            .downcast_ref::<Continuous>()
            .cloned()
    });
    let continuous = match own {
        Some(c) => c,
        None if training.sample.poses.len() > LIMIT_MAX_SAMPLES => return None,
        None => {
            let fitted = bench.fit(Method::CONTINUOUS, settings, training).ok()?;
            (underlying(fitted.as_ref()) as &dyn std::any::Any)
                .downcast_ref::<Continuous>()?
                .clone()
        }
    };
    let (model, noise) = noise_model(&continuous, training).ok()?;
    let per_motion = tests
        .iter()
        .map(|(truth, rows)| frame_bounds(&continuous, &model, truth, rows))
        .collect();
    Some(Limits { per_motion, noise })
}

/// The noise model: the full covariance of the validation residuals y − f(q_true), else (no
/// validation motion) the tracker's leave-one-out noise scales as independent.
pub fn noise_model(
    continuous: &Continuous,
    training: &TrainingSet,
) -> Result<(NoiseModel, LimitNoise), InformationError> {
    let sigmas = continuous.residual_scales();
    let Some(validation) = &training.validation else {
        let model = NoiseModel::diagonal(sigmas)?;
        return Ok((model, LimitNoise::diagonal()));
    };
    let mut f = vec![0.0; sigmas.len()];
    let residuals: Vec<Vec<Option<f64>>> = (validation.rows.iter().zip(validation.poses))
        .map(|(row, &q)| {
            continuous.feature_map_into(q, &mut f);
            (row.iter().zip(&f))
                .map(|(y, fi)| y.filter(|y| y.is_finite()).map(|y| y - fi))
                .collect()
        })
        .collect();
    let model = NoiseModel::from_residuals(sigmas, &residuals)?;
    let (floored, floor) = model.floored();
    Ok((model, LimitNoise::full(floored, floor)))
}

/// tr I⁻¹ at each frame's true pose with the features present in its row.
pub fn frame_bounds(
    continuous: &Continuous,
    model: &NoiseModel,
    truth: &[[f64; 2]],
    rows: &[Vec<Option<f64>>],
) -> Vec<Option<f64>> {
    let n = model.dim();
    let (mut values, mut slopes) = (vec![0.0; n], vec![[0.0; 2]; n]);
    (truth.iter().zip(rows))
        .map(|(&q, row)| {
            continuous.feature_slopes_into(q, &mut values, &mut slopes);
            let present: Vec<bool> = (0..n)
                .map(|i| row.get(i).copied().flatten().is_some_and(f64::is_finite))
                .collect();
            model.bound(&slopes, &present)
        })
        .collect()
}

/// Puts each frame's limit (√ tr I⁻¹) on its records and each method's efficiency on its
/// summary; the run's limit is over the clean frames.
pub(super) fn attach(
    found: Limits,
    tests: &[super::TestMotion],
    records: &mut [FrameRecord],
    methods: &mut [MethodSummary],
) -> LimitSummary {
    let bound_of = |motion: &str, frame: usize| {
        let k = tests.iter().position(|t| t.0 == motion)?;
        *found.per_motion.get(k)?.get(frame)?
    };
    for r in records.iter_mut() {
        r.limit_mm = bound_of(&r.motion, r.frame).map(f64::sqrt);
    }
    for m in methods.iter_mut() {
        let own: Vec<&FrameRecord> = records.iter().filter(|r| r.method == m.method).collect();
        m.efficiency = efficiency(&own);
    }
    let frames: Vec<(Option<f64>, bool)> = (tests.iter().zip(&found.per_motion))
        .flat_map(|(t, bounds)| {
            bounds.iter().enumerate().map(|(i, b)| {
                let corrupted = t.4.as_ref().is_some_and(|l| l[i].corrupted());
                (*b, corrupted)
            })
        })
        .collect();
    LimitSummary::of(&frames, found.noise)
}
