//! The log marginal likelihood of the hyperparameters with its analytic gradient, and the
//! inverse of a kernel matrix from its Cholesky factor.

use std::sync::Mutex;

use nalgebra::{Cholesky, DMatrix, Dyn};

use super::cholesky::cholesky;
use super::inverse::{upper_inverse_into, InverseScratch};

/// Sets of buffers an objective keeps for its next evaluations (one per thread evaluating it at
/// once is enough; more are dropped).
const SPARE_BUFFERS: usize = 4;

/// Minus the log marginal likelihood per fit sample, summed over the outputs (one kernel shared
/// by all), as a function of θ = (log ℓ_1 … log ℓ_D, log σf, log(σn/σf)) (a ratio, so that every
/// bound is a box).
pub struct Objective {
    m: usize,
    dim: usize,
    /// Outputs per sample.
    outputs: usize,
    /// The fit samples' inputs, feature by feature (`d·m + i`): the kernel's loops run along
    /// samples. The squared differences are formed again at each evaluation, as before stored
    /// (the same bits): m²·D/2 of them were megabytes read twice per evaluation.
    columns: Vec<f64>,
    /// The same, sample by sample (`i·padded + d`), each padded with zeros to `padded` (a
    /// multiple of 4): the gradient's loops run along features.
    rows: Vec<f64>,
    padded: usize,
    /// Scaled outputs of the fit samples (m × outputs).
    y: DMatrix<f64>,
    /// The m × m buffers of earlier evaluations, for the next ones: fresh ones cost a page
    /// fault per 4 KiB (the allocator hands large blocks back to the system), a tenth of a fit.
    spare: Mutex<Vec<Buffers>>,
}

/// The large buffers of one evaluation (their contents do not carry over).
#[derive(Debug, Default)]
struct Buffers {
    /// The kernel matrix, then its Cholesky factor below the diagonal and K above it.
    kernel: Vec<f64>,
    /// One column's squared scaled distances.
    distances: Vec<f64>,
    /// The upper triangle of K⁻¹.
    inverse: Vec<f64>,
    scratch: InverseScratch,
}

impl Objective {
    /// The objective on the samples `subset` of row-major `inputs` (`dim` per sample) and
    /// row-major `outputs` (`outputs.len() / samples` per sample).
    pub fn new(inputs: &[f64], outputs: &[f64], dim: usize, subset: &[usize]) -> Self {
        let m = subset.len();
        let columns = (0..dim)
            .flat_map(|d| subset.iter().map(move |&i| inputs[i * dim + d]))
            .collect();
        let padded = dim.div_ceil(4).max(1) * 4;
        let mut rows = vec![0.0; m * padded];
        for (row, &i) in rows.chunks_exact_mut(padded).zip(subset) {
            row[..dim].copy_from_slice(&inputs[i * dim..(i + 1) * dim]);
        }
        let k = outputs.len() / (inputs.len() / dim.max(1)).max(1);
        let y = DMatrix::from_fn(m, k, |i, o| outputs[subset[i] * k + o]);
        Self {
            m,
            dim,
            outputs: k,
            columns,
            rows,
            padded,
            y,
            spare: Mutex::default(),
        }
    }

    /// Value and gradient at θ; `None` where the kernel matrix is not positive definite.
    pub fn eval(&self, theta: &[f64]) -> Option<(f64, Vec<f64>)> {
        let mut point = self.value(theta)?;
        let grad = self.gradient(&mut point)?;
        Some((point.value, grad))
    }

