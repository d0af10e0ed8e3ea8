//! The detection score the GP and k-NN share: how far a frame's standardised features lie from
//! those the samples show at the method's answer. Every feature counts alike, whatever weight
//! the method itself gives it, so a corrupted feature it ignores (an occluded tile under the
//! GP's long length scale) or outvotes (salt-and-pepper on a few features among many under
//! k-NN's distance) still shows the frame is unlike any sample near its answer.
//!
//! What the samples show at the answer is a quadratic surface through the 16 samples nearest it
//! (a 4 × 4 block of a mesh), per feature: a plane there left the features' curvature in the
//! score, so clean frames at strongly curved poses scored like struck ones (docs/results.md,
//! "The GP's clean abstentions").

use nalgebra::{SMatrix, SVector};

use super::inputs::scaled_norm;

/// Samples nearest the answer that the local surface goes through (a 4 × 4 block of a mesh).
pub(super) const LOCAL_SAMPLES: usize = 16;

/// Terms of a quadratic in two offsets: 1, dx, dy, dx², dx·dy, dy².
const QUADRATIC_TERMS: usize = 6;

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
/// drops a missing feature), of the standardised `query` less a quadratic surface through the
/// samples `near` (least squares, per feature, in pose offsets from `pose`; a plane when fewer
/// than 6 samples). `rows` holds the samples' standardised features, row-major, one row per pose
/// of `poses`. Infinite when `near` is empty or the surface cannot be solved; a residual beyond
/// the double range gives its scaled norm.
pub(super) fn surface_distance(
    query: &[f64],
    mask: Option<&[f64]>,
    pose: [f64; 2],
    poses: &[[f64; 2]],
    rows: &[f64],
    near: &[usize],
) -> f64 {
    let weights = if near.len() >= QUADRATIC_TERMS {
        let quadratic = |dx: f64, dy: f64| SVector::from([1.0, dx, dy, dx * dx, dx * dy, dy * dy]);
        weights_at(quadratic, pose, poses, near)
    } else {
        let plane = |dx: f64, dy: f64| SVector::from([1.0, dx, dy]);
        weights_at(plane, pose, poses, near)
    };
    let Some(weights) = weights else {
        return f64::INFINITY;
    };
    let dim = query.len();
    let residuals: Vec<f64> = (0..dim)
        .map(|d| {
            if mask.is_some_and(|m| m[d] == 0.0) {
                return 0.0;
            }
            let fitted: f64 = weights.iter().map(|&(w, i)| w * rows[i * dim + d]).sum();
            query[d] - fitted
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

/// The least-squares fit on `basis` (of the pose offsets from `pose`) of values at the samples
/// `near`, read at `pose`, is linear in those values: each sample's weight in it, with the
/// sample. The same weights serve every feature. `None` without samples or when the fit cannot
/// be solved.
fn weights_at<const N: usize>(
    basis: impl Fn(f64, f64) -> SVector<f64, N>,
    pose: [f64; 2],
    poses: &[[f64; 2]],
    near: &[usize],
) -> Option<Vec<(f64, usize)>> {
    if near.is_empty() {
        return None;
    }
    let offsets: Vec<SVector<f64, N>> = (near.iter())
        .map(|&i| basis(poses[i][0] - pose[0], poses[i][1] - pose[1]))
        .collect();
    let mut gram = SMatrix::<f64, N, N>::zeros();
    for u in &offsets {
        gram += u * u.transpose();
    }
    // A little ridge on every term but the level keeps it solvable when the poses are collinear
    // or repeated (the terms they cannot tell apart then stay near zero).
    for k in 1..N {
        gram[(k, k)] += 1e-9;
    }
    // The fit's value at the pose is its level (the first term).
    let level = gram
        .cholesky()?
        .solve(&SVector::<f64, N>::from_fn(|k, _| f64::from(k == 0)));
    Some(
        (offsets.iter().zip(near))
            .map(|(u, &i)| (level.dot(u), i))
            .collect(),
    )
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
    fn a_quadratic_feature_leaves_no_residual_between_the_samples() {
        // Two features on a 1 mm mesh: one curved (a plane misses it between the samples), one
        // linear; the frame has the features' exact values at a pose between the nodes.
        let poses: Vec<[f64; 2]> = (0..100)
            .map(|i| [(i % 10) as f64, (i / 10) as f64])
            .collect();
        let curved = |p: [f64; 2]| 0.3 * p[0] * p[0] - 0.2 * p[0] * p[1] + 0.1 * p[1] * p[1];
        let linear = |p: [f64; 2]| 1.0 + 0.5 * p[0] - 0.25 * p[1];
        let rows: Vec<f64> = poses.iter().flat_map(|&p| [curved(p), linear(p)]).collect();
        let pose = [4.37, 5.42];
        let query = [curved(pose), linear(pose)];
        let near = nearest_by_scan(pose, &poses);
        assert_eq!(near.len(), LOCAL_SAMPLES);
        let distance = surface_distance(&query, None, pose, &poses, &rows, &near);
        assert!(distance < 1e-6, "{distance}");
        // The plane through the same samples misses the curved feature by its curvature.
        let plane = |dx: f64, dy: f64| SVector::from([1.0, dx, dy]);
        let weights = weights_at(plane, pose, &poses, &near).unwrap();
        let missed: Vec<f64> = (0..2)
            .map(|d| {
                query[d]
                    - weights
                        .iter()
                        .map(|&(w, i)| w * rows[i * 2 + d])
                        .sum::<f64>()
            })
            .collect();
        assert!(
            missed[0].abs() > 0.1 && missed[1].abs() < 1e-6,
            "{missed:?}"
        );
        // A corrupted feature shows in full; a masked one not at all.
        let struck = [query[0], query[1] + 0.8];
        let d = surface_distance(&struck, None, pose, &poses, &rows, &near);
        assert!((d - 0.8).abs() < 1e-6, "{d}");
        let masked = surface_distance(&struck, Some(&[1.0, 0.0]), pose, &poses, &rows, &near);
        assert!(masked < 1e-6, "{masked}");
        // Fewer than six samples: the plane, exact on the linear feature; none: infinite.
        let few = &near[..4];
        let d = surface_distance(
            &[0.0, query[1]],
            Some(&[0.0, 1.0]),
            pose,
            &poses,
            &rows,
            few,
        );
        assert!(d < 1e-6, "{d}");
        assert_eq!(
            surface_distance(&query, None, pose, &poses, &rows, &[]),
            f64::INFINITY
        );
        // Samples on a line (a path): still a finite score.
        let line: Vec<[f64; 2]> = (0..20).map(|i| [f64::from(i) * 0.5, 3.0]).collect();
        let line_rows: Vec<f64> = line.iter().flat_map(|&p| [curved(p), linear(p)]).collect();
        let on_line = [4.2, 3.0];
        let near = nearest_by_scan(on_line, &line);
        let at = [curved(on_line), linear(on_line)];
        let d = surface_distance(&at, None, on_line, &line, &line_rows, &near);
        assert!(d.is_finite() && d < 1e-3, "{d}");
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
