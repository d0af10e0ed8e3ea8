//! Measurement belief functions from likelihood vectors (§3.6): Bayesian and consonant
//! (Shafer's) constructors, with a documented fallback for unusable likelihoods.

use serde::{Deserialize, Serialize};

use super::mass::MassFunction;
use super::subset::Subset;
use super::EvidenceError;

/// How a likelihood vector Γ becomes a mass function.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Constructor {
    /// m({θ}) = Γ(θ) / Σ Γ (§3.6.1).
    #[default]
    Bayesian,
    /// Shafer's consonant function: nested focal sets by decreasing likelihood, with
    /// Pl({θ}) = Γ(θ) / max Γ (§3.6.2).
    Consonant,
}

/// Why a likelihood vector could not be used (the result is then vacuous).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LikelihoodIssue {
    /// Some value is NaN or ±∞ (checked first).
    NonFinite,
    /// Some value is negative (checked second).
    Negative,
    /// All values are zero (checked last).
    AllZero,
}

/// A measurement function and whether it had to fall back to the vacuous function.
#[derive(Clone, Debug, PartialEq)]
pub struct Measurement {
    /// The mass function on the feature's frame.
    pub mass: MassFunction,
    /// `Some` when the likelihoods were unusable and `mass` is vacuous.
    pub issue: Option<LikelihoodIssue>,
}

/// Build a measurement function on a frame of `likelihoods.len()` elements.
///
/// Unusable likelihoods never fail and never panic: a vector holding NaN or ±∞, a negative value,
/// or only zeros gives the vacuous function (no evidence) with the matching [`LikelihoodIssue`].
/// Ties in the consonant constructor keep tied states in the same focal sets.
///
/// # Errors
/// [`EvidenceError::EmptyFrame`] for an empty vector.
pub fn from_likelihoods(
    constructor: Constructor,
    likelihoods: &[f64],
) -> Result<Measurement, EvidenceError> {
    let n = likelihoods.len();
    if n == 0 {
        return Err(EvidenceError::EmptyFrame);
    }
    let issue = if likelihoods.iter().any(|x| !x.is_finite()) {
        Some(LikelihoodIssue::NonFinite)
    } else if likelihoods.iter().any(|&x| x < 0.0) {
        Some(LikelihoodIssue::Negative)
    } else if likelihoods.iter().all(|&x| x == 0.0) {
        Some(LikelihoodIssue::AllZero)
    } else {
        None
    };
    if issue.is_some() {
        return Ok(Measurement {
            mass: MassFunction::vacuous(n)?,
            issue,
        });
    }
    let mass = match constructor {
        Constructor::Bayesian => bayesian(likelihoods),
        Constructor::Consonant => consonant(likelihoods),
    };
    Ok(Measurement { mass, issue: None })
}

fn bayesian(g: &[f64]) -> MassFunction {
    let n = g.len();
    // Divide by the max first so huge finite values cannot overflow the sum.
    let max = g.iter().fold(0.0f64, |a, &b| a.max(b));
    let sum: f64 = g.iter().map(|x| x / max).sum();
    let mut focal = Vec::with_capacity(n);
    let mut mass = Vec::with_capacity(n);
    for (i, &x) in g.iter().enumerate() {
        let m = x / max / sum;
        if m > 0.0 {
            focal.push(Subset::singleton(n, i));
            mass.push(m);
        }
    }
    MassFunction::from_parts(n, focal, mass)
}

fn consonant(g: &[f64]) -> MassFunction {
    let n = g.len();
    let max = g.iter().fold(0.0f64, |a, &b| a.max(b));
    let mut order: Vec<usize> = (0..n).collect();
    // Stable: ties keep ascending index order.
    order.sort_by(|&a, &b| g[b].total_cmp(&g[a]));
    let mut focal = Vec::new();
    let mut mass = Vec::new();
    let mut set = Subset::empty(n);
    for (k, &i) in order.iter().enumerate() {
        set.insert(i);
        let here = g[i] / max;
        let next = order.get(k + 1).map_or(0.0, |&j| g[j] / max);
        let m = here - next;
        if m > 0.0 {
            focal.push(set.clone());
            mass.push(m);
        }
    }
    MassFunction::from_parts(n, focal, mass)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bayesian_by_hand() {
        let m = from_likelihoods(Constructor::Bayesian, &[1.0, 3.0, 0.0, 4.0]).unwrap();
        assert_eq!(m.issue, None);
        let c = m.mass.contour();
        assert_eq!(c, vec![0.125, 0.375, 0.0, 0.5]);
        assert_eq!(m.mass.len(), 3);
    }

    #[test]
    fn consonant_by_hand() {
        // Γ = (1, 3, 0, 4): focal sets {3}: 0.25, {1,3}: 0.5, {0,1,3}: 0.25.
        let m = from_likelihoods(Constructor::Consonant, &[1.0, 3.0, 0.0, 4.0])
            .unwrap()
            .mass;
        assert_eq!(m.len(), 3);
        let c = m.contour();
        let want = [0.25, 0.75, 0.0, 1.0];
        for (x, y) in c.iter().zip(want) {
            assert!((x - y).abs() < 1e-15, "{c:?}");
        }
        let sets: Vec<Vec<usize>> = m.focal_sets().iter().map(Subset::to_vec).collect();
        assert_eq!(sets, vec![vec![3], vec![1, 3], vec![0, 1, 3]]);
        // Belief of a set: 1 − max Γ outside / max Γ.
        let a = Subset::from_indices(4, [1, 3]).unwrap();
        assert!((m.belief(&a) - (1.0 - 0.25)).abs() < 1e-15);
    }

    #[test]
    fn consonant_ties_share_focal_sets() {
        let m = from_likelihoods(Constructor::Consonant, &[2.0, 2.0, 1.0])
            .unwrap()
            .mass;
        let sets: Vec<Vec<usize>> = m.focal_sets().iter().map(Subset::to_vec).collect();
        assert_eq!(sets, vec![vec![0, 1], vec![0, 1, 2]]);
        assert_eq!(m.masses(), &[0.5, 0.5]);
    }

    #[test]
    fn unusable_likelihoods_give_flagged_vacuous_functions() {
        for c in [Constructor::Bayesian, Constructor::Consonant] {
            let cases: [(&[f64], LikelihoodIssue); 5] = [
                (&[0.0, 0.0], LikelihoodIssue::AllZero),
                (&[f64::NAN, 1.0], LikelihoodIssue::NonFinite),
                (&[f64::INFINITY, 1.0], LikelihoodIssue::NonFinite),
                (&[-1.0, f64::NEG_INFINITY], LikelihoodIssue::NonFinite),
                (&[-1.0, 2.0], LikelihoodIssue::Negative),
            ];
            for (g, issue) in cases {
                let m = from_likelihoods(c, g).unwrap();
                assert_eq!(m.issue, Some(issue));
                assert!(m.mass.is_vacuous());
            }
            assert_eq!(from_likelihoods(c, &[]), Err(EvidenceError::EmptyFrame));
            // Huge finite values do not overflow.
            let m = from_likelihoods(c, &[f64::MAX, f64::MAX]).unwrap();
            assert_eq!(m.issue, None);
            assert!((m.mass.contour()[0] - m.mass.contour()[1]).abs() < 1e-15);
        }
    }
}