    /// The value at θ and what its gradient needs; `None` where the kernel matrix is not
    /// positive definite or the value is not finite. A line search rejects most of its trial
    /// points on the value alone, so the gradient (an inverse, as costly as the factor) waits.
    pub(super) fn value(&self, theta: &[f64]) -> Option<Point<'_>> {
        let (m, dim, outputs) = (self.m, self.dim, self.outputs as f64);
        let inv_l2: Vec<f64> = theta[..dim].iter().map(|t| (-2.0 * t).exp()).collect();
        let sf2 = (2.0 * theta[dim]).exp();
        let sn2 = (2.0 * (theta[dim] + theta[dim + 1])).exp();
        let mut buffers = self.take_buffers();
        // Every entry is written below, so the buffer's earlier contents do not matter.
        let mut kernel = std::mem::take(&mut buffers.kernel);
        kernel.resize(m * m, 0.0);
        let distances = &mut buffers.distances;
        distances.resize(m, 0.0);
        // Column i below the diagonal: each entry's sum over d in increasing d, as before, but
        // samples side by side (vectorised) and stored at consecutive addresses.
        for i in 0..m {
            let below = &mut distances[i + 1..m];
            below.fill(0.0);
            for (column, il) in self.columns.chunks_exact(m.max(1)).zip(&inv_l2) {
                let zi = column[i];
                for (r2, zj) in below.iter_mut().zip(&column[i + 1..]) {
                    let t = zi - zj;
                    *r2 += t * t * il;
                }
            }
            let column = &mut kernel[i * m..(i + 1) * m];
            column[i] = sf2 + sn2;
            for (k, r2) in column[i + 1..].iter_mut().zip(below.iter()) {
                *k = sf2 * (-0.5 * r2).exp();
            }
        }
        // Above the diagonal too: the factor keeps it, and the gradient reads K there.
        mirror_lower(&mut kernel, m);
        let kernel = DMatrix::from_vec(m, m, kernel);
        let chol = cholesky(kernel)?;
        let alpha = chol.solve(&self.y);
        let log_det: f64 = 2.0 * (0..m).map(|i| chol.l_dirty()[(i, i)].ln()).sum::<f64>();
        let fit: f64 = self.y.iter().zip(alpha.iter()).map(|(a, b)| a * b).sum();
        // Grouped so that two outputs give the same bits as the two-output formula.
        let lml = -0.5 * fit
            - 0.5 * outputs * log_det
            - 0.5 * outputs * m as f64 * (2.0 * std::f64::consts::PI).ln();
        let value = -1.0 / m as f64 * lml;
        let point = Point {
            value,
            inv_l2,
            sf2,
            sn2,
            chol: Some(chol),
            alpha,
            buffers,
            spare: &self.spare,
        };
        value.is_finite().then_some(point)
    }

    /// A set of buffers from earlier evaluations, or new ones.
    fn take_buffers(&self) -> Buffers {
        let mut spare = self.spare.lock().unwrap_or_else(|e| e.into_inner());
        spare.pop().unwrap_or_default()
    }

    /// The gradient at a point [`Objective::value`] found; `None` where it is not finite.
    pub(super) fn gradient(&self, point: &mut Point<'_>) -> Option<Vec<f64>> {
        let (m, dim, outputs) = (self.m, self.dim, self.outputs as f64);
        let Point {
            inv_l2,
            sf2,
            sn2,
            chol,
            alpha,
            buffers,
            ..
        } = point;
        // W = Σ_o α_o α_oᵀ − (outputs)·K⁻¹; ∂L/∂θ = ½ tr(W ∂K/∂θ).
        let (inv_l2, sf2, sn2, alpha) = (&*inv_l2, *sf2, *sn2, &*alpha);
        let Buffers {
            inverse, scratch, ..
        } = buffers;
        // The factor below the diagonal, K above it (as built, kept by the factorisation).
        let factor = chol.as_ref()?.l_dirty();
        upper_inverse_into(factor, scratch, inverse);
        let (inverse, kernel) = (&*inverse, factor.as_slice());
        // Only i ≤ j is read: the upper triangle of K⁻¹, column-major.
        let w = |i: usize, j: usize| {
            let aa: f64 = (0..self.outputs)
                .map(|o| alpha[(i, o)] * alpha[(j, o)])
                .sum();
            aa - outputs * inverse[i + j * m]
        };
        let padded = self.padded;
        let mut scales = vec![0.0; padded];
        scales[..dim].copy_from_slice(inv_l2);
        let mut sums = vec![0.0; padded];
        let pairs = Pairs {
            m,
            padded,
            rows: &self.rows,
            scales: &scales,
            kernel,
            inverse,
            alpha: alpha.as_slice(),
            outputs: self.outputs,
        };
        let off_diagonal = pair_sums(&pairs, &mut sums);
        let mut grad: Vec<f64> = sums[..dim].to_vec();
        grad.extend([0.0, 0.0]);
        let trace: f64 = (0..m).map(|i| w(i, i)).sum();
        // σn = σf·ratio, so log σf moves σn too.
        grad[dim + 1] = sn2 * trace;
        grad[dim] = 2.0 * off_diagonal + sf2 * trace + grad[dim + 1];
        let scale = -1.0 / m as f64;
        let grad: Vec<f64> = grad.iter().map(|g| scale * g).collect();
        grad.iter().all(|g| g.is_finite()).then_some(grad)
    }
}

