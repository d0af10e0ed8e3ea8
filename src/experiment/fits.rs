//! A run's costly fits side by side. Each fit is a pure function of its settings and training
//! data, so fitting the heavy methods (`heavy_fit`: the Gaussian processes) at once gives what
//! fitting them in order gives; the run then tracks every method in order as before. Side by
//! side, a fit that waits for a piece another run is fitting (a shared feature map) no longer
//! holds back the fits after it.

use std::time::Instant;

use super::Workbench;
use crate::estimator::{EstimatorError, EstimatorSettings, Method, PoseEstimator, TrainingSet};

/// A fit made ahead: the fitted method or its error, and the fit's wall time (s).
pub(super) type Ahead = (Result<Box<dyn PoseEstimator>, EstimatorError>, f64);

/// With two or more threads (`bench.threads()`) and two or more heavy methods, fits each heavy
/// method of `methods` on a thread of its own, in its slot; every other slot is `None` (the run
/// fits those in order). A panic in a fit goes on here.
pub(super) fn fit_heavy_ahead(
    methods: &[Method],
    bench: &Workbench,
    settings: &EstimatorSettings,
    training: &TrainingSet,
) -> Vec<Option<Ahead>> {
    let heavy = |m: &Method| m.entry().heavy_fit;
    let mut ahead: Vec<Option<Ahead>> = methods.iter().map(|_| None).collect();
    if bench.threads() < 2 || methods.iter().filter(|m| heavy(m)).count() < 2 {
        return ahead;
    }
    std::thread::scope(|scope| {
        let handles: Vec<_> = (methods.iter().enumerate())
            .filter(|(_, m)| heavy(m))
            .map(|(k, &method)| {
                let handle = scope.spawn(move || {
                    let clock = Instant::now();
                    let fitted = bench.fit(method, settings, training);
                    (fitted, clock.elapsed().as_secs_f64())
                });
                (k, handle)
            })
            .collect();
        for (k, handle) in handles {
            let done = handle
                .join()
                .unwrap_or_else(|panic| std::panic::resume_unwind(panic));
            ahead[k] = Some(done);
        }
    });
    ahead
}
