//! The detection score the GP and k-NN share: how far a frame's standardised features lie from
//! those the samples show at the method's answer. Every feature counts alike, whatever weight
//! the method itself gives it, so a corrupted feature it ignores (an occluded tile under the
//! GP's long length scale) or outvotes (salt-and-pepper on a few features among many under
//! k-NN's distance) still shows the frame is unlike any sample near its answer.

use nalgebra::{Matrix3, Vector3};

use super::inputs::scaled_norm;

/// Samples nearest the answer that the local plane goes through (a 3 × 3 block of a mesh).
pub(super) const LOCAL_SAMPLES: usize = 9;

/// The Euclidean norm, over the features `mask` keeps (all when `None`; a mask value of 0
/// drops a missing feature), of the standardised `query` less a plane through the
/// [`LOCAL_SAMPLES`] sample poses nearest `pose` (least squares, per feature). `rows` holds the
/// samples' standardised features, row-major, one row per pose of `poses` (not empty). Infinite
/// only when the plane cannot be solved; a residual beyond the double range gives its scaled
/// norm.
pub(super) fn plane_distance(
    query: &[f64],
    mask: Option<&[f64]>,
    pose: [f64; 2],
    poses: &[[f64; 2]],
    rows: &[f64],
) -> f64 {
    let dim = query.len();
    let mut near: Vec<(f64, usize)> = (poses.iter().enumerate())
        .map(|(i, p)| ((p[0] - pose[0]).powi(2) + (p[1] - pose[1]).powi(2), i))
        .collect();
    let m = near.len().min(LOCAL_SAMPLES);
    if m == 0 {
        return f64::INFINITY;
    }
    // Ties to the lower index, so the score does not depend on the sort.
    near.select_nth_unstable_by(m - 1, |a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    let offsets: Vec<(Vector3<f64>, usize)> = (near[..m].iter())
        .map(|&(_, i)| {
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
