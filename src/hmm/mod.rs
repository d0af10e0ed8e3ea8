//! Gaussian hidden Markov models for scalar features (paper §3.2–3.4).
//!
//! This room quantises one scalar feature: [`GaussianHmm::fit`] learns an HMM with Gaussian
//! emissions by Baum–Welch (EM) from a sequence of observations, and the fitted model gives per
//! state the likelihood Γⱼ(y) of an observation ([`GaussianHmm::likelihoods`]) and the state
//! assignment of each training sample ([`GaussianHmm::assign`]), by largest Γⱼ (the paper's rule,
//! §3.3) or by Viterbi. The states of a fitted model are sorted by increasing mean.
//!
//! Numerics: the forward–backward pass works in scaled space; emission densities are normalised
//! per observation by their largest value (kept as a log offset), so no observation, however far
//! from every state, makes the pass underflow.
//!
//! Degenerate data has a defined outcome: an empty sequence, zero states or a non-finite
//! observation is an error (naming the index); data with fewer distinct values than requested
//! states (a constant feature, two distinct values, fewer samples than states) gives a model with
//! as many states as distinct values, see [`GaussianHmm::fit`].

mod em;
mod init;
mod prepare;
mod settings;
mod shared;

pub use settings::{AssignmentRule, HmmSettings};

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use thiserror::Error;

use em::{em, EmissionConsts, Params, Run, Workspace};
use prepare::{prepare, start, Prepared};

/// Tolerance on the sum of a probability vector (initial probabilities, transition rows) accepted
/// by [`GaussianHmm::validate`].
pub const STOCHASTIC_TOLERANCE: f64 = 1e-6;

/// Squared standardised distances are capped here so that any finite observation gives a finite
/// log density.
const MAX_SQUARED_DISTANCE: f64 = 1e300;

const LN_2PI: f64 = 1.837_877_066_409_345_5;

/// Errors of HMM fitting, evaluation and validation.
#[derive(Debug, Error, Clone, PartialEq)]
#[non_exhaustive]
pub enum HmmError {
    /// No observations were given.
    #[error("no observations to fit: give at least one sample")]
    Empty,
    /// Zero states were requested.
    #[error("an HMM needs at least one state: ask for n_states >= 1")]
    NoStates,
    /// An observation is NaN or infinite.
    #[error("observation {index} is not finite ({value}); drop or repair it before fitting")]
    NonFinite {
        /// Position of the offending observation.
        index: usize,
        /// Its value.
        value: f64,
    },
    /// The observations are so large that their variance overflows.
    #[error("the observations' variance is not finite (values too large); rescale the feature")]
    DataRange,
    /// A setting is out of range.
    #[error("invalid HMM setting `{field}`: {reason}")]
    Settings {
        /// The offending field.
        field: &'static str,
        /// What is wrong and what is allowed.
        reason: String,
    },
    /// Every restart of EM failed numerically.
    #[error("EM failed numerically in all {restarts} restarts; check the data for extreme values")]
    Numerical {
        /// How many restarts were tried.
        restarts: usize,
    },
    /// The log-likelihood of a sequence is not finite (values extremely far from every state).
    #[error("the sequence's log-likelihood is not finite: its values lie extremely far from every state")]
    NonFiniteLikelihood,
    /// Model parameters are not a valid Gaussian HMM (e.g. a deserialised model).
    #[error("invalid HMM parameters: {0}")]
    InvalidModel(String),
    /// An output buffer has the wrong length.
    #[error("output buffer has length {got} but the model has {expected} states")]
    OutputLength {
        /// Number of states of the model.
        expected: usize,
        /// Length of the buffer given.
        got: usize,
    },
}

/// The result of [`GaussianHmm::fit`].
#[derive(Debug, Clone, PartialEq)]
pub struct HmmFit {
    /// The fitted model (states sorted by increasing mean).
    pub hmm: GaussianHmm,
    /// Log-likelihood of the training data under `hmm`.
    pub log_likelihood: f64,
    /// Log-likelihood before each EM update and after the last one, of the kept restart; never
    /// decreases (up to rounding).
    pub trace: Vec<f64>,
    /// EM iterations (parameter updates) of the kept restart.
    pub iterations: usize,
    /// Whether the kept restart met the tolerance before the iteration cap.
    pub converged: bool,
}

/// A hidden Markov model with scalar Gaussian emissions.
///
/// Deserialisation validates the parameters (see [`GaussianHmm::validate`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "HmmParameters")]
pub struct GaussianHmm {
    initial: Vec<f64>,
    transitions: Vec<Vec<f64>>,
    means: Vec<f64>,
    variances: Vec<f64>,
}

