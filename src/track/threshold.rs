//! Learning the conflict threshold on a validation motion (§4.3).

use super::TrackError;
use crate::evidence::ConflictLevel;

/// The conflict threshold learned from a validation motion: the mean of the per-frame levels of
/// conflict of the full combination, weighted by the per-frame estimation errors,
/// K̂ = Σ K_k e_k / Σ e_k.
///
/// Frames whose level is infinite (or NaN) are skipped: they have no finite level to average.
/// When the remaining frames' errors sum to 0 (every estimate exact), the plain mean of their levels
/// is returned; when no frame has a finite level (or there are no frames), the result is
/// [`ConflictLevel::Infinite`], i.e. every pair with finite conflict stays compatible.
///
/// # Errors
/// [`TrackError::LearningLengths`] when the slices differ in length, [`TrackError::LearningError`]
/// for an error that is NaN, infinite or negative.
pub fn learn_conflict_threshold(
    levels: &[f64],
    errors: &[f64],
) -> Result<ConflictLevel, TrackError> {
    if levels.len() != errors.len() {
        return Err(TrackError::LearningLengths {
            levels: levels.len(),
            errors: errors.len(),
        });
    }
    if let Some((frame, &value)) = errors
        .iter()
        .enumerate()
        .find(|(_, e)| !e.is_finite() || **e < 0.0)
    {
        return Err(TrackError::LearningError { frame, value });
    }
    let (mut num, mut den, mut sum, mut count) = (0.0, 0.0, 0.0, 0usize);
    for (&k, &e) in levels.iter().zip(errors) {
        if !k.is_finite() {
            continue;
        }
        num += k * e;
        den += e;
        sum += k;
        count += 1;
    }
    Ok(if count == 0 {
        ConflictLevel::Infinite
    } else if den > 0.0 {
        ConflictLevel::Finite(num / den)
    } else {
        ConflictLevel::Finite(sum / count as f64)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weighted_mean_by_hand() {
        // (0.1·1 + 0.4·3) / 4 = 0.325; the infinite frame is skipped.
        let k = learn_conflict_threshold(&[0.1, 0.4, f64::INFINITY], &[1.0, 3.0, 100.0]).unwrap();
        assert!((k.value() - 0.325).abs() < 1e-15);
    }

    #[test]
    fn documented_fallbacks() {
        let k = learn_conflict_threshold(&[0.2, 0.4], &[0.0, 0.0]).unwrap();
        assert!((k.value() - 0.3).abs() < 1e-15);
        assert_eq!(
            learn_conflict_threshold(&[f64::INFINITY], &[1.0]).unwrap(),
            ConflictLevel::Infinite
        );
        assert_eq!(
            learn_conflict_threshold(&[], &[]).unwrap(),
            ConflictLevel::Infinite
        );
        assert!(learn_conflict_threshold(&[0.1], &[]).is_err());
        assert!(learn_conflict_threshold(&[0.1], &[f64::NAN]).is_err());
        assert!(learn_conflict_threshold(&[0.1], &[-1.0]).is_err());
    }
}
