//! PCR6 by Martin and Osswald's general (n-ary) formula: the conjunctive combination's non-empty
//! part, plus each conflicting tuple's product sent back to its focal sets in proportion to the
//! masses the sources put on them. Every tuple is visited once (an odometer, no recursion), so the
//! work is the product of the functions' focal-set counts, held to [`WorkLimits::tuples`].

use super::super::combine::{unnormalised, Combination};
use super::super::limits::WorkLimits;
use super::super::mass::MassFunction;
use super::super::subset::{word_count, Subset};
use super::super::EvidenceError;
use super::from_pairs;

/// PCR6 of normalised functions on a frame of `n`; `c` is their Dempster combination (its
/// non-empty part, scaled back by e^(−K), is the conjunctive part of PCR6).
pub(super) fn combine(
    n: usize,
    fs: &[&MassFunction],
    c: &Combination,
    limits: &WorkLimits,
) -> Result<MassFunction, EvidenceError> {
    let tuples = fs.iter().fold(1usize, |t, f| t.saturating_mul(f.len()));
    limits.check_tuples(tuples)?;
    let w = word_count(n).max(1);
    let k = fs.len();
    let sets: Vec<Vec<&[u64]>> = fs
        .iter()
        .map(|f| f.focal_sets().iter().map(Subset::words).collect())
        .collect();
    let masses: Vec<&[f64]> = fs.iter().map(|f| f.masses()).collect();
    // share[i][j]: what focal set j of function i gets back from the conflicting tuples.
    let mut share: Vec<Vec<f64>> = masses.iter().map(|m| vec![0.0; m.len()]).collect();
    let mut idx = vec![0usize; k];
    // Per level l: the intersection, product and sum of masses of the tuple's first l + 1 sets.
    let mut meet = vec![0u64; k * w];
    let mut prod = vec![0.0; k];
    let mut sum = vec![0.0; k];
    let mut from = 0;
    loop {
        for l in from..k {
            let m = masses[l][idx[l]];
            let set = sets[l][idx[l]];
            if l == 0 {
                meet[..w].copy_from_slice(set);
                prod[0] = m;
                sum[0] = m;
            } else {
                let (done, rest) = meet.split_at_mut(l * w);
                for ((x, a), b) in rest[..w].iter_mut().zip(&done[(l - 1) * w..]).zip(set) {
                    *x = a & b;
                }
                prod[l] = prod[l - 1] * m;
                sum[l] = sum[l - 1] + m;
            }
        }
        let last = k - 1;
        if prod[last] > 0.0 && meet[last * w..].iter().all(|&x| x == 0) {
            let scale = prod[last] / sum[last];
            for (i, &j) in idx.iter().enumerate() {
                share[i][j] += scale * masses[i][j];
            }
        }
        // Next tuple: the last index that can move moves, the ones after it restart.
        let Some(l) = (0..k).rev().find(|&l| idx[l] + 1 < masses[l].len()) else {
            break;
        };
        idx[l] += 1;
        idx[l + 1..].fill(0);
        from = l;
    }
    let conj = unnormalised(n, c);
    let mut pairs: Vec<(Subset, f64)> = conj
        .focal()
        .filter(|(s, _)| !s.is_empty())
        .map(|(s, m)| (s.clone(), m))
        .collect();
    for (f, back) in fs.iter().zip(share) {
        pairs.extend(f.focal_sets().iter().cloned().zip(back));
    }
    Ok(from_pairs(n, pairs))
}