/// Unvalidated parameters as they appear in a file.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct HmmParameters {
    initial: Vec<f64>,
    transitions: Vec<Vec<f64>>,
    means: Vec<f64>,
    variances: Vec<f64>,
}

impl TryFrom<HmmParameters> for GaussianHmm {
    type Error = HmmError;
    fn try_from(p: HmmParameters) -> Result<Self, HmmError> {
        GaussianHmm::new(p.initial, p.transitions, p.means, p.variances)
    }
}

impl GaussianHmm {
    /// Builds a model from its parameters, validated as by [`GaussianHmm::validate`].
    pub fn new(
        initial: Vec<f64>,
        transitions: Vec<Vec<f64>>,
        means: Vec<f64>,
        variances: Vec<f64>,
    ) -> Result<Self, HmmError> {
        let hmm = Self {
            initial,
            transitions,
            means,
            variances,
        };
        hmm.validate()?;
        Ok(hmm)
    }

    /// Checks the parameters: at least one state, consistent sizes, finite means, finite
    /// positive variances, and initial probabilities and transition rows that are non-negative
    /// and sum to 1 within [`STOCHASTIC_TOLERANCE`].
    pub fn validate(&self) -> Result<(), HmmError> {
        let k = self.means.len();
        let bad = |msg: String| Err(HmmError::InvalidModel(msg));
        if k == 0 {
            return bad("the model has no states".into());
        }
        if self.initial.len() != k || self.variances.len() != k || self.transitions.len() != k {
            return bad(format!(
                "sizes disagree: {} means, {} variances, {} initial probabilities, {} transition rows",
                k,
                self.variances.len(),
                self.initial.len(),
                self.transitions.len()
            ));
        }
        if let Some(j) = self.means.iter().position(|m| !m.is_finite()) {
            return bad(format!("mean of state {j} is not finite"));
        }
        if let Some(j) = self
            .variances
            .iter()
            .position(|v| !(v.is_finite() && *v > 0.0))
        {
            return bad(format!(
                "variance of state {j} is {}, must be finite and > 0",
                self.variances[j]
            ));
        }
        check_stochastic(&self.initial, "initial probabilities")?;
        for (i, row) in self.transitions.iter().enumerate() {
            if row.len() != k {
                return bad(format!(
                    "transition row {i} has {} entries, expected {k}",
                    row.len()
                ));
            }
            check_stochastic(row, &format!("transition row {i}"))?;
        }
        Ok(())
    }

    /// Number of states.
    pub fn n_states(&self) -> usize {
        self.means.len()
    }

    /// Initial state probabilities.
    pub fn initial(&self) -> &[f64] {
        &self.initial
    }

    /// Transition matrix, row i = probabilities of the next state given state i.
    pub fn transitions(&self) -> &[Vec<f64>] {
        &self.transitions
    }

    /// Emission means, one per state.
    pub fn means(&self) -> &[f64] {
        &self.means
    }

    /// Emission variances, one per state.
    pub fn variances(&self) -> &[f64] {
        &self.variances
    }

    /// Number of free parameters (k − 1 initial, k(k − 1) transition, 2k emission), for
    /// information criteria.
    pub fn n_parameters(&self) -> usize {
        let k = self.n_states();
        k * k + 2 * k - 1
    }

    /// Bayesian information criterion −2 ln L + p ln n of this model for a log-likelihood
    /// `log_likelihood` on `n_observations` samples; lower is better.
    pub fn bic(&self, log_likelihood: f64, n_observations: usize) -> f64 {
        -2.0 * log_likelihood + self.n_parameters() as f64 * (n_observations.max(1) as f64).ln()
    }

    /// Log emission densities ln Γⱼ(y) of every state into `out`. Errors on a non-finite `y`
    /// (reported with index 0) or an `out` of the wrong length.
    pub fn log_likelihoods(&self, y: f64, out: &mut [f64]) -> Result<(), HmmError> {
        self.check_out(out)?;
        if !y.is_finite() {
            return Err(HmmError::NonFinite { index: 0, value: y });
        }
        // Per call, without the allocations of `EmissionConsts`: this is the tracker's per-frame
        // path.
        for ((o, m), v) in out.iter_mut().zip(&self.means).zip(&self.variances) {
            let d2 = (y - m) * (y - m) / v;
            *o = -0.5 * (LN_2PI + v.ln()) - 0.5 * d2.min(MAX_SQUARED_DISTANCE);
        }
        Ok(())
    }

