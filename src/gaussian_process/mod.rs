//! Gaussian-process maths shared by the GP baseline and the continuous tracker's feature maps:
//! the squared-exponential kernel's log marginal likelihood with its gradient
//! ([`Objective`]), a box-constrained L-BFGS over the log hyperparameters ([`minimise`]), and
//! the inverse of a kernel matrix from its Cholesky factor ([`upper_inverse`]), and that factor
//! itself ([`cholesky`]: nalgebra's, bit for bit, faster). A leaf.

mod cholesky;
mod inverse;
mod likelihood;
mod optimiser;
pub(crate) mod simd;

pub use cholesky::cholesky;
pub use inverse::upper_inverse;
pub use likelihood::Objective;
pub use optimiser::{dot, minimise};

use std::f64::consts::LN_10;

// Bounds of the log hyperparameters (inputs and outputs are standardised, so these are wide):
// the floor of σn/σf keeps the kernel matrix positive definite in practice.
/// Bounds of log ℓ: ℓ in 1e-2 ..= 1e3.
pub const LOG_LENGTH: (f64, f64) = (-2.0 * LN_10, 3.0 * LN_10);
/// Bounds of log σf: σf in 1e-3 ..= 1e3.
pub const LOG_SIGNAL: (f64, f64) = (-3.0 * LN_10, 3.0 * LN_10);
/// Bounds of log(σn/σf): σn/σf in 1e-6 ..= 10.
pub const LOG_NOISE_RATIO: (f64, f64) = (-6.0 * LN_10, LN_10);

#[cfg(test)]
mod tests;
