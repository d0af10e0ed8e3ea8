//! Each feature's fitted map shared between the continuous fits that fit it identically: a
//! sweep's variants that add features to the same others (the paper's (e) adds the barycentre
//! to (a)'s six size functions) fit those others on the same standardised data, so their
//! hyperparameters and factored kernels are the same to the bit. Keyed by everything they
//! depend on, bit for bit, and held weakly as the grid's table is (`grid_share`): the fits that
//! use them keep them alive.

use std::sync::{Arc, Mutex, OnceLock};

use super::super::grid_share::{try_shared, try_shared_infallible, Live};
use super::{FeatureKernel, SurrogateHyperparameters};

/// A feature's fitted hyperparameters (`None`: a singular kernel at every start).
pub(in crate::estimator::continuous) type Fitted = Option<SurrogateHyperparameters>;

/// The hyperparameters `fit` finds for one feature: on the standardised pose `inputs` (x, y
/// per sample) and feature `column`, from `m` evenly spaced samples, with `iterations`.
/// While another fit finds them, `wait` waits, and without it nothing happens (`None`).
pub(super) fn hyperparameters(
    inputs: &[f64],
    column: &[f64],
    m: usize,
    iterations: usize,
    wait: bool,
    fit: impl FnOnce() -> Fitted,
) -> Option<Arc<Fitted>> {
    static LIVE: OnceLock<Live<Fitted>> = OnceLock::new();
    let mut key = Vec::with_capacity(8 * (2 + inputs.len() + column.len()));
    key.extend((m as u64).to_le_bytes());
    key.extend((iterations as u64).to_le_bytes());
    append(&mut key, inputs);
    key.push(b'|');
    append(&mut key, column);
    try_shared_infallible(LIVE.get_or_init(Mutex::default), key, wait, fit)
}

/// The kernel `build` factors for one feature with `h` on the standardised poses and the
/// feature's standardised values `y` (with the leave-one-out diagonal or not); an error is not
/// kept. While another fit factors it, `wait` waits, and without it nothing happens (`None`).
pub(super) fn kernel(
    h: &SurrogateHyperparameters,
    standardised: &[[f64; 2]],
    y: &[f64],
    leave_one_out: bool,
    wait: bool,
    build: impl FnOnce() -> Result<FeatureKernel, String>,
) -> Option<Result<Arc<FeatureKernel>, String>> {
    static LIVE: OnceLock<Live<FeatureKernel>> = OnceLock::new();
    // The log marginal likelihood is a record of the fit: the kernel does not depend on it.
    let numbers = [
        h.length_scales[0],
        h.length_scales[1],
        h.signal_std,
        h.noise_std,
    ];
    let mut key = Vec::with_capacity(8 * (5 + 3 * y.len()));
    key.push(u8::from(leave_one_out));
    append(&mut key, &numbers);
    append(&mut key, standardised.as_flattened());
    key.push(b'|');
    append(&mut key, y);
    try_shared(LIVE.get_or_init(Mutex::default), key, wait, build)
}

fn append(key: &mut Vec<u8>, values: &[f64]) {
    key.extend((values.len() as u64).to_le_bytes());
    values
        .iter()
        .for_each(|v| key.extend(v.to_bits().to_le_bytes()));
}
