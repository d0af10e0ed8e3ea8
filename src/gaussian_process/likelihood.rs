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
    /// (z_i,d − z_j,d)² for each pair i < j (j-major), then each d.
    diffs: Vec<f64>,
    /// Scaled outputs of the fit samples (m × outputs).
    y: DMatrix<f64>,
    /// The m × m buffers of earlier evaluations, for the next ones: fresh ones cost a page
    /// fault per 4 KiB (the allocator hands large blocks back to the system), a tenth of a fit.
    spare: Mutex<Vec<Buffers>>,
}

/// The large buffers of one evaluation (their contents do not carry over).
#[derive(Debug, Default)]
struct Buffers {
    /// The kernel matrix, then its Cholesky factor.
    kernel: Vec<f64>,
    /// Kernel values of the pairs i < j.
    kf: Vec<f64>,
    /// The upper triangle of K⁻¹.
    inverse: Vec<f64>,
    scratch: InverseScratch,
}

impl Objective {
    /// The objective on the samples `subset` of row-major `inputs` (`dim` per sample) and
    /// row-major `outputs` (`outputs.len() / samples` per sample).
    pub fn new(inputs: &[f64], outputs: &[f64], dim: usize, subset: &[usize]) -> Self {
        let m = subset.len();
        let mut diffs = Vec::with_capacity(m * m.saturating_sub(1) / 2 * dim);
        for j in 0..m {
            for i in 0..j {
                let (a, b) = (subset[i] * dim, subset[j] * dim);
                diffs.extend((0..dim).map(|d| (inputs[a + d] - inputs[b + d]).powi(2)));
            }
        }
        let k = outputs.len() / (inputs.len() / dim.max(1)).max(1);
        let y = DMatrix::from_fn(m, k, |i, o| outputs[subset[i] * k + o]);
        Self {
            m,
            dim,
            outputs: k,
            diffs,
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
        let mut kernel = DMatrix::from_vec(m, m, kernel);
        let mut kf = std::mem::take(&mut buffers.kf);
        kf.clear();
        kf.reserve(self.diffs.len() / dim.max(1));
        let mut pairs = self.diffs.chunks_exact(dim);
        for j in 0..m {
            for i in 0..j {
                let diff = pairs.next()?;
                let r2: f64 = diff.iter().zip(&inv_l2).map(|(a, b)| a * b).sum();
                let k = sf2 * (-0.5 * r2).exp();
                kernel[(i, j)] = k;
                kernel[(j, i)] = k;
                kf.push(k);
            }
            kernel[(j, j)] = sf2 + sn2;
        }
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
            kf,
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
            kf,
            chol,
            alpha,
            buffers,
            ..
        } = point;
        // W = Σ_o α_o α_oᵀ − (outputs)·K⁻¹; ∂L/∂θ = ½ tr(W ∂K/∂θ).
        let (inv_l2, sf2, sn2, kf, alpha) = (&*inv_l2, *sf2, *sn2, &*kf, &*alpha);
        let Buffers {
            inverse, scratch, ..
        } = buffers;
        upper_inverse_into(chol.as_ref()?.l_dirty(), scratch, inverse);
        let inverse = &*inverse;
        // Only i ≤ j is read: the upper triangle of K⁻¹, column-major.
        let w = |i: usize, j: usize| {
            let aa: f64 = (0..self.outputs)
                .map(|o| alpha[(i, o)] * alpha[(j, o)])
                .sum();
            aa - outputs * inverse[i + j * m]
        };
        let mut grad = vec![0.0; dim + 2];
        let mut off_diagonal = 0.0;
        let pairs = (0..m).flat_map(|j| (0..j).map(move |i| (i, j)));
        for (((i, j), k), diff) in pairs.zip(kf).zip(self.diffs.chunks_exact(dim)) {
            let wk = w(i, j) * k;
            off_diagonal += wk;
            for ((g, d), il) in grad.iter_mut().zip(diff).zip(inv_l2) {
                *g += wk * d * il;
            }
        }
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
    /// Kernel values of the pairs i < j, in the order of the differences.
    kf: Vec<f64>,
    /// Always `Some` until dropped.
    chol: Option<Cholesky<f64, Dyn>>,
    alpha: DMatrix<f64>,
    /// The other buffers (the kernel's and the pairs' are in `chol` and `kf`).
    buffers: Buffers,
    spare: &'a Mutex<Vec<Buffers>>,
}

impl Drop for Point<'_> {
    fn drop(&mut self) {
        let mut buffers = std::mem::take(&mut self.buffers);
        buffers.kf = std::mem::take(&mut self.kf);
        if let Some(chol) = self.chol.take() {
            buffers.kernel = chol.unpack_dirty().data.into();
        }
        let mut spare = self.spare.lock().unwrap_or_else(|e| e.into_inner());
        if spare.len() < SPARE_BUFFERS {
            spare.push(buffers);
        }
    }
}
