//! The tabulated maps at many poses at once, feature-major (issue 32): what the particle filter
//! weighs its particles with. The same interpolation as `Grid::eval`'s values, operation for
//! operation, so the values are bit-identical; only the value weights are computed (no slopes),
//! and each pose's cell is looked up once for all its features (they are contiguous per node).

use super::grid::hermite;
use super::Grid;
use crate::estimator::continuous::Continuous;

impl Grid {
    /// The values of the `dim` features at each pose of `poses` into `out`, feature-major:
    /// feature i at pose p is `out[i * poses.len() + p]`.
    fn eval_block(&self, poses: &[[f64; 2]], dim: usize, out: &mut [f64]) {
        let m = poses.len();
        let table = &self.table[..];
        for (p, q) in poses.iter().enumerate() {
            let (weights, at) = self.value_weights(*q, dim);
            for i in 0..dim {
                let mut sum = 0.0;
                for (w, &at) in weights.iter().zip(&at) {
                    let n = &table[at + i];
                    sum += w[0] * n[0] + w[1] * n[1] + w[2] * n[2] + w[3] * n[3];
                }
                out[i * m + p] = sum;
            }
        }
    }

    /// Per corner of `q`'s cell: the weights of f, h·fx, h·fy, h²·fxy (as `Grid::eval` forms
    /// them) and the corner's first table index.
    #[inline]
    fn value_weights(&self, q: [f64; 2], dim: usize) -> ([[f64; 4]; 4], [usize; 4]) {
        let (cell, t) = self.locate(q);
        let (bx, by) = (hermite(t[0]), hermite(t[1]));
        let [hx, hy] = self.step;
        let corners = [(0, 0), (1, 0), (0, 1), (1, 1)];
        let weights = corners.map(|(a, b)| {
            let (v0, v1, w0, w1) = (bx[2 * a], bx[2 * a + 1], by[2 * b], by[2 * b + 1]);
            [v0 * w0, hx * v1 * w0, hy * v0 * w1, hx * hy * v1 * w1]
        });
        let at = corners.map(|(a, b)| ((cell[1] + b) * self.nodes[0] + cell[0] + a) * dim);
        (weights, at)
    }
}

impl Continuous {
    /// Every feature's learned value at each pose of `poses` (mm) into `out` (at least
    /// features × poses long), feature-major: feature i at pose p is `out[i * poses.len() + p]`.
    /// Bit-identical to [`Continuous::feature_map`] at each pose.
    pub(crate) fn feature_maps_block(&self, poses: &[[f64; 2]], out: &mut [f64]) {
        let s = &self.surrogate;
        s.grid.eval_block(poses, s.dim(), out);
    }
}

#[cfg(test)]
mod tests {
    use crate::estimator::test_maps::{fitted_continuous, workspace_points};
    use rand::SeedableRng;

    #[test]
    fn the_block_is_the_single_pose_map_bit_for_bit() {
        let maps = fitted_continuous(5, 8, 20, 0.01, false, 2);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        // Inside the workspace and beyond the grid on every side (clamped).
        let mut poses = workspace_points(300, &mut rng);
        poses.extend([[-500.0, 47.0], [500.0, 47.0], [0.0, -500.0], [0.0, 500.0]]);
        let mut out = vec![f64::NAN; 5 * poses.len()];
        maps.feature_maps_block(&poses, &mut out);
        for (p, &q) in poses.iter().enumerate() {
            for (i, v) in maps.feature_map(q).iter().enumerate() {
                assert_eq!(out[i * poses.len() + p].to_bits(), v.to_bits(), "{q:?} {i}");
            }
        }
    }
}