    /// Emission densities Γⱼ(y) (Gaussian density of state j at `y`) into `out`. Errors on a
    /// non-finite `y` or an `out` of the wrong length. Far from every state all densities may
    /// underflow to 0; use [`GaussianHmm::log_likelihoods`] when only their ratios matter.
    pub fn likelihoods(&self, y: f64, out: &mut [f64]) -> Result<(), HmmError> {
        self.log_likelihoods(y, out)?;
        for o in out.iter_mut() {
            *o = o.exp();
        }
        Ok(())
    }

    /// State of each observation by `rule`. Errors on a non-finite observation.
    pub fn assign(
        &self,
        observations: &[f64],
        rule: AssignmentRule,
    ) -> Result<Vec<usize>, HmmError> {
        match rule {
            AssignmentRule::MaxLikelihood => {
                check_finite(observations)?;
                let consts = EmissionConsts::new(&self.means, &self.variances);
                Ok(observations
                    .iter()
                    .map(|&y| {
                        let mut best = 0;
                        let mut best_l = f64::NEG_INFINITY;
                        for j in 0..self.n_states() {
                            let l = consts.log_density(j, y);
                            if l > best_l {
                                best = j;
                                best_l = l;
                            }
                        }
                        best
                    })
                    .collect())
            }
            AssignmentRule::Viterbi => self.viterbi(observations),
        }
    }

    /// Most likely state sequence (Viterbi, in log space; ties go to the lower state index).
    /// Errors on a non-finite observation; an empty sequence gives an empty path.
    pub fn viterbi(&self, observations: &[f64]) -> Result<Vec<usize>, HmmError> {
        check_finite(observations)?;
        let n = observations.len();
        let k = self.n_states();
        if n == 0 {
            return Ok(Vec::new());
        }
        let consts = EmissionConsts::new(&self.means, &self.variances);
        let log_a: Vec<f64> = self
            .transitions
            .iter()
            .flat_map(|row| row.iter().map(|p| p.ln()))
            .collect();
        let mut delta: Vec<f64> = (0..k)
            .map(|j| self.initial[j].ln() + consts.log_density(j, observations[0]))
            .collect();
        let mut next = vec![0.0; k];
        let mut back = vec![0usize; n * k];
        for (t, &y) in observations.iter().enumerate().skip(1) {
            for j in 0..k {
                let mut best = 0;
                let mut best_v = f64::NEG_INFINITY;
                for i in 0..k {
                    let v = delta[i] + log_a[i * k + j];
                    if v > best_v {
                        best = i;
                        best_v = v;
                    }
                }
                back[t * k + j] = best;
                next[j] = best_v + consts.log_density(j, y);
            }
            std::mem::swap(&mut delta, &mut next);
        }
        let mut state = argmax(&delta);
        let mut path = vec![0; n];
        for t in (0..n).rev() {
            path[t] = state;
            state = back[t * k + state];
        }
        Ok(path)
    }

    /// Log-likelihood of a whole observation sequence under this model (forward algorithm).
    /// Errors on an empty sequence or a non-finite observation.
    pub fn log_likelihood(&self, observations: &[f64]) -> Result<f64, HmmError> {
        if observations.is_empty() {
            return Err(HmmError::Empty);
        }
        check_finite(observations)?;
        let mut ws = Workspace::new(observations.len(), self.n_states());
        let params = Params::from_hmm(self);
        ws.forward(observations, &params)
            .ok_or(HmmError::NonFiniteLikelihood)
    }

