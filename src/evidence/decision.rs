//! Decisions from a mass function: relative plausibility of singletons, pignistic probability and
//! the pointwise estimate Σ p(k) q_k of a vector quantity attached to the frame's elements (§4.4).

use super::mass::MassFunction;
use super::EvidenceError;

/// Relative plausibility of the singletons: the contour function divided by its sum.
///
/// # Errors
/// [`EvidenceError::AllZero`] when every singleton has plausibility 0 (all mass on ∅).
pub fn relative_plausibility(m: &MassFunction) -> Result<Vec<f64>, EvidenceError> {
    let mut c = m.contour();
    let s: f64 = c.iter().sum();
    if s <= 0.0 {
        return Err(EvidenceError::AllZero {
            what: "singleton plausibilities",
        });
    }
    for x in &mut c {
        *x /= s;
    }
    Ok(c)
}

/// Pignistic probability BetP(ω) = Σ_{A ∋ ω} m(A) / (|A| (1 − m(∅))).
///
/// # Errors
/// [`EvidenceError::AllZero`] when all mass is on ∅.
pub fn pignistic(m: &MassFunction) -> Result<Vec<f64>, EvidenceError> {
    let mut p = vec![0.0; m.frame_size()];
    let mut total = 0.0;
    for (a, mass) in m.focal() {
        let k = a.count();
        if k == 0 {
            continue;
        }
        total += mass;
        let share = mass / k as f64;
        for i in a.iter() {
            p[i] += share;
        }
    }
    if total <= 0.0 {
        return Err(EvidenceError::AllZero {
            what: "masses on non-empty sets",
        });
    }
    for x in &mut p {
        *x /= total;
    }
    Ok(p)
}

/// Pointwise estimate Σ p(k) q_k / Σ p(k) for points of any dimension `D`.
///
/// Weights need not be normalised; they are divided by their sum.
///
/// # Errors
/// [`EvidenceError::LengthMismatch`], [`EvidenceError::InvalidNumber`] for a NaN/infinite/negative
/// weight or a non-finite coordinate, [`EvidenceError::AllZero`] when the weights sum to 0.
pub fn pointwise_estimate<const D: usize>(
    weights: &[f64],
    points: &[[f64; D]],
) -> Result<[f64; D], EvidenceError> {
    if weights.len() != points.len() {
        return Err(EvidenceError::LengthMismatch {
            what: "weights vs points",
            expected: points.len(),
            found: weights.len(),
        });
    }
    let mut sum = 0.0;
    let mut acc = [0.0; D];
    for (i, (&w, q)) in weights.iter().zip(points).enumerate() {
        if !w.is_finite() || w < 0.0 {
            return Err(EvidenceError::InvalidNumber {
                what: "weight",
                index: i,
                value: w,
                non_negative: true,
            });
        }
        if let Some(&bad) = q.iter().find(|x| !x.is_finite()) {
            return Err(EvidenceError::InvalidNumber {
                what: "point coordinate of point",
                index: i,
                value: bad,
                non_negative: false,
            });
        }
        if w == 0.0 {
            continue;
        }
        sum += w;
        for (a, x) in acc.iter_mut().zip(q) {
            *a += w * x;
        }
    }
    if sum <= 0.0 {
        return Err(EvidenceError::AllZero { what: "weights" });
    }
    for a in &mut acc {
        *a /= sum;
    }
    Ok(acc)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::evidence::Subset;

    #[test]
    fn pignistic_and_relative_plausibility_by_hand() {
        // m({0}) = 0.5, m({0,1,2}) = 0.3, m({1,2}) = 0.2.
        let n = 3;
        let s = |v: &[usize]| Subset::from_indices(n, v.iter().copied()).unwrap();
        let m = MassFunction::new(
            n,
            vec![(s(&[0]), 0.5), (s(&[0, 1, 2]), 0.3), (s(&[1, 2]), 0.2)],
        )
        .unwrap();
        let p = pignistic(&m).unwrap();
        let want = [0.6, 0.2, 0.2];
        for (x, y) in p.iter().zip(want) {
            assert!((x - y).abs() < 1e-15);
        }
        // Contour (0.8, 0.5, 0.5) / 1.8.
        let r = relative_plausibility(&m).unwrap();
        for (x, y) in r.iter().zip([0.8 / 1.8, 0.5 / 1.8, 0.5 / 1.8]) {
            assert!((x - y).abs() < 1e-15);
        }
        let u = MassFunction::unnormalised(n, vec![(Subset::empty(n), 1.0)]).unwrap();
        assert!(relative_plausibility(&u).is_err());
        assert!(pignistic(&u).is_err());
    }

    #[test]
    fn pointwise_estimate_by_hand() {
        let q = [[0.0, 0.0], [2.0, 4.0]];
        assert_eq!(pointwise_estimate(&[1.0, 3.0], &q).unwrap(), [1.5, 3.0]);
        assert_eq!(pointwise_estimate(&[1.0], &[[7.0]]).unwrap(), [7.0]);
        assert!(pointwise_estimate(&[0.0, 0.0], &q).is_err());
        assert!(pointwise_estimate(&[f64::NAN, 1.0], &q).is_err());
        assert!(pointwise_estimate(&[1.0], &q).is_err());
        assert!(pointwise_estimate(&[1.0, 1.0], &[[0.0, f64::INFINITY], [0.0, 0.0]]).is_err());
    }
}