/// The objective's value at one θ, with what its gradient needs; its buffers go back to the
/// objective when it is dropped.
pub(super) struct Point<'a> {
    pub(super) value: f64,
    inv_l2: Vec<f64>,
    sf2: f64,
    sn2: f64,
    /// Always `Some` until dropped.
    chol: Option<Cholesky<f64, Dyn>>,
    alpha: DMatrix<f64>,
    /// The other buffers (the kernel's is in `chol`).
    buffers: Buffers,
    spare: &'a Mutex<Vec<Buffers>>,
}

impl Drop for Point<'_> {
    fn drop(&mut self) {
        let mut buffers = std::mem::take(&mut self.buffers);
        if let Some(chol) = self.chol.take() {
            buffers.kernel = chol.unpack_dirty().data.into();
        }
        let mut spare = self.spare.lock().unwrap_or_else(|e| e.into_inner());
        if spare.len() < SPARE_BUFFERS {
            spare.push(buffers);
        }
    }
}

/// Copies the strict lower triangle of a column-major n × n matrix onto its upper triangle, in
/// square blocks (a plain transpose strides through memory on one side).
fn mirror_lower(matrix: &mut [f64], n: usize) {
    const BLOCK: usize = 32;
    for j0 in (0..n).step_by(BLOCK) {
        for i0 in (0..=j0).step_by(BLOCK) {
            for j in j0..(j0 + BLOCK).min(n) {
                for i in i0..(i0 + BLOCK).min(j) {
                    matrix[i + j * n] = matrix[j + i * n];
                }
            }
        }
    }
}

/// What the gradient's sums over the pairs i < j read.
struct Pairs<'a> {
    m: usize,
    padded: usize,
    /// The fit samples' inputs, `padded` per sample (zeros past the features).
    rows: &'a [f64],
    /// 1/ℓ_d², zeros past the features.
    scales: &'a [f64],
    /// K above the diagonal, column-major m × m.
    kernel: &'a [f64],
    /// K⁻¹ on and above the diagonal, column-major m × m.
    inverse: &'a [f64],
    /// α, column-major m × outputs.
    alpha: &'a [f64],
    outputs: usize,
}

/// Σ W_ij·K_ij over the pairs i < j (returned) and, into `sums` (`padded` long), Σ W_ij·K_ij·
/// (z_i,d − z_j,d)²/ℓ_d² for each d: every sum over the pairs in the order j, then i, as the
/// stored differences were summed. With AVX and 4 or 8 padded features, the features' sums sit
/// in registers (the compiler's own widening shuffled them through memory).
fn pair_sums(pairs: &Pairs<'_>, sums: &mut [f64]) -> f64 {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx") {
        // SAFETY (both): the processor was just found to have AVX, all they need.
        match pairs.padded {
            4 => return unsafe { pair_sums_avx::<1>(pairs, sums) },
            8 => return unsafe { pair_sums_avx::<2>(pairs, sums) },
            _ => {}
        }
    }
    let mut off_diagonal = 0.0;
    for_each_pair(pairs, |wk, zi, zj| {
        off_diagonal += wk;
        let blocks = zi.chunks_exact(4).zip(zj.chunks_exact(4));
        let blocks = blocks.zip(pairs.scales.chunks_exact(4));
        for (sum, ((a, b), il)) in sums.chunks_exact_mut(4).zip(blocks) {
            for x in 0..4 {
                let t = a[x] - b[x];
                sum[x] += wk * (t * t) * il[x];
            }
        }
    });
    off_diagonal
}

