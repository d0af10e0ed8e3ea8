//! Training settings of the evidential model: state counts, given or tuned (§5.2), and EM.

use serde::{Deserialize, Serialize};

use super::ModelError;
use crate::hmm::HmmSettings;

/// State counts: one for every feature, or one per feature in feature order.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum StateCounts {
    /// The same count for every feature.
    All(usize),
    /// One count per feature.
    PerFeature(Vec<usize>),
}

impl Default for StateCounts {
    fn default() -> Self {
        StateCounts::All(3)
    }
}

impl StateCounts {
    /// The count of each of `n_features` features; errors when a list has the wrong length or a
    /// count is 0.
    pub fn resolve(
        &self,
        n_features: usize,
        field: &'static str,
    ) -> Result<Vec<usize>, ModelError> {
        let counts = match self {
            StateCounts::All(n) => vec![*n; n_features],
            StateCounts::PerFeature(v) => {
                if v.len() != n_features {
                    return Err(ModelError::Settings {
                        field,
                        reason: format!(
                            "{} counts for {n_features} features: give one count or one per feature",
                            v.len()
                        ),
                    });
                }
                v.clone()
            }
        };
        if let Some(i) = counts.iter().position(|&n| !(1..=MAX_STATES).contains(&n)) {
            return Err(ModelError::Settings {
                field,
                reason: format!(
                    "count for feature {i} is {}, must be in 1..={MAX_STATES}",
                    counts[i]
                ),
            });
        }
        Ok(counts)
    }
}

/// Most HMM states a feature may have: a frame of discernment larger than this has more states
/// than any sample trajectory can train.
pub const MAX_STATES: usize = 64;

/// How the state count of each feature is chosen (§5.2), each feature separately.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(tag = "method", rename_all = "snake_case", deny_unknown_fields)]
pub enum Tuning {
    /// Use [`ModelSettings::states`] as given.
    #[default]
    Given,
    /// The count within bounds (inclusive) with the lowest Bayesian information criterion
    /// −2 ln L + p ln N of the HMM fit; ties go to fewer states.
    Bic {
        /// Lower bounds.
        min_states: StateCounts,
        /// Upper bounds.
        max_states: StateCounts,
    },
    /// The count within bounds (inclusive) with the lowest score from a `StateCountTuner`
    /// (the tracker's estimation error on a validation motion); ties go to fewer states.
    Validation {
        /// Lower bounds.
        min_states: StateCounts,
        /// Upper bounds.
        max_states: StateCounts,
    },
}

/// Settings of model training.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ModelSettings {
    /// HMM state count per feature (used when `tuning` is `given`): `states = 3` or
    /// `states = [3, 4, ...]`; default 3.
    pub states: StateCounts,
    /// EM settings shared by every feature, including the state assignment rule.
    pub hmm: HmmSettings,
    /// Seed of every random draw of training (each feature and state count gets a seed derived
    /// from it); default 0.
    pub seed: u64,
    /// How state counts are chosen, e.g. `[tuning] method = "bic", min_states = 2,
    /// max_states = 6`; default `given`.
    pub tuning: Tuning,
}

impl ModelSettings {
    /// Checks what can be checked without the data: HMM settings, non-zero counts, bounds in
    /// order (per-feature lists are checked against the number of features at training).
    pub fn check(&self) -> Result<(), ModelError> {
        self.hmm.check().map_err(|e| ModelError::Settings {
            field: "hmm",
            reason: e.to_string(),
        })?;
        let nonzero = |c: &StateCounts, field: &'static str| {
            let ok = match c {
                StateCounts::All(n) => (1..=MAX_STATES).contains(n),
                StateCounts::PerFeature(v) => v.iter().all(|n| (1..=MAX_STATES).contains(n)),
            };
            if !ok {
                Err(ModelError::Settings {
                    field,
                    reason: format!("state counts must be in 1..={MAX_STATES}"),
                })
            } else {
                Ok(())
            }
        };
        nonzero(&self.states, "states")?;
        if let Tuning::Bic {
            min_states,
            max_states,
        }
        | Tuning::Validation {
            min_states,
            max_states,
        } = &self.tuning
        {
            nonzero(min_states, "tuning.min_states")?;
            nonzero(max_states, "tuning.max_states")?;
            if let (StateCounts::All(lo), StateCounts::All(hi)) = (min_states, max_states) {
                if lo > hi {
                    return Err(ModelError::Settings {
                        field: "tuning",
                        reason: format!("min_states {lo} is above max_states {hi}"),
                    });
                }
            }
        }
        Ok(())
    }

    /// Inclusive state-count range of each of `n_features` features (one count when they are
    /// given); errors when a list has the wrong length, a count is 0 or a range is reversed.
    pub fn state_ranges(&self, n_features: usize) -> Result<Vec<(usize, usize)>, ModelError> {
        match &self.tuning {
            Tuning::Given => Ok(self
                .states
                .resolve(n_features, "states")?
                .into_iter()
                .map(|n| (n, n))
                .collect()),
            Tuning::Bic {
                min_states,
                max_states,
            }
            | Tuning::Validation {
                min_states,
                max_states,
            } => {
                let lo = min_states.resolve(n_features, "tuning.min_states")?;
                let hi = max_states.resolve(n_features, "tuning.max_states")?;
                lo.into_iter()
                    .zip(hi)
                    .enumerate()
                    .map(|(f, (lo, hi))| {
                        if lo > hi {
                            Err(ModelError::Settings {
                                field: "tuning",
                                reason: format!(
                                    "feature {f}: min_states {lo} is above max_states {hi}"
                                ),
                            })
                        } else {
                            Ok((lo, hi))
                        }
                    })
                    .collect()
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn settings_check_and_ranges() {
        let mut s = ModelSettings::default();
        assert!(s.check().is_ok());
        s.states = StateCounts::All(0);
        assert!(matches!(s.check(), Err(ModelError::Settings { .. })));
        s.states = StateCounts::PerFeature(vec![2, 3]);
        assert!(s.check().is_ok());
        assert!(matches!(
            s.state_ranges(3),
            Err(ModelError::Settings { .. })
        ));
        assert_eq!(s.state_ranges(2).unwrap(), vec![(2, 2), (3, 3)]);
        s.tuning = Tuning::Bic {
            min_states: StateCounts::All(4),
            max_states: StateCounts::All(2),
        };
        assert!(matches!(s.check(), Err(ModelError::Settings { .. })));
        s.tuning = Tuning::Bic {
            min_states: StateCounts::All(1),
            max_states: StateCounts::PerFeature(vec![3, 0]),
        };
        assert!(s.check().is_err());
        s.tuning = Tuning::Bic {
            min_states: StateCounts::PerFeature(vec![1, 5]),
            max_states: StateCounts::All(4),
        };
        assert!(s.check().is_ok());
        assert!(matches!(
            s.state_ranges(2),
            Err(ModelError::Settings { .. })
        ));
    }
}
