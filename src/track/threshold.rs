//! Learning the conflict threshold on a validation motion (§4.3).
//!
//! The levels are those of the groups the tracker combines with no threshold (the largest group
//! with a finite level, §4.3's "compatible b.f."), and the learned threshold is applied to the
//! same quantity: a group is combined only when its own level is within it.

use serde::{Deserialize, Serialize};

use super::TrackError;
use crate::evidence::ConflictLevel;

/// How the threshold is learned from the validation levels.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum ThresholdRule {
    /// The paper's: the levels' mean weighted by the estimation errors
    /// ([`learn_conflict_threshold`]). A typical level, so clean frames above it lose features.
    ErrorWeighted,
    /// This quantile of the levels (e.g. 0.99): on clean data about 1 − q of the frames exceed
    /// it, a false-alarm rate chosen in advance ([`quantile_threshold`]).
    Quantile(f64),
    /// This factor (≥ 1) times the largest finite level: the clean validation frames all keep
    /// their features, and the factor covers the higher levels of longer, unseen clean motions
    /// (`DEFAULT_MAX_FACTOR`). The default.
    ValidationMax(f64),
}

/// The default rule's factor over the largest clean validation level. On held-out clean motions
/// (docs/results.md, "Faults": 10 validation paths, 500 test frames each) the paper's tracker's largest
/// level reached 1.82× the validation motion's with 24 states, so 2 keeps every such frame
/// whole; a larger factor lets one stuck feature into the group more often.
pub const DEFAULT_MAX_FACTOR: f64 = 2.0;

impl Default for ThresholdRule {
    fn default() -> Self {
        ThresholdRule::ValidationMax(DEFAULT_MAX_FACTOR)
    }
}

impl ThresholdRule {
    /// Checks the quantile lies in (0, 1] and the factor is finite and at least 1.
    ///
    /// # Errors
    /// [`TrackError::InvalidSetting`].
    pub fn check(self) -> Result<Self, TrackError> {
        match self {
            ThresholdRule::Quantile(q) if !(q > 0.0 && q <= 1.0) => {
                Err(TrackError::InvalidSetting {
                    field: "threshold_rule.quantile",
                    reason: format!("{q} is not in (0, 1]"),
                })
            }
            ThresholdRule::ValidationMax(f) if !(f.is_finite() && f >= 1.0) => {
                Err(TrackError::InvalidSetting {
                    field: "threshold_rule.validation_max",
                    reason: format!(
                        "{f} is not a finite factor ≥ 1 (below 1 it would leave features out of \
                         clean validation frames)"
                    ),
                })
            }
            rule => Ok(rule),
        }
    }

    /// The threshold this rule learns from per-frame `levels` and estimation `errors`.
    ///
    /// # Errors
    /// As [`learn_conflict_threshold`].
    pub fn learn(self, levels: &[f64], errors: &[f64]) -> Result<ConflictLevel, TrackError> {
        let paper = learn_conflict_threshold(levels, errors)?;
        Ok(match self {
            ThresholdRule::ErrorWeighted => paper,
            ThresholdRule::Quantile(q) => quantile_threshold(levels, q),
            ThresholdRule::ValidationMax(factor) => match quantile_threshold(levels, 1.0) {
                ConflictLevel::Finite(max) => ConflictLevel::Finite(factor * max),
                ConflictLevel::Infinite => ConflictLevel::Infinite,
            },
        })
    }
}

/// The `q`-quantile of the finite `levels` (the smallest level at least a share `q` of them do not
/// exceed); [`ConflictLevel::Infinite`] without a finite level.
pub fn quantile_threshold(levels: &[f64], q: f64) -> ConflictLevel {
    let mut finite: Vec<f64> = levels.iter().copied().filter(|k| k.is_finite()).collect();
    if finite.is_empty() {
        return ConflictLevel::Infinite;
    }
    finite.sort_by(f64::total_cmp);
    let rank = ((q * finite.len() as f64).ceil() as usize).clamp(1, finite.len());
    ConflictLevel::Finite(finite[rank - 1])
}

/// The conflict threshold learned from a validation motion (§4.3): the mean of the per-frame levels
/// of conflict of the combined groups, weighted by the per-frame estimation errors,
/// K̂ = Σ K_k e_k / Σ e_k. (The paper prints the numerator only; "the mean value … weighted by the
/// estimation errors" needs the division, without which K̂ would grow with the motion's length.)
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
    fn quantiles_of_the_finite_levels() {
        let levels = [5.0, 1.0, f64::INFINITY, 3.0, 2.0, 4.0];
        assert_eq!(quantile_threshold(&levels, 1.0), ConflictLevel::Finite(5.0));
        assert_eq!(quantile_threshold(&levels, 0.8), ConflictLevel::Finite(4.0));
        assert_eq!(quantile_threshold(&levels, 0.5), ConflictLevel::Finite(3.0));
        assert_eq!(
            quantile_threshold(&levels, 0.01),
            ConflictLevel::Finite(1.0)
        );
        assert_eq!(
            quantile_threshold(&[f64::INFINITY], 0.5),
            ConflictLevel::Infinite
        );
        let rule = ThresholdRule::Quantile(0.5);
        assert_eq!(
            rule.learn(&levels, &[1.0; 6]).unwrap(),
            ConflictLevel::Finite(3.0)
        );
        assert!(rule.learn(&levels, &[1.0]).is_err());
        assert!(ThresholdRule::Quantile(0.0).check().is_err());
        assert!(ThresholdRule::Quantile(f64::NAN).check().is_err());
        let parsed: std::collections::BTreeMap<String, ThresholdRule> = toml::from_str(
            "a = \"error_weighted\"\nb = { quantile = 0.95 }\nc = { validation_max = 1.5 }",
        )
        .unwrap();
        assert_eq!(parsed["a"], ThresholdRule::ErrorWeighted);
        assert_eq!(parsed["b"], ThresholdRule::Quantile(0.95));
        assert_eq!(parsed["c"], ThresholdRule::ValidationMax(1.5));
    }

    #[test]
    fn the_default_rule_is_a_factor_over_the_largest_finite_level() {
        let levels = [5.0, 1.0, f64::INFINITY, 3.0];
        let rule = ThresholdRule::default();
        assert_eq!(rule, ThresholdRule::ValidationMax(DEFAULT_MAX_FACTOR));
        assert_eq!(
            rule.learn(&levels, &[1.0; 4]).unwrap(),
            ConflictLevel::Finite(5.0 * DEFAULT_MAX_FACTOR)
        );
        // Every clean validation frame keeps its features, unlike the paper's typical level.
        let paper = ThresholdRule::ErrorWeighted
            .learn(&levels, &[1.0; 4])
            .unwrap();
        assert!(paper.value() < 5.0);
        assert_eq!(
            ThresholdRule::ValidationMax(1.0)
                .learn(&[f64::INFINITY], &[1.0])
                .unwrap(),
            ConflictLevel::Infinite
        );
        assert!(ThresholdRule::ValidationMax(2.0)
            .learn(&levels, &[1.0])
            .is_err());
        for bad in [0.5, f64::NAN, f64::INFINITY] {
            let e = ThresholdRule::ValidationMax(bad).check().unwrap_err();
            assert!(e.to_string().contains("validation_max"), "{e}");
        }
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