/// Calls `f(W_ij·K_ij, z_i, z_j)` for the pairs i < j in the order j, then i.
#[inline(always)]
fn for_each_pair(pairs: &Pairs<'_>, mut f: impl FnMut(f64, &[f64], &[f64])) {
    let Pairs {
        m,
        padded,
        rows,
        kernel,
        inverse,
        alpha,
        outputs,
        ..
    } = *pairs;
    let weight = outputs as f64;
    for (j, zj) in rows.chunks_exact(padded).enumerate().take(m) {
        let column = kernel[j * m..j * m + j]
            .iter()
            .zip(&inverse[j * m..j * m + j]);
        for (i, ((k, inv), zi)) in column.zip(rows.chunks_exact(padded)).enumerate() {
            let aa: f64 = (0..outputs)
                .map(|o| alpha[i + o * m] * alpha[j + o * m])
                .sum();
            f((aa - weight * inv) * k, zi, zj);
        }
    }
}

/// [`pair_sums`] with `BLOCKS` × 4 padded features in AVX registers: each lane adds
/// (W_ij·K_ij·t²)·(1/ℓ²) rounded as the plain loop does.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
fn pair_sums_avx<const BLOCKS: usize>(pairs: &Pairs<'_>, sums: &mut [f64]) -> f64 {
    use std::arch::x86_64::{
        __m256d, _mm256_add_pd, _mm256_loadu_pd, _mm256_mul_pd, _mm256_set1_pd, _mm256_setzero_pd,
        _mm256_storeu_pd, _mm256_sub_pd,
    };
    let load = |values: &[f64]| -> __m256d {
        let values: &[f64; 4] = values[..4].try_into().unwrap_or(&[0.0; 4]);
        // SAFETY: `values` holds four f64; the closure runs inside this AVX function.
        unsafe { _mm256_loadu_pd(values.as_ptr()) }
    };
    let mut held = [_mm256_setzero_pd(); BLOCKS];
    let mut scales = [_mm256_setzero_pd(); BLOCKS];
    for (scale, values) in scales.iter_mut().zip(pairs.scales.chunks_exact(4)) {
        *scale = load(values);
    }
    let mut off_diagonal = 0.0;
    let mut last_j: Option<*const f64> = None;
    let mut zj = [_mm256_setzero_pd(); BLOCKS];
    for_each_pair(pairs, |wk, zi, zj_row| {
        off_diagonal += wk;
        if last_j != Some(zj_row.as_ptr()) {
            last_j = Some(zj_row.as_ptr());
            for (value, values) in zj.iter_mut().zip(zj_row.chunks_exact(4)) {
                *value = load(values);
            }
        }
        let w = _mm256_set1_pd(wk);
        for ((sum, values), (b, il)) in held
            .iter_mut()
            .zip(zi.chunks_exact(4))
            .zip(zj.iter().zip(&scales))
        {
            let t = _mm256_sub_pd(load(values), *b);
            *sum = _mm256_add_pd(
                *sum,
                _mm256_mul_pd(_mm256_mul_pd(w, _mm256_mul_pd(t, t)), *il),
            );
        }
    });
    for (sum, values) in held.iter().zip(sums.chunks_exact_mut(4)) {
        let values: &mut [f64; 4] = match values.try_into() {
            Ok(values) => values,
            Err(_) => break,
        };
        // SAFETY: `values` holds four f64.
        unsafe { _mm256_storeu_pd(values.as_mut_ptr(), *sum) };
    }
    off_diagonal
}
