//! Learning the filter's motion noise σ and outlier share ε on the validation motion, as the
//! temporal trackers learn α: each candidate is run over the validation frames in order and the
//! one with the lowest mean error is kept. σ first (with ε as given or its default), then ε
//! with that σ: two short searches instead of their product, since a run costs a pass of the
//! whole filter over the validation motion.
//!
//! Chosen by validation error rather than from the displacement statistics of the estimates:
//! the best step also depends on how many particles cover it and on how sharp the likelihood
//! is, which the displacements do not show.

use super::ParticleFilter;
use crate::estimator::motion::motion_error_within;
use crate::estimator::{EstimatorError, TrainingSet};

/// The σ (mm/s) tried when learning the Gaussian step: from a slow drift to beyond the fastest
/// test motion (40 mm/s).
pub const MOTION_NOISE_CANDIDATES: [f64; 7] = [1.0, 2.0, 4.0, 8.0, 16.0, 32.0, 64.0];

/// σ (mm/s) when it is neither given nor learnable (no validation motion with timestamps).
pub const DEFAULT_MOTION_NOISE: f64 = 16.0;

/// The ε tried when learning the outlier share.
pub const OUTLIER_SHARE_CANDIDATES: [f64; 4] = [0.001, 0.01, 0.05, 0.2];

/// ε when it is neither given nor learnable.
pub const DEFAULT_OUTLIER_SHARE: f64 = 0.05;

/// Validation errors within this relative margin of the lowest are a tie.
const TIE: f64 = 1e-9;

/// Learns σ and ε where the settings leave them out and the training set has a validation
/// motion with timestamps; otherwise leaves the given or default values.
pub(super) fn learn(filter: &mut ParticleFilter, data: &TrainingSet) -> Result<(), EstimatorError> {
    if data.validation.is_none() || data.validation_times.is_none() {
        return Ok(());
    }
    let given = filter.file.settings.clone();
    // The σ search's winning pass, with the ε it ran under: the ε search need not run it again.
    let mut known = None;
    if given.motion_noise.is_none() {
        let (sigma, error) = lowest(&MOTION_NOISE_CANDIDATES, |sigma, bound| {
            filter.file.motion_noise = sigma;
            motion_error_within(filter, data, bound)
        })?;
        filter.file.motion_noise = sigma;
        filter.file.motion_noise_learned = true;
        known = Some((filter.file.outlier_share, error));
    }
    if given.outlier_share.is_none() {
        let (eps, _) = lowest(&OUTLIER_SHARE_CANDIDATES, |eps, bound| {
            if let Some((_, error)) = known.filter(|&(e, _)| e == eps) {
                return Ok(Some(error));
            }
            filter.file.outlier_share = eps;
            motion_error_within(filter, data, bound)
        })?;
        filter.file.outlier_share = eps;
        filter.file.outlier_share_learned = true;
    }
    Ok(())
}

/// The candidate with the lowest `error`, and its error; ties go to the largest (the broader
/// step, the more tolerant likelihood), as α's ties go to the most reliable. `error(candidate,
/// bound)` may stop early and give `None` when the candidate's error is above `bound`, the tie
/// limit of the best so far: such a candidate can be neither the lowest nor a tie, whatever
/// comes after.
fn lowest(
    candidates: &[f64],
    mut error: impl FnMut(f64, f64) -> Result<Option<f64>, EstimatorError>,
) -> Result<(f64, f64), EstimatorError> {
    let mut errors = Vec::with_capacity(candidates.len());
    let mut best = f64::INFINITY;
    for &c in candidates {
        let e = error(c, best * (1.0 + TIE))?.unwrap_or(f64::INFINITY);
        best = best.min(e);
        errors.push(e);
    }
    Ok(candidates
        .iter()
        .zip(&errors)
        .rev()
        .find(|(_, &e)| e <= best * (1.0 + TIE))
        .map_or((candidates[0], errors[0]), |(&c, &e)| (c, e)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::cmp::Ordering;

    #[test]
    fn the_lowest_error_wins_and_ties_go_to_the_largest() {
        let errors = [3.0, 1.0, 2.0, 1.0];
        // As a full pass would: stopped (`None`) when the error is above the bound.
        let pick =
            |errors: [f64; 4]| {
                let mut k = 0;
                lowest(&[1.0, 2.0, 4.0, 8.0], |_, bound| {
                    k += 1;
                    Ok(Some(errors[k - 1])
                        .filter(|e| e.partial_cmp(&bound) != Some(Ordering::Greater)))
                })
                .unwrap()
                .0
            };
        assert_eq!(pick(errors), 8.0);
        assert_eq!(pick([3.0, 1.0, 2.0, 1.5]), 2.0);
        // Every run failing to estimate (infinite error) keeps the largest candidate.
        assert_eq!(pick([f64::INFINITY; 4]), 8.0);
        assert_eq!(pick([f64::NAN; 4]), 1.0);
    }
}
