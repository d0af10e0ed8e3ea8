//! The tabulated maps at many poses at once, feature-major (issue 32): what the particle filter
//! weighs its particles with. The same interpolation as `Grid::eval`'s values, operation for
//! operation, so the values are bit-identical; only the value weights are computed (no slopes),
//! and each pose's cell is looked up once for all its features (they are contiguous per node).
//! With AVX, four features at a time from a copy of the table regrouped by four features (each
//! node value of the four side by side, so a product needs no shuffle): each lane multiplies a
//! feature's four node values by the corner's weights and adds the products in the plain order
//! (no fused multiply-add), so the bits are the plain build's.

use super::grid::hermite;
use super::Grid;
use crate::estimator::continuous::Continuous;

impl Grid {
    /// The values of the `dim` features at each pose of `poses` into `out`, feature-major:
    /// feature i at pose p is `out[i * poses.len() + p]`.
    fn eval_block(&self, poses: &[[f64; 2]], dim: usize, out: &mut [f64]) {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx") {
            // SAFETY: the processor was just found to have AVX, all `eval_block_avx` needs.
            unsafe { self.eval_block_avx(poses, dim, out) };
            return;
        }
        self.eval_block_plain(poses, dim, out);
    }

    fn eval_block_plain(&self, poses: &[[f64; 2]], dim: usize, out: &mut [f64]) {
        let m = poses.len();
        for (p, q) in poses.iter().enumerate() {
            let (weights, nodes) = self.value_weights(*q);
            let at = [
                nodes[0] * dim,
                nodes[1] * dim,
                nodes[2] * dim,
                nodes[3] * dim,
            ];
            self.features_at(&weights, &at, 0..dim, |i, v| out[i * m + p] = v);
        }
    }

    /// Features `range` at one pose from its corner `weights` and table indices `at`, each
    /// value handed to `put` with its feature index.
    #[inline(always)]
    fn features_at(
        &self,
        weights: &[[f64; 4]; 4],
        at: &[usize; 4],
        range: std::ops::Range<usize>,
        mut put: impl FnMut(usize, f64),
    ) {
        for i in range {
            let mut sum = 0.0;
            for (w, &at) in weights.iter().zip(at) {
                let n = &self.table[at + i];
                sum += w[0] * n[0] + w[1] * n[1] + w[2] * n[2] + w[3] * n[3];
            }
            put(i, sum);
        }
    }

    /// [`Grid::eval_block_plain`] four features at a time in 256-bit vectors, from the table
    /// regrouped ([`Grid::lanes`]): per corner, each node value of four features times its
    /// weight in one product, and each lane adds its feature's four products in the plain order.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx")]
    fn eval_block_avx(&self, poses: &[[f64; 2]], dim: usize, out: &mut [f64]) {
        use std::arch::x86_64::{
            __m256d, _mm256_add_pd, _mm256_castpd256_pd128, _mm256_extractf128_pd, _mm256_loadu_pd,
            _mm256_mul_pd, _mm256_set1_pd, _mm256_setzero_pd, _mm_cvtsd_f64, _mm_unpackhi_pd,
        };
        let lanes = |v: __m256d| {
            let (lo, hi) = (_mm256_castpd256_pd128(v), _mm256_extractf128_pd::<1>(v));
            [
                _mm_cvtsd_f64(lo),
                _mm_cvtsd_f64(_mm_unpackhi_pd(lo, lo)),
                _mm_cvtsd_f64(hi),
                _mm_cvtsd_f64(_mm_unpackhi_pd(hi, hi)),
            ]
        };
        let m = poses.len();
        let groups = dim / 4;
        let grouped = self.lanes(dim);
        for (p, q) in poses.iter().enumerate() {
            let (weights, nodes) = self.value_weights(*q);
            for g in 0..groups {
                let mut sum = _mm256_setzero_pd();
                for (w, &node) in weights.iter().zip(&nodes) {
                    let n = &grouped[node * groups + g];
                    // SAFETY: each `n[k]` is four contiguous doubles.
                    let load = |k: usize| unsafe { _mm256_loadu_pd(n[k].as_ptr()) };
                    let (p0, p1) = (
                        _mm256_mul_pd(_mm256_set1_pd(w[0]), load(0)),
                        _mm256_mul_pd(_mm256_set1_pd(w[1]), load(1)),
                    );
                    let (p2, p3) = (
                        _mm256_mul_pd(_mm256_set1_pd(w[2]), load(2)),
                        _mm256_mul_pd(_mm256_set1_pd(w[3]), load(3)),
                    );
                    let t = _mm256_add_pd(_mm256_add_pd(_mm256_add_pd(p0, p1), p2), p3);
                    sum = _mm256_add_pd(sum, t);
                }
                for (l, v) in lanes(sum).into_iter().enumerate() {
                    out[(4 * g + l) * m + p] = v;
                }
            }
            let at = [
                nodes[0] * dim,
                nodes[1] * dim,
                nodes[2] * dim,
                nodes[3] * dim,
            ];
            self.features_at(&weights, &at, 4 * groups..dim, |i, v| out[i * m + p] = v);
        }
    }

    /// The table's first `dim − dim % 4` features regrouped by four (made once per grid):
    /// entry `node · (dim / 4) + g` holds, for each node value k (f, h·fx, h·fy, h²·fxy), that
    /// value of features 4g to 4g + 3.
    fn lanes(&self, dim: usize) -> &[[[f64; 4]; 4]] {
        self.lanes.get_or_init(|| {
            let groups = dim / 4;
            if groups == 0 {
                return Vec::new();
            }
            let mut grouped = Vec::with_capacity(self.table.len() / dim * groups);
            for node in self.table.chunks_exact(dim) {
                for g in 0..groups {
                    let four = &node[4 * g..4 * g + 4];
                    grouped.push(std::array::from_fn(|k| std::array::from_fn(|l| four[l][k])));
                }
            }
            grouped
        })
    }

    /// Per corner of `q`'s cell: the weights of f, h·fx, h·fy, h²·fxy (as `Grid::eval` forms
    /// them) and the corner's node.
    #[inline(always)]
    fn value_weights(&self, q: [f64; 2]) -> ([[f64; 4]; 4], [usize; 4]) {
        let (cell, t) = self.locate(q);
        let (bx, by) = (hermite(t[0]), hermite(t[1]));
        let [hx, hy] = self.step;
        // Written out rather than mapped over the corners: `array::map` was not inlined.
        let weight = |a: usize, b: usize| {
            let (v0, v1, w0, w1) = (bx[2 * a], bx[2 * a + 1], by[2 * b], by[2 * b + 1]);
            [v0 * w0, hx * v1 * w0, hy * v0 * w1, hx * hy * v1 * w1]
        };
        let node = |a: usize, b: usize| (cell[1] + b) * self.nodes[0] + cell[0] + a;
        (
            [weight(0, 0), weight(1, 0), weight(0, 1), weight(1, 1)],
            [node(0, 0), node(1, 0), node(0, 1), node(1, 1)],
        )
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
        // 5 features: one vector of four (with AVX) and one alone; 8: two vectors; 3: none.
        for dim in [5, 8, 3] {
            let maps = fitted_continuous(dim, 8, 20, 0.01, false, 2);
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
            // Inside the workspace and beyond the grid on every side (clamped).
            let mut poses = workspace_points(300, &mut rng);
            poses.extend([[-500.0, 47.0], [500.0, 47.0], [0.0, -500.0], [0.0, 500.0]]);
            let mut out = vec![f64::NAN; dim * poses.len()];
            maps.feature_maps_block(&poses, &mut out);
            let mut plain = vec![f64::NAN; dim * poses.len()];
            maps.surrogate
                .grid
                .eval_block_plain(&poses, dim, &mut plain);
            for (p, &q) in poses.iter().enumerate() {
                for (i, v) in maps.feature_map(q).iter().enumerate() {
                    let k = i * poses.len() + p;
                    assert_eq!(out[k].to_bits(), v.to_bits(), "{dim}: {q:?} {i}");
                    assert_eq!(plain[k].to_bits(), v.to_bits(), "{dim}: {q:?} {i}");
                }
            }
        }
    }
}
