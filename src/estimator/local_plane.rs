//! The detection score the GP and k-NN share: how far a frame's standardised features lie from
//! those the samples show at the method's answer. Every feature counts alike, whatever weight
//! the method itself gives it, so a corrupted feature it ignores (an occluded tile under the
//! GP's long length scale) or outvotes (salt-and-pepper on a few features among many under
//! k-NN's distance) still shows the frame is unlike any sample near its answer.

use nalgebra::{Matrix3, Vector3};

use super::inputs::scaled_norm;

/// Samples nearest the answer that the local plane goes through (a 3 × 3 block of a mesh).
pub(super) const LOCAL_SAMPLES: usize = 9;

/// The [`LOCAL_SAMPLES`] sample poses nearest `pose` (all when fewer), by a scan: ties to the
/// lower index, in the order the selection leaves them (the GP's, which its figures rest on).
pub(super) fn nearest_by_scan(pose: [f64; 2], poses: &[[f64; 2]]) -> Vec<usize> {
    let mut near: Vec<(f64, usize)> = (poses.iter().enumerate())
        .map(|(i, p)| (squared_distance(*p, pose), i))
        .collect();
    let m = near.len().min(LOCAL_SAMPLES);
    if m == 0 {
        return Vec::new();
    }
    near.select_nth_unstable_by(m - 1, |a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    near[..m].iter().map(|&(_, i)| i).collect()
}

fn squared_distance(p: [f64; 2], q: [f64; 2]) -> f64 {
    (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2)
}

/// The Euclidean norm, over the features `mask` keeps (all when `None`; a mask value of 0
/// drops a missing feature), of the standardised `query` less a plane through the samples
/// `near` (least squares, per feature, in pose offsets from `pose`). `rows` holds the samples'
/// standardised features, row-major, one row per pose of `poses`. Infinite when `near` is empty
/// or the plane cannot be solved; a residual beyond the double range gives its scaled norm.
pub(super) fn plane_distance(
    query: &[f64],
    mask: Option<&[f64]>,
    pose: [f64; 2],
    poses: &[[f64; 2]],
    rows: &[f64],
    near: &[usize],
) -> f64 {
    let dim = query.len();
    if near.is_empty() {
        return f64::INFINITY;
    }
    let offsets: Vec<(Vector3<f64>, usize)> = (near.iter())
        .map(|&i| {
            let u = Vector3::new(1.0, poses[i][0] - pose[0], poses[i][1] - pose[1]);
            (u, i)
        })
        .collect();
    // Normal equations of f ≈ a + b·(p − pose); a little ridge on the slopes keeps them
    // solvable when the poses are collinear (then a is their mean).
    let mut gram = Matrix3::<f64>::zeros();
    for (u, _) in &offsets {
        gram += u * u.transpose();
    }
    gram[(1, 1)] += 1e-9;
    gram[(2, 2)] += 1e-9;
    let Some(inverse) = gram.try_inverse() else {
        return f64::INFINITY;
    };
    let row = inverse.row(0);
    let residuals: Vec<f64> = (0..dim)
        .map(|d| {
            if mask.is_some_and(|m| m[d] == 0.0) {
                return 0.0;
            }
            let mut rhs = Vector3::zeros();
            for (u, i) in &offsets {
                rhs += u * rows[i * dim + d];
            }
            query[d] - row.dot(&rhs.transpose())
        })
        .collect();
    let squares: f64 = residuals.iter().map(|r| r.powi(2)).sum();
    if squares.is_finite() {
        squares.sqrt()
    } else {
        // A frame far beyond the samples overflows the squares: the norm itself.
        scaled_norm(residuals.iter().copied())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimator::motion::PoseBuckets;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn sorted(mut v: Vec<usize>, pose: [f64; 2], poses: &[[f64; 2]]) -> Vec<usize> {
        v.sort_by(|&a, &b| {
            let (da, db) = (
                squared_distance(poses[a], pose),
                squared_distance(poses[b], pose),
            );
            da.total_cmp(&db).then(a.cmp(&b))
        });
        v
    }

    #[test]
    fn the_grid_finds_the_scans_samples_on_meshes_paths_and_lines() {
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let mesh: Vec<[f64; 2]> = (0..400)
            .map(|i| [(i % 20) as f64 - 9.5, (i / 20) as f64 + 38.0])
            .collect();
        let random: Vec<[f64; 2]> = (0..3000)
            .map(|_| [rng.random_range(-9.5..9.5), rng.random_range(38.0..57.0)])
            .collect();
        let line: Vec<[f64; 2]> = (0..50).map(|i| [i as f64 * 0.3, 40.0]).collect();
        let few: Vec<[f64; 2]> = vec![[1.0, 2.0], [1.0, 2.0], [3.0, 5.0]];
        for poses in [&mesh, &random, &line, &few] {
            let grid = PoseBuckets::new(poses);
            let mut queries: Vec<[f64; 2]> = poses.iter().step_by(7).copied().collect();
            queries.extend(
                (0..200).map(|_| [rng.random_range(-12.0..12.0), rng.random_range(36.0..60.0)]),
            );
            // Halfway between mesh nodes: ties everywhere.
            queries.extend((0..50).map(|i| [(i % 10) as f64 - 9.0, (i / 10) as f64 + 40.5]));
            for q in queries {
                let scan = sorted(nearest_by_scan(q, poses), q, poses);
                assert_eq!(grid.nearest(q, LOCAL_SAMPLES), scan, "{q:?}");
            }
        }
    }
}
