//! Initialisation of EM: seeded k-means++ on scalars, refined by a few Lloyd iterations, turned
//! into starting parameters.

use rand::Rng;
use rand_chacha::ChaCha8Rng;

use super::argmax;
use super::em::Params;

/// Seeded k-means++ on scalars followed by a few Lloyd iterations; the clusters give the initial
/// means, variances (floored), initial probabilities and a smoothed transition matrix.
/// Requires at least `k` distinct values in `y`.
pub(super) fn init_kmeanspp(y: &[f64], k: usize, floor: f64, rng: &mut ChaCha8Rng) -> Params {
    let n = y.len();
    let mut centres = Vec::with_capacity(k);
    centres.push(y[rng.random_range(0..n)]);
    let mut d2: Vec<f64> = y.iter().map(|v| (v - centres[0]).powi(2)).collect();
    while centres.len() < k {
        let total: f64 = d2.iter().sum();
        let pick = if total > 0.0 && total.is_finite() {
            let mut r = rng.random::<f64>() * total;
            let mut pick = None;
            for (i, d) in d2.iter().enumerate() {
                if *d > 0.0 {
                    pick = Some(i);
                    if r < *d {
                        break;
                    }
                    r -= d;
                }
            }
            pick
        } else {
            None
        };
        // Rounding can leave `pick` on a zero-distance point only if none is positive, which the
        // caller rules out by counting distinct values; fall back to the farthest point anyway.
        let i = pick.unwrap_or_else(|| argmax(&d2));
        let c = y[i];
        centres.push(c);
        for (d, v) in d2.iter_mut().zip(y) {
            *d = d.min((v - c).powi(2));
        }
    }
    let mut labels = vec![0usize; n];
    for _ in 0..10 {
        let mut changed = false;
        for (l, v) in labels.iter_mut().zip(y) {
            // Selects rather than branches: which centre is nearest is unpredictable.
            let mut best = 0;
            let mut best_d = (v - centres[0]).abs();
            for (j, c) in centres.iter().enumerate().skip(1) {
                let d = (v - c).abs();
                let nearer = d < best_d;
                best = if nearer { j } else { best };
                best_d = if nearer { d } else { best_d };
            }
            changed |= *l != best;
            *l = best;
        }
        let mut sum = vec![0.0; k];
        let mut count = vec![0usize; k];
        for (l, v) in labels.iter().zip(y) {
            sum[*l] += v;
            count[*l] += 1;
        }
        for j in 0..k {
            if count[j] > 0 {
                centres[j] = sum[j] / count[j] as f64;
            }
        }
        if !changed {
            break;
        }
    }
    let mut count = vec![0.0; k];
    let mut ss = vec![0.0; k];
    for (l, v) in labels.iter().zip(y) {
        count[*l] += 1.0;
        ss[*l] += (v - centres[*l]).powi(2);
    }
    let variances = (0..k)
        .map(|j| {
            if count[j] > 0.0 {
                (ss[j] / count[j]).max(floor)
            } else {
                floor
            }
        })
        .collect();
    // Laplace-smoothed transition counts between consecutive labels.
    let mut trans = vec![1.0; k * k];
    for w in labels.windows(2) {
        trans[w[0] * k + w[1]] += 1.0;
    }
    for i in 0..k {
        let s: f64 = trans[i * k..(i + 1) * k].iter().sum();
        for x in &mut trans[i * k..(i + 1) * k] {
            *x /= s;
        }
    }
    let total = n as f64 + k as f64;
    Params {
        k,
        initial: count.iter().map(|c| (c + 1.0) / total).collect(),
        trans,
        means: centres,
        variances,
    }
}