    /// Fits an HMM with `n_states` states to `observations` (one sequence) by Baum–Welch.
    ///
    /// Each of `settings.restarts` runs starts from a k-means++ initialisation drawn from a
    /// ChaCha8 generator seeded with `seed` (same seed → bit-identical fit); the run with the
    /// highest final log-likelihood is kept. State variances never go below
    /// `settings.variance_floor` × the data variance.
    ///
    /// Degenerate data: if the observations have fewer distinct values than `n_states` (a
    /// constant feature, two distinct values, fewer samples than states), the model gets one state
    /// per distinct value, so [`GaussianHmm::n_states`] may be below `n_states`. Errors: no
    /// observations, `n_states == 0`, a non-finite observation (its index), invalid settings.
    pub fn fit(
        observations: &[f64],
        n_states: usize,
        settings: &HmmSettings,
        seed: u64,
    ) -> Result<HmmFit, HmmError> {
        let Prepared {
            mean,
            floor,
            k,
            centred,
        } = prepare(observations, n_states, settings)?;
        let n = observations.len();
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut ws = Workspace::new(n, k);
        let mut best: Option<(Params, Run)> = None;
        let mut tried: Vec<Params> = Vec::with_capacity(settings.restarts);
        for restart in 0..settings.restarts {
            let init = start(restart, &centred, k, floor, &mut rng);
            // k-means often lands on the same clustering from different seeds; EM from an
            // identical start gives an identical result, so it is not run twice.
            if tried.contains(&init) {
                continue;
            }
            tried.push(init.clone());
            let Some((params, run)) = em(&centred, init, floor, settings, &mut ws) else {
                continue;
            };
            let better = match &best {
                None => true,
                Some((_, b)) => run.log_likelihood > b.log_likelihood,
            };
            if better {
                best = Some((params, run));
            }
        }
        let Some((mut params, run)) = best else {
            return Err(HmmError::Numerical {
                restarts: settings.restarts,
            });
        };
        for m in &mut params.means {
            *m += mean;
        }
        let hmm = params.into_sorted_hmm();
        hmm.validate()?;
        Ok(HmmFit {
            hmm,
            log_likelihood: run.log_likelihood,
            trace: run.trace,
            iterations: run.iterations,
            converged: run.converged,
        })
    }

    fn check_out(&self, out: &[f64]) -> Result<(), HmmError> {
        if out.len() != self.n_states() {
            return Err(HmmError::OutputLength {
                expected: self.n_states(),
                got: out.len(),
            });
        }
        Ok(())
    }
}

fn check_stochastic(p: &[f64], what: &str) -> Result<(), HmmError> {
    if let Some(j) = p.iter().position(|x| !(x.is_finite() && *x >= 0.0)) {
        return Err(HmmError::InvalidModel(format!(
            "{what}: entry {j} is {}, must be finite and >= 0",
            p[j]
        )));
    }
    let s: f64 = p.iter().sum();
    if (s - 1.0).abs() > STOCHASTIC_TOLERANCE {
        return Err(HmmError::InvalidModel(format!(
            "{what} sum to {s}, must sum to 1"
        )));
    }
    Ok(())
}

fn check_finite(observations: &[f64]) -> Result<(), HmmError> {
    match observations.iter().position(|y| !y.is_finite()) {
        Some(index) => Err(HmmError::NonFinite {
            index,
            value: observations[index],
        }),
        None => Ok(()),
    }
}

/// Number of distinct values in `y`, counted only up to `cap`.
fn count_distinct_up_to(y: &[f64], cap: usize) -> usize {
    if cap <= 16 {
        // Usually `cap` distinct values turn up within the first few samples: no sort needed.
        let mut seen: Vec<f64> = Vec::with_capacity(cap);
        for v in y {
            if seen.len() == cap {
                break;
            }
            if !seen.contains(v) {
                seen.push(*v);
            }
        }
        seen.len()
    } else {
        let mut sorted = y.to_vec();
        sorted.sort_by(f64::total_cmp);
        sorted.dedup();
        sorted.len().min(cap)
    }
}

fn argmax(v: &[f64]) -> usize {
    let mut best = 0;
    for (j, x) in v.iter().enumerate() {
        if *x > v[best] {
            best = j;
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #[test]
        fn count_distinct_agrees_with_sort_and_dedup(
            ys in proptest::collection::vec(prop_oneof![-3i32..3, -1000i32..1000], 0..80),
            cap in 0usize..40,
        ) {
            let ys: Vec<f64> = ys.into_iter().map(|v| v as f64 * 0.5).collect();
            let mut sorted = ys.clone();
            sorted.sort_by(f64::total_cmp);
            sorted.dedup();
            prop_assert_eq!(count_distinct_up_to(&ys, cap), sorted.len().min(cap));
        }
    }

    #[test]
    fn settings_check_rejects_out_of_range() {
        let bad = [
            HmmSettings {
                restarts: 0,
                ..Default::default()
            },
            HmmSettings {
                max_iterations: 0,
                ..Default::default()
            },
            HmmSettings {
                patience: 0,
                ..Default::default()
            },
            HmmSettings {
                tolerance: f64::NAN,
                ..Default::default()
            },
            HmmSettings {
                variance_floor: 0.0,
                ..Default::default()
            },
            HmmSettings {
                variance_floor: 2.0,
                ..Default::default()
            },
        ];
        for s in bad {
            assert!(matches!(s.check(), Err(HmmError::Settings { .. })), "{s:?}");
        }
        assert!(HmmSettings::default().check().is_ok());
    }
}
