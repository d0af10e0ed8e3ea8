//! Settings of EM fitting and the rule attributing samples to states.

use serde::{Deserialize, Serialize};

use super::HmmError;
use crate::range::within;

/// How each training sample is attributed to a state.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AssignmentRule {
    /// The state with the largest emission likelihood Γⱼ(y) (paper §3.3); ties go to the lower
    /// state index.
    #[default]
    MaxLikelihood,
    /// The most likely state sequence (Viterbi), which also uses the transition matrix.
    Viterbi,
}

/// Settings of EM fitting.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct HmmSettings {
    /// Number of EM runs from different initialisations, cycling through seeded k-means++, the
    /// best partition of the sorted values into groups with their own variance, the data's
    /// quantiles and random data points (then k-means++ again, …); the run with the best final
    /// log-likelihood is kept (an identical start runs once). At least 1; default 2 (k-means++
    /// and the partition: on the 1 mm mesh's features at 2 and 3 states these reach the best of
    /// 20 varied restarts to 1e-3).
    pub restarts: usize,
    /// Cap on EM iterations per run. At least 1; default 500.
    pub max_iterations: usize,
    /// EM stops when `patience` iterations in a row each raise the log-likelihood by less than
    /// `tolerance` per observation. Finite, at least 0; default 5e-7 (1e-4, the old default,
    /// stopped `size_line0` at 2 states on a plateau 0.8 % below its optimum, where EM gained
    /// about 1e-6 per observation and iteration for ten iterations before climbing again).
    pub tolerance: f64,
    /// How many slow iterations in a row end EM: a plateau that EM leaves after a few slow
    /// steps is not convergence. At least 1; default 1.
    pub patience: usize,
    /// Lower bound on every state variance, relative to the variance of the training data (when
    /// the data is constant: relative to max(mean², 1)). Finite, in (0, 1]; default 1e-3.
    pub variance_floor: f64,
    /// How training samples are attributed to states; default [`AssignmentRule::MaxLikelihood`].
    pub assignment: AssignmentRule,
}

impl Default for HmmSettings {
    fn default() -> Self {
        Self {
            restarts: 2,
            max_iterations: 500,
            tolerance: 5e-7,
            patience: 1,
            variance_floor: 1e-3,
            assignment: AssignmentRule::MaxLikelihood,
        }
    }
}

impl HmmSettings {
    /// Checks that every setting is in range.
    pub fn check(&self) -> Result<(), HmmError> {
        for (field, value, range) in [
            ("restarts", self.restarts, 1..=100),
            ("max_iterations", self.max_iterations, 1..=100_000),
            ("patience", self.patience, 1..=1000),
        ] {
            within(value, range).map_err(|reason| HmmError::Settings { field, reason })?;
        }
        if !(self.tolerance.is_finite() && self.tolerance >= 0.0) {
            return Err(HmmError::Settings {
                field: "tolerance",
                reason: format!("must be finite and >= 0, got {}", self.tolerance),
            });
        }
        if !(self.variance_floor.is_finite()
            && self.variance_floor > 0.0
            && self.variance_floor <= 1.0)
        {
            return Err(HmmError::Settings {
                field: "variance_floor",
                reason: format!("must be in (0, 1], got {}", self.variance_floor),
            });
        }
        Ok(())
    }
}
