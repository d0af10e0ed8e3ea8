//! One feature of the evidential model: its Gaussian HMM, its frame of discernment Θᵢ (the HMM
//! states that receive a sample) and its refining ωᵢ onto the sample poses.

use std::fmt;

use super::ModelError;
use crate::evidence::Refining;
use crate::hmm::{AssignmentRule, GaussianHmm};

/// One feature of the model: its HMM, its frame Θᵢ (the kept HMM states) and its refining
/// ωᵢ onto the sample poses.
#[derive(Debug, Clone, PartialEq)]
pub struct FeatureModel {
    pub(super) name: String,
    pub(super) requested_states: usize,
    pub(super) hmm: GaussianHmm,
    pub(super) log_likelihood: f64,
    pub(super) n_observations: usize,
    /// HMM state of every sample pose.
    pub(super) states: Vec<usize>,
    /// HMM state index of every frame element, ascending.
    pub(super) kept_states: Vec<usize>,
    pub(super) removed_states: Vec<usize>,
    /// Samples whose value was missing (state by the nearest-pose rule).
    pub(super) imputed: Vec<usize>,
    pub(super) refining: Refining,
    /// Whether EM met its stopping rule before the iteration cap, when this model was trained
    /// here (not recorded in model files).
    pub(super) em_converged: Option<bool>,
}

impl FeatureModel {
    /// Builds a feature model from an HMM already fitted on `column` (one value per sample
    /// pose; `None` or non-finite = missing): assigns every present value a state by `rule`,
    /// removes states that receive no sample, gives each missing sample the state of the
    /// nearest sample pose with a value, and builds the refining.
    ///
    /// `log_likelihood` is recorded as the fit's final log-likelihood; `requested_states` is the
    /// count asked of the fit (the HMM may have fewer states on degenerate data).
    pub fn from_hmm(
        name: &str,
        requested_states: usize,
        hmm: GaussianHmm,
        log_likelihood: f64,
        column: &[Option<f64>],
        sample_poses: &[[f64; 2]],
        rule: AssignmentRule,
    ) -> Result<Self, ModelError> {
        if column.len() != sample_poses.len() {
            return Err(ModelError::ColumnLength {
                feature: name.to_string(),
                expected: sample_poses.len(),
                got: column.len(),
            });
        }
        let (present, values) = present_values(column);
        if values.is_empty() {
            return Err(ModelError::NoValues {
                feature: name.to_string(),
            });
        }
        let assigned = hmm
            .assign(&values, rule)
            .map_err(|source| ModelError::Hmm {
                feature: name.to_string(),
                source,
            })?;
        let mut states = vec![usize::MAX; column.len()];
        for (&i, &s) in present.iter().zip(&assigned) {
            states[i] = s;
        }
        let mut imputed = Vec::new();
        for i in 0..column.len() {
            if states[i] == usize::MAX {
                let nearest = nearest_pose(sample_poses, &present, sample_poses[i]);
                states[i] = assigned[nearest];
                imputed.push(i);
            }
        }
        Self::from_parts(
            name.to_string(),
            requested_states,
            hmm,
            log_likelihood,
            values.len(),
            states,
            imputed,
        )
    }

    /// Assembles and checks a feature model from the HMM state of every sample.
    pub(super) fn from_parts(
        name: String,
        requested_states: usize,
        hmm: GaussianHmm,
        log_likelihood: f64,
        n_observations: usize,
        states: Vec<usize>,
        imputed: Vec<usize>,
    ) -> Result<Self, ModelError> {
        let k = hmm.n_states();
        if let Some(&s) = states.iter().find(|&&s| s >= k) {
            return Err(crate::model_file::corrupted(format!(
                "feature `{name}`: state {s} assigned to a sample, but the HMM has {k} states"
            ))
            .into());
        }
        let mut used = vec![false; k];
        for &s in &states {
            used[s] = true;
        }
        let kept_states: Vec<usize> = (0..k).filter(|&s| used[s]).collect();
        let removed_states: Vec<usize> = (0..k).filter(|&s| !used[s]).collect();
        let mut frame_of = vec![usize::MAX; k];
        for (theta, &s) in kept_states.iter().enumerate() {
            frame_of[s] = theta;
        }
        let assignment: Vec<usize> = states.iter().map(|&s| frame_of[s]).collect();
        let refining =
            Refining::from_assignment(kept_states.len(), &assignment).map_err(|source| {
                ModelError::Refining {
                    feature: name.clone(),
                    source,
                }
            })?;
        Ok(Self {
            name,
            requested_states,
            hmm,
            log_likelihood,
            n_observations,
            states,
            kept_states,
            removed_states,
            imputed,
            refining,
            em_converged: None,
        })
    }

    /// Feature name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// State count asked of the HMM fit.
    pub fn requested_states(&self) -> usize {
        self.requested_states
    }

    /// The feature's HMM (all its states, including removed ones).
    pub fn hmm(&self) -> &GaussianHmm {
        &self.hmm
    }

    /// Final log-likelihood of the HMM fit.
    pub fn log_likelihood(&self) -> f64 {
        self.log_likelihood
    }

    /// Number of values the HMM was fitted on (samples with a value).
    pub fn n_observations(&self) -> usize {
        self.n_observations
    }

    /// Bayesian information criterion of the HMM fit, −2 ln L + p ln N.
    pub fn bic(&self) -> f64 {
        self.hmm.bic(self.log_likelihood, self.n_observations)
    }

