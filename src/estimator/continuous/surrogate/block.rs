//! The tabulated maps at many poses at once, feature-major (issue 32): what the particle filter
//! weighs its particles with. The same interpolation as `Grid::eval`'s values, operation for
//! operation, so the values are bit-identical; only the value weights are computed (no slopes),
//! and each pose's cell is looked up once for all its features (they are contiguous per node).
//! With AVX, four features at a time: each lane multiplies a feature's four node values by the
//! corner's weights and adds the products in the plain order (no fused multiply-add), so the
//! bits are the plain build's.

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
            let (weights, at) = self.value_weights(*q, dim);
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

    /// [`Grid::eval_block_plain`] four features at a time in 256-bit vectors: per corner, four
    /// features' node values times the weights, transposed so that each lane adds its feature's
    /// four products in the plain order.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx")]
    fn eval_block_avx(&self, poses: &[[f64; 2]], dim: usize, out: &mut [f64]) {
        use std::arch::x86_64::{
            __m256d, _mm256_add_pd, _mm256_castpd256_pd128, _mm256_extractf128_pd, _mm256_mul_pd,
            _mm256_permute2f128_pd, _mm256_set_pd, _mm256_setzero_pd, _mm256_unpackhi_pd,
            _mm256_unpacklo_pd, _mm_cvtsd_f64, _mm_unpackhi_pd,
        };
        let load = |n: &[f64; 4]| _mm256_set_pd(n[3], n[2], n[1], n[0]);
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
        let wide = dim - dim % 4;
        for (p, q) in poses.iter().enumerate() {
            let (weights, at) = self.value_weights(*q, dim);
            let w = [
                load(&weights[0]),
                load(&weights[1]),
                load(&weights[2]),
                load(&weights[3]),
            ];
            for i in (0..wide).step_by(4) {
                let mut sum = _mm256_setzero_pd();
                for (w, &at) in w.iter().zip(&at) {
                    let n = &self.table[at + i..at + i + 4];
                    let (p0, p1) = (
                        _mm256_mul_pd(*w, load(&n[0])),
                        _mm256_mul_pd(*w, load(&n[1])),
                    );
                    let (p2, p3) = (
                        _mm256_mul_pd(*w, load(&n[2])),
                        _mm256_mul_pd(*w, load(&n[3])),
                    );
                    // Column k holds the four features' k-th products.
                    let (a, b) = (_mm256_unpacklo_pd(p0, p1), _mm256_unpackhi_pd(p0, p1));
                    let (c, d) = (_mm256_unpacklo_pd(p2, p3), _mm256_unpackhi_pd(p2, p3));
                    let c0 = _mm256_permute2f128_pd::<0x20>(a, c);
                    let c1 = _mm256_permute2f128_pd::<0x20>(b, d);
                    let c2 = _mm256_permute2f128_pd::<0x31>(a, c);
                    let c3 = _mm256_permute2f128_pd::<0x31>(b, d);
                    let t = _mm256_add_pd(_mm256_add_pd(_mm256_add_pd(c0, c1), c2), c3);
                    sum = _mm256_add_pd(sum, t);
                }
                for (l, v) in lanes(sum).into_iter().enumerate() {
                    out[(i + l) * m + p] = v;
                }
            }
            self.features_at(&weights, &at, wide..dim, |i, v| out[i * m + p] = v);
        }
    }

    /// Per corner of `q`'s cell: the weights of f, h·fx, h·fy, h²·fxy (as `Grid::eval` forms
    /// them) and the corner's first table index.
    #[inline(always)]
    fn value_weights(&self, q: [f64; 2], dim: usize) -> ([[f64; 4]; 4], [usize; 4]) {
        let (cell, t) = self.locate(q);
        let (bx, by) = (hermite(t[0]), hermite(t[1]));
        let [hx, hy] = self.step;
        // Written out rather than mapped over the corners: `array::map` was not inlined.
        let weight = |a: usize, b: usize| {
            let (v0, v1, w0, w1) = (bx[2 * a], bx[2 * a + 1], by[2 * b], by[2 * b + 1]);
            [v0 * w0, hx * v1 * w0, hy * v0 * w1, hx * hy * v1 * w1]
        };
        let index = |a: usize, b: usize| ((cell[1] + b) * self.nodes[0] + cell[0] + a) * dim;
        (
            [weight(0, 0), weight(1, 0), weight(0, 1), weight(1, 1)],
            [index(0, 0), index(1, 0), index(0, 1), index(1, 1)],
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
