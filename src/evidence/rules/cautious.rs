//! Denœux's cautious conjunctive rule through the canonical conjunctive decomposition, on dense
//! tables of all 2ⁿ subsets (so frames of at most [`MAX_CAUTIOUS_FRAME`] elements):
//! ln w(A) = −Σ_{B⊇A} (−1)^{|B∖A|} ln q(B) for A ≠ Ω, w₁₂ = min over the functions, then
//! q₁₂(B) = Π_{A⊉B} w₁₂(A) (the conjunctive combination of the simple functions A^w) and m₁₂ its
//! Möbius transform.

use super::super::combine::Combination;
use super::super::mass::MassFunction;
use super::super::subset::Subset;
use super::super::EvidenceError;
use super::from_pairs;

/// Largest frame the cautious rule takes: its tables hold 2ⁿ values (8 MiB each at 20).
pub const MAX_CAUTIOUS_FRAME: usize = 20;

/// Masses at most this are rounding noise of the Möbius transforms and are left out.
const NOISE: f64 = 1e-14;

/// a[B] ← Σ_{A⊇B} a[A] (`sign` = 1) or the inverse Möbius transform (`sign` = −1).
fn superset_transform(a: &mut [f64], n: usize, sign: f64) {
    for i in 0..n {
        let bit = 1usize << i;
        for b in 0..a.len() {
            if b & bit == 0 {
                a[b] += sign * a[b | bit];
            }
        }
    }
}

/// The cautious combination of non-dogmatic functions on a frame of `n`.
pub(super) fn combine(n: usize, fs: &[&MassFunction]) -> Result<Combination, EvidenceError> {
    if n > MAX_CAUTIOUS_FRAME {
        return Err(EvidenceError::FrameTooLargeForRule {
            rule: "cautious",
            frame: n,
            max: MAX_CAUTIOUS_FRAME,
        });
    }
    let size = 1usize << n;
    let full = size - 1;
    // The smallest ln w(A) over the functions, for every A ≠ Ω.
    let mut lw = vec![f64::INFINITY; size];
    for (function, f) in fs.iter().enumerate() {
        let mut q = vec![0.0; size];
        for (s, m) in f.focal() {
            q[s.words().first().map_or(0, |&x| x as usize)] += m;
        }
        if q[full] <= 0.0 {
            return Err(EvidenceError::Dogmatic { function });
        }
        superset_transform(&mut q, n, 1.0);
        for x in &mut q {
            *x = x.ln();
        }
        superset_transform(&mut q, n, -1.0);
        for (w, v) in lw.iter_mut().zip(&q).take(full) {
            *w = w.min(-v);
        }
    }
    lw[full] = 0.0;
    // Σ_{A⊉B} ln w(A) = Σ_A ln w(A) − Σ_{A⊇B} ln w(A).
    superset_transform(&mut lw, n, 1.0);
    let total = lw[0];
    let mut m: Vec<f64> = lw.iter().map(|s| (total - s).exp()).collect();
    superset_transform(&mut m, n, -1.0);
    let kappa = if m[0] > NOISE { m[0].min(1.0) } else { 0.0 };
    let pairs: Vec<(Subset, f64)> = m
        .iter()
        .enumerate()
        .skip(1)
        .filter(|(_, &x)| x > NOISE)
        .map(|(mask, &x)| (Subset::from_words(n, &[mask as u64]), x))
        .collect();
    let kept: f64 = pairs.iter().map(|p| p.1).sum();
    let level = if kappa < 0.5 {
        -(-kappa).ln_1p()
    } else {
        -kept.ln()
    };
    let mut pairs = pairs;
    if kappa > 0.0 {
        pairs.push((Subset::empty(n), kappa));
    }
    Ok(Combination {
        mass: Some(from_pairs(n, pairs)),
        conflict_mass: kappa,
        conflict_level: level.max(0.0),
    })
}