    /// Size of the frame Θᵢ (kept states).
    pub fn frame_size(&self) -> usize {
        self.kept_states.len()
    }

    /// HMM state index of each frame element θⱼ, ascending.
    pub fn kept_states(&self) -> &[usize] {
        &self.kept_states
    }

    /// HMM states removed because no sample was assigned to them.
    pub fn removed_states(&self) -> &[usize] {
        &self.removed_states
    }

    /// HMM state of every sample pose.
    pub fn hmm_states(&self) -> &[usize] {
        &self.states
    }

    /// Frame element θ of every sample pose (the refining as an assignment).
    pub fn assignment(&self) -> &[usize] {
        self.refining.assignment()
    }

    /// Sample poses whose value was missing, given the state of the nearest pose with a value.
    pub fn imputed(&self) -> &[usize] {
        &self.imputed
    }

    /// The refining ωᵢ from Θᵢ onto the sample poses.
    pub fn refining(&self) -> &Refining {
        &self.refining
    }

    /// Number of sample poses in each block ωᵢ({θⱼ}).
    pub fn block_sizes(&self) -> Vec<usize> {
        self.refining.blocks().iter().map(|b| b.count()).collect()
    }

    /// Likelihoods Γⱼ(y) of a value over the frame (kept states), scaled by a common factor so
    /// that the largest is 1: both measurement constructors (§3.6) are invariant to that factor,
    /// and the scaling keeps far outliers from underflowing to all zeros. `None` for a missing
    /// or non-finite value.
    pub fn likelihoods(&self, value: Option<f64>) -> Option<Vec<f64>> {
        let mut out = self.log_likelihoods(value)?;
        let max = out.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        for l in &mut out {
            *l = (*l - max).exp();
        }
        Some(out)
    }

    /// Log densities ln Γⱼ(y) of a value over the frame (kept states), unscaled. `None` for a
    /// missing or non-finite value.
    pub fn log_likelihoods(&self, value: Option<f64>) -> Option<Vec<f64>> {
        let y = value.filter(|y| y.is_finite())?;
        let mut all = vec![0.0; self.hmm.n_states()];
        // Cannot fail: y is finite and the buffer has the model's length.
        self.hmm.log_likelihoods(y, &mut all).ok()?;
        Some(self.kept_states.iter().map(|&s| all[s]).collect())
    }

    /// One-line summary for printing.
    pub fn summary(&self) -> FeatureSummary {
        FeatureSummary {
            name: self.name.clone(),
            requested_states: self.requested_states,
            states: self.frame_size(),
            removed_states: self.removed_states.clone(),
            log_likelihood: self.log_likelihood,
            bic: self.bic(),
            n_observations: self.n_observations,
            imputed: self.imputed.len(),
            block_sizes: self.block_sizes(),
            em_converged: self.em_converged,
        }
    }
}

/// Per-feature summary of a trained model, for printing.
#[derive(Debug, Clone, PartialEq)]
pub struct FeatureSummary {
    /// Feature name.
    pub name: String,
    /// State count asked of the HMM.
    pub requested_states: usize,
    /// Size of the frame (kept states).
    pub states: usize,
    /// HMM states removed for receiving no sample.
    pub removed_states: Vec<usize>,
    /// Final log-likelihood of the HMM fit.
    pub log_likelihood: f64,
    /// BIC of the HMM fit.
    pub bic: f64,
    /// Values the HMM was fitted on.
    pub n_observations: usize,
    /// Samples with a missing value (imputed by the nearest-pose rule).
    pub imputed: usize,
    /// Sample poses per frame element.
    pub block_sizes: Vec<usize>,
    /// Whether EM met its stopping rule before the iteration cap (`None` for a loaded model).
    pub em_converged: Option<bool>,
}

impl fmt::Display for FeatureSummary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{}: {} states (asked {}), log-likelihood {:.3}, BIC {:.3}, blocks {:?}",
            self.name,
            self.states,
            self.requested_states,
            self.log_likelihood,
            self.bic,
            self.block_sizes
        )?;
        if !self.removed_states.is_empty() {
            write!(f, ", removed states {:?}", self.removed_states)?;
        }
        if self.imputed > 0 {
            write!(f, ", {} missing values imputed", self.imputed)?;
        }
        Ok(())
    }
}

/// Indices and values of the present (finite) entries of a column.
pub(super) fn present_values(column: &[Option<f64>]) -> (Vec<usize>, Vec<f64>) {
    column
        .iter()
        .enumerate()
        .filter_map(|(i, v)| v.filter(|y| y.is_finite()).map(|y| (i, y)))
        .unzip()
}

/// Position in `present` of the sample pose nearest to `q` (ties to the lower index).
fn nearest_pose(poses: &[[f64; 2]], present: &[usize], q: [f64; 2]) -> usize {
    let mut best = 0;
    let mut best_d = f64::INFINITY;
    for (k, &i) in present.iter().enumerate() {
        let p = poses[i];
        let d = (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2);
        if d < best_d {
            best = k;
            best_d = d;
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nearest_pose_prefers_lower_index_on_ties() {
        let poses = [[0.0, 0.0], [1.0, 0.0], [-1.0, 0.0], [5.0, 5.0]];
        assert_eq!(nearest_pose(&poses, &[1, 2, 3], [0.0, 0.0]), 0);
        assert_eq!(nearest_pose(&poses, &[1, 2, 3], [4.0, 4.0]), 2);
    }
}
