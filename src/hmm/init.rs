//! Initialisation of EM, three kinds so that restarts explore different basins: seeded k-means++
//! on scalars refined by a few Lloyd iterations, the data's quantiles, and random data points;
//! each clustering turned into starting parameters.

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
    let labels = lloyd(y, &mut centres, 10);
    params_from_labels(y, &labels, centres, floor)
}

/// `iterations` Lloyd iterations from `centres` (at most; fewer when nothing changes): the
/// nearest-centre labels, with the centres moved to their clusters' means.
fn lloyd(y: &[f64], centres: &mut [f64], iterations: usize) -> Vec<usize> {
    let mut labels = vec![0usize; y.len()];
    for _ in 0..iterations {
        let changed = nearest_labels(y, centres, &mut labels);
        move_to_cluster_means(y, &labels, centres);
        if !changed {
            break;
        }
    }
    labels
}

/// Moves every centre whose cluster holds a value to the cluster's mean.
fn move_to_cluster_means(y: &[f64], labels: &[usize], centres: &mut [f64]) {
    let k = centres.len();
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
}

/// Labels every value with its nearest centre; whether any label changed.
fn nearest_labels(y: &[f64], centres: &[f64], labels: &mut [usize]) -> bool {
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
    changed
}

/// Centres at the data's quantiles (j + ½)/k, each value labelled with the nearest: no
/// randomness, and no Lloyd iterations, which would pull it towards k-means' basin.
pub(super) fn init_quantile(y: &[f64], k: usize, floor: f64) -> Params {
    let mut sorted = y.to_vec();
    sorted.sort_by(f64::total_cmp);
    let n = sorted.len();
    let centres: Vec<f64> = (0..k)
        .map(|j| sorted[(((2 * j + 1) * n) / (2 * k)).min(n - 1)])
        .collect();
    let mut labels = vec![0usize; n];
    nearest_labels(y, &centres, &mut labels);
    params_from_labels(y, &labels, centres, floor)
}

/// Centres at `k` data points drawn at random (distinct values), each value labelled with the
/// nearest. Requires at least `k` distinct values in `y`.
pub(super) fn init_random(y: &[f64], k: usize, floor: f64, rng: &mut ChaCha8Rng) -> Params {
    let n = y.len();
    let mut centres: Vec<f64> = Vec::with_capacity(k);
    // Bounded: with at least k distinct values each draw has a positive chance of a new one;
    // the fallback fills any gap deterministically.
    for _ in 0..64 * k {
        if centres.len() == k {
            break;
        }
        let c = y[rng.random_range(0..n)];
        if !centres.contains(&c) {
            centres.push(c);
        }
    }
    for &v in y {
        if centres.len() == k {
            break;
        }
        if !centres.contains(&v) {
            centres.push(v);
        }
    }
    centres.sort_by(f64::total_cmp);
    let mut labels = vec![0usize; n];
    nearest_labels(y, &centres, &mut labels);
    params_from_labels(y, &labels, centres, floor)
}

/// The partition of the sorted values into `k` contiguous groups that maximises the Gaussian
/// likelihood of each group with its own variance (floored), by dynamic programming over at most
/// [`PARTITION_POINTS`] order statistics: unlike k-means, it finds a tight group beside a wide
/// one, where the mixture's best optimum often lies. Each value is labelled with its group.
pub(super) fn init_partition(y: &[f64], k: usize, floor: f64) -> Params {
    let mut sorted = y.to_vec();
    sorted.sort_by(f64::total_cmp);
    let n = sorted.len();
    let m = n.min(PARTITION_POINTS);
    let points: Vec<f64> = (0..m).map(|i| sorted[i * n / m]).collect();
    // Prefix sums of the points and their squares give each segment's variance in O(1).
    let (mut s1, mut s2) = (vec![0.0; m + 1], vec![0.0; m + 1]);
    for (i, v) in points.iter().enumerate() {
        s1[i + 1] = s1[i] + v;
        s2[i + 1] = s2[i] + v * v;
    }
    // Cost of points[a..b]: its size times the log of its variance, ½ its negative likelihood;
    // every segment's once, row a at a·(m + 1).
    let mut costs = vec![0.0; (m + 1) * (m + 1)];
    for a in 0..m {
        for b in a + 1..=m {
            let c = (b - a) as f64;
            let mean = (s1[b] - s1[a]) / c;
            let var = ((s2[b] - s2[a]) / c - mean * mean).max(0.0) + floor;
            costs[a * (m + 1) + b] = c * var.ln();
        }
    }
    let cost = |a: usize, b: usize| costs[a * (m + 1) + b];
    let smallest = 2.min(m / k).max(1);
    // best[j][b]: the lowest cost of points[..b] in j + 1 segments; from[j][b]: where the last
    // one starts.
    let mut best = vec![vec![f64::INFINITY; m + 1]; k];
    let mut from = vec![vec![0usize; m + 1]; k];
    for (b, slot) in best[0].iter_mut().enumerate().skip(smallest) {
        *slot = cost(0, b);
    }
    for j in 1..k {
        for b in (j + 1) * smallest..=m {
            for a in j * smallest..=b - smallest {
                let c = best[j - 1][a] + cost(a, b);
                if c < best[j][b] {
                    best[j][b] = c;
                    from[j][b] = a;
                }
            }
        }
    }
    // The upper end of each segment, from the last back.
    let mut ends = vec![m; k];
    for j in (1..k).rev() {
        ends[j - 1] = from[j][ends[j]];
    }
    let bounds: Vec<f64> = ends[..k - 1]
        .iter()
        .map(|&e| points[e.min(m - 1)])
        .collect();
    let labels: Vec<usize> = y
        .iter()
        .map(|v| bounds.iter().filter(|&&b| *v >= b).count())
        .collect();
    // A group no value falls in keeps a point of its segment as its centre.
    let mut centres: Vec<f64> = (ends.iter())
        .map(|&e| points[(e.max(1) - 1).min(m - 1)])
        .collect();
    move_to_cluster_means(y, &labels, &mut centres);
    params_from_labels(y, &labels, centres, floor)
}

/// Most order statistics the partition's dynamic programme runs on (O(k·m²)).
const PARTITION_POINTS: usize = 64;

/// Starting parameters of a clustering: each cluster's mean and variance (floored), initial
/// probabilities from the cluster sizes and a smoothed transition matrix of consecutive labels.
fn params_from_labels(y: &[f64], labels: &[usize], centres: Vec<f64>, floor: f64) -> Params {
    let (n, k) = (y.len(), centres.len());
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
