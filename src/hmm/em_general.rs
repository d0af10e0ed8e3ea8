//! The forward and backward recursions for any number of states (beyond the specialised
//! K ≤ 6 of `em.rs`), register-blocked and widened with AVX where the processor has it.
//!
//! Every sum keeps the order of the plain per-state loops (terms added one after another into
//! a sum that starts at 0), so the bits are those loops' bits; only which sums run side by side
//! changes (`general_recursions_are_the_sums_per_state_bit_for_bit`).

use super::{Params, Workspace};

/// `out[j] = Σ_r a_r · row_r[j]` for j < `out.len()`, over the `(a_r, row_r)` of `terms` in
/// their order, each sum starting at 0. The sums run in blocks held in registers while the
/// terms are walked once per block: the widest block that fits, so that enough independent
/// chains of additions hide each addition's latency.
#[inline(always)]
fn ordered_sums<'a, I>(terms: I, out: &mut [f64])
where
    I: Iterator<Item = (f64, &'a [f64])> + Clone,
{
    let mut j0 = 0;
    while j0 < out.len() {
        j0 += match out.len() - j0 {
            32.. => block::<32, _>(terms.clone(), j0, out),
            24.. => block::<24, _>(terms.clone(), j0, out),
            16.. => block::<16, _>(terms.clone(), j0, out),
            12.. => block::<12, _>(terms.clone(), j0, out),
            8.. => block::<8, _>(terms.clone(), j0, out),
            4.. => block::<4, _>(terms.clone(), j0, out),
            2.. => block::<2, _>(terms.clone(), j0, out),
            _ => block::<1, _>(terms.clone(), j0, out),
        };
    }
}

/// The sums of `out[j0..j0 + W]`; returns W.
#[inline(always)]
fn block<'a, const W: usize, I>(terms: I, j0: usize, out: &mut [f64]) -> usize
where
    I: Iterator<Item = (f64, &'a [f64])>,
{
    let mut acc = [0.0f64; W];
    for (a, row) in terms {
        let lanes = &row[j0..j0 + W];
        for c in 0..W {
            acc[c] += a * lanes[c];
        }
    }
    out[j0..j0 + W].copy_from_slice(&acc);
    W
}

crate::simd::with_avx!(
    /// [`forward_of`], with AVX where the processor has it.
    fn forward(ws: &mut Workspace, p: &Params) -> Option<f64> = forward_of
);

crate::simd::with_avx!(
    /// [`backward_of`], with AVX where the processor has it.
    fn backward(ws: &mut Workspace, y: &[f64], p: &Params) -> bool = backward_of
);

/// αₜ(j) = (Σᵢ αₜ₋₁(i) Aᵢⱼ) b'ₜ(j), rescaled; returns Σ ln(rescaling factors).
#[inline(always)]
fn forward_of(ws: &mut Workspace, p: &Params) -> Option<f64> {
    let (n, k) = (ws.n, ws.k);
    let mut log_scale = 0.0;
    for j in 0..k {
        ws.alpha[j] = p.initial[j] * ws.emis[j * n];
    }
    log_scale += Workspace::rescale(&mut ws.alpha[..k], &mut ws.inv_scale[0])?;
    let mut sums = vec![0.0; k];
    for t in 1..n {
        let (done, todo) = ws.alpha.split_at_mut(t * k);
        let prev = &done[(t - 1) * k..];
        ordered_sums(prev.iter().copied().zip(p.trans.chunks_exact(k)), &mut sums);
        let cur = &mut todo[..k];
        for (j, (c, &s)) in cur.iter_mut().zip(&sums).enumerate() {
            *c = s * ws.emis[j * n + t];
        }
        log_scale += Workspace::rescale(cur, &mut ws.inv_scale[t])?;
    }
    Some(log_scale)
}

/// β, the γ sums and the ξ sums (ξ from the wₜ kept during the pass, at the end).
#[inline(always)]
fn backward_of(ws: &mut Workspace, y: &[f64], p: &Params) -> bool {
    let (n, k) = (ws.n, ws.k);
    let total: f64 = ws.alpha[(n - 1) * k..n * k].iter().sum();
    if !(total > 0.0 && total.is_finite()) {
        return false;
    }
    ws.gamma_sum.fill(0.0);
    ws.gamma_y.fill(0.0);
    ws.gamma_yy.fill(0.0);
    // Aᵀ: β_{t−1}(i) = Σⱼ Aᵢⱼ wₜ(j) is then a sum of rows of Aᵀ.
    let mut trans_t = vec![0.0; k * k];
    for (i, row) in p.trans.chunks_exact(k).enumerate() {
        for (j, &t_ij) in row.iter().enumerate() {
            trans_t[j * k + i] = t_ij;
        }
    }
    // wₜ(j) = b'ₜ(j) βₜ(j) / scaleₜ, row t (row 0 unused).
    let mut w = vec![0.0; n * k];
    let mut beta = vec![1.0; k];
    for t in (0..n).rev() {
        let alpha = &ws.alpha[t * k..(t + 1) * k];
        let yt = y[t];
        for i in 0..k {
            let g = alpha[i] * beta[i];
            ws.gamma_sum[i] += g;
            ws.gamma_y[i] += g * yt;
            ws.gamma_yy[i] += g * yt * yt;
            if t == 0 {
                ws.gamma_first[i] = g;
            }
        }
        if t == 0 {
            break;
        }
        let inv = ws.inv_scale[t];
        let w_t = &mut w[t * k..(t + 1) * k];
        for (j, wj) in w_t.iter_mut().enumerate() {
            *wj = ws.emis[j * n + t] * beta[j] * inv;
        }
        ordered_sums(w_t.iter().copied().zip(trans_t.chunks_exact(k)), &mut beta);
    }
    // ξ(i, j) = Σₜ αₜ₋₁(i) wₜ(j), t from the last step down, as the pass visits them.
    let (alpha, w) = (&ws.alpha, &w);
    for (i, xi_row) in ws.xi_sum.chunks_exact_mut(k).enumerate() {
        let terms = (1..n)
            .rev()
            .map(|t| (alpha[(t - 1) * k + i], &w[t * k..(t + 1) * k]));
        ordered_sums(terms, xi_row);
    }
    let r = 1.0 / total;
    for i in 0..k {
        ws.gamma_sum[i] *= r;
        ws.gamma_y[i] *= r;
        ws.gamma_yy[i] *= r;
        ws.gamma_first[i] *= r;
        for j in 0..k {
            ws.xi_sum[i * k + j] *= p.trans[i * k + j] * r;
        }
    }
    ws.statistics_finite()
}

impl Workspace {
    /// Forward recursion for any number of states.
    pub(super) fn forward_dyn(&mut self, p: &Params) -> Option<f64> {
        forward(self, p)
    }

    /// Backward pass with the E-step statistics for any number of states; requires
    /// `forward_dyn` on the same parameters. Returns false on a numerical failure.
    pub(super) fn backward_dyn(&mut self, y: &[f64], p: &Params) -> bool {
        backward(self, y, p)
    }
}
