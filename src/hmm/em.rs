//! The EM machinery: scaled forward–backward passes over a reusable [`Workspace`], the M-step,
//! one Baum–Welch run ([`em`]), the per-state emission constants used by evaluation, and the
//! fast `exp` of the E-step.

use super::{GaussianHmm, HmmSettings, LN_2PI, MAX_SQUARED_DISTANCE};

/// ln of the smallest scaled emission used by the forward–backward pass, 1e-150: an emission
/// `1e-150` times smaller than the best state's counts as `1e-150` (a negligible change), which
/// keeps every forward step from underflowing.
const LN_EMISSION_FLOOR: f64 = -345.387_763_949_107;

/// eˣ for x in [−700, 0], accurate to a few ulp; an inlinable, branch-free replacement for
/// `f64::exp` in the E-step, where it is the hot spot (the emission pass over all T × N
/// densities vectorises with it). x = k ln 2 + r with |r| ≤ ln 2 / 2, then eʳ by its Taylor
/// series to degree 13 (truncation error below 1e-17) and 2ᵏ from the exponent bits.
#[inline(always)]
fn exp_nonpositive(x: f64) -> f64 {
    // ln 2 split so that k × LN2_HI is exact for |k| < 2²⁰.
    const LN2_HI: f64 = 0.693_147_180_369_123_8;
    const LN2_LO: f64 = 1.908_214_929_270_587_7e-10;
    // Adding 1.5 × 2⁵² rounds x log₂e to the nearest integer k and leaves k in the low
    // mantissa bits: no float-to-integer conversion, which SSE2 lacks for packed f64.
    const SHIFT: f64 = 6_755_399_441_055_744.0;
    let t = x * std::f64::consts::LOG2_E + SHIFT;
    let kf = t - SHIFT;
    let r = (x - kf * LN2_HI) - kf * LN2_LO;
    // Coefficients 1/i!, i = 0..=13, evaluated by Estrin's scheme (a shallow dependency chain).
    const C: [f64; 14] = [
        1.0,
        1.0,
        1.0 / 2.0,
        1.0 / 6.0,
        1.0 / 24.0,
        1.0 / 120.0,
        1.0 / 720.0,
        1.0 / 5_040.0,
        1.0 / 40_320.0,
        1.0 / 362_880.0,
        1.0 / 3_628_800.0,
        1.0 / 39_916_800.0,
        1.0 / 479_001_600.0,
        1.0 / 6_227_020_800.0,
    ];
    let r2 = r * r;
    let r4 = r2 * r2;
    let r8 = r4 * r4;
    let q0 = (C[0] + C[1] * r) + (C[2] + C[3] * r) * r2;
    let q1 = (C[4] + C[5] * r) + (C[6] + C[7] * r) * r2;
    let q2 = (C[8] + C[9] * r) + (C[10] + C[11] * r) * r2;
    let q3 = C[12] + C[13] * r;
    let p = (q0 + q1 * r4) + (q2 + q3 * r4) * r8;
    // The low 12 bits of t's bit pattern plus the exponent bias are k + 1023 ∈ [13, 1023]
    // (the constant part of SHIFT has zero low bits); shifted into the exponent field they
    // give 2ᵏ.
    p * f64::from_bits(t.to_bits().wrapping_add(1023) << 52)
}

/// Per-state constants of the Gaussian log density.
pub(super) struct EmissionConsts {
    means: Vec<f64>,
    log_norm: Vec<f64>,
    inv_sd: Vec<f64>,
}

impl EmissionConsts {
    pub(super) fn new(means: &[f64], variances: &[f64]) -> Self {
        Self {
            means: means.to_vec(),
            log_norm: variances.iter().map(|v| -0.5 * (LN_2PI + v.ln())).collect(),
            inv_sd: variances.iter().map(|v| 1.0 / v.sqrt()).collect(),
        }
    }

    #[inline]
    pub(super) fn log_density(&self, j: usize, y: f64) -> f64 {
        let d = (y - self.means[j]) * self.inv_sd[j];
        self.log_norm[j] - 0.5 * (d * d).min(MAX_SQUARED_DISTANCE)
    }
}

/// Parameters during EM, flat.
#[derive(Clone, PartialEq)]
pub(super) struct Params {
    pub(super) k: usize,
    pub(super) initial: Vec<f64>,
    /// Row-major k × k.
    pub(super) trans: Vec<f64>,
    pub(super) means: Vec<f64>,
    pub(super) variances: Vec<f64>,
}

impl Params {
    pub(super) fn from_hmm(h: &GaussianHmm) -> Self {
        Self {
            k: h.n_states(),
            initial: h.initial.clone(),
            trans: h.transitions.iter().flatten().copied().collect(),
            means: h.means.clone(),
            variances: h.variances.clone(),
        }
    }

    /// Relabels states by increasing mean and renormalises probabilities exactly.
    pub(super) fn into_sorted_hmm(self) -> GaussianHmm {
        let k = self.k;
        let mut order: Vec<usize> = (0..k).collect();
        order.sort_by(|&a, &b| self.means[a].total_cmp(&self.means[b]));
        let normalise = |v: Vec<f64>| {
            let s: f64 = v.iter().sum();
            v.into_iter().map(|x| x / s).collect::<Vec<f64>>()
        };
        GaussianHmm {
            initial: normalise(order.iter().map(|&i| self.initial[i]).collect()),
            transitions: order
                .iter()
                .map(|&i| normalise(order.iter().map(|&j| self.trans[i * k + j]).collect()))
                .collect(),
            means: order.iter().map(|&i| self.means[i]).collect(),
            variances: order.iter().map(|&i| self.variances[i]).collect(),
        }
    }
}

/// Outcome of one EM run.
pub(super) struct Run {
    pub(super) log_likelihood: f64,
    pub(super) trace: Vec<f64>,
    pub(super) iterations: usize,
    pub(super) converged: bool,
}

/// Buffers of the forward–backward pass, reused across iterations and restarts.
pub(super) struct Workspace {
    n: usize,
    k: usize,
    /// Scaled emissions b'ₜ(j) ∈ [1e-150, 1], state-major (k × n) so that the emission
    /// pass runs over contiguous memory and vectorises.
    emis: Vec<f64>,
    /// ln of the largest emission density at each t.
    offset: Vec<f64>,
    /// Forward variables, n × k, rescaled only when their sum falls below [`RESCALE_BELOW`].
    alpha: Vec<f64>,
    /// 1 / (rescaling factor) applied at each t (1 where none was applied).
    inv_scale: Vec<f64>,
    /// Per-state constants of the log density: −½ ln(2πσ²) and 1/σ.
    log_norm: Vec<f64>,
    inv_sd: Vec<f64>,
    /// Accumulators of the E-step.
    gamma_sum: Vec<f64>,
    gamma_y: Vec<f64>,
    gamma_yy: Vec<f64>,
    gamma_first: Vec<f64>,
    xi_sum: Vec<f64>,
}

/// The forward variables are rescaled when their sum falls below this; with emissions floored
/// at 1e-150 one step cannot take them below 1e-250, far from underflow.
const RESCALE_BELOW: f64 = 1e-100;

impl Workspace {
    pub(super) fn new(n: usize, k: usize) -> Self {
        Self {
            n,
            k,
            emis: vec![0.0; n * k],
            offset: vec![0.0; n],
            alpha: vec![0.0; n * k],
            inv_scale: vec![0.0; n],
            log_norm: vec![0.0; k],
            inv_sd: vec![0.0; k],
            gamma_sum: vec![0.0; k],
            gamma_y: vec![0.0; k],
            gamma_yy: vec![0.0; k],
            gamma_first: vec![0.0; k],
            xi_sum: vec![0.0; k * k],
        }
    }

    /// All T × N scaled emissions b'ₜ(j) = exp(ln Γⱼ(yₜ) − offsetₜ), floored, into `emis`, and
    /// the offsets offsetₜ = maxⱼ ln Γⱼ(yₜ). Three branch-free passes over contiguous memory
    /// rather than one per step: the compiler vectorises them.
    fn emissions(&mut self, y: &[f64], p: &Params) {
        let n = self.n;
        for j in 0..self.k {
            self.log_norm[j] = -0.5 * (LN_2PI + p.variances[j].ln());
            self.inv_sd[j] = 1.0 / p.variances[j].sqrt();
        }
        for (j, row) in self.emis.chunks_exact_mut(n).enumerate() {
            let (mu, isd, ln) = (p.means[j], self.inv_sd[j], self.log_norm[j]);
            for (e, &yt) in row.iter_mut().zip(y) {
                let d = (yt - mu) * isd;
                *e = ln - 0.5 * (d * d).min(MAX_SQUARED_DISTANCE);
            }
        }
        let (first, rest) = self.emis.split_at(n);
        self.offset.copy_from_slice(first);
        for row in rest.chunks_exact(n) {
            for (m, &e) in self.offset.iter_mut().zip(row) {
                if e > *m {
                    *m = e;
                }
            }
        }
        for row in self.emis.chunks_exact_mut(n) {
            for (e, &m) in row.iter_mut().zip(&self.offset) {
                // Clamped at the floor: below it the value hardly matters and the clamp keeps
                // the exponent in range. The best state gets exp(0) = 1 exactly.
                let d = *e - m;
                *e = exp_nonpositive(if d > LN_EMISSION_FLOOR {
                    d
                } else {
                    LN_EMISSION_FLOOR
                });
            }
        }
    }

    /// Scaled emissions and forward pass; returns the log-likelihood, or None if it is not
    /// finite.
    pub(super) fn forward(&mut self, y: &[f64], p: &Params) -> Option<f64> {
        self.emissions(y, p);
        // Constant state counts let the compiler unroll the inner loops and keep the forward
        // variables in registers.
        let log_scale = match self.k {
            1 => self.forward_k::<1>(p),
            2 => self.forward_k::<2>(p),
            3 => self.forward_k::<3>(p),
            4 => self.forward_k::<4>(p),
            5 => self.forward_k::<5>(p),
            6 => self.forward_k::<6>(p),
            _ => self.forward_dyn(p),
        }?;
        // Log-likelihood = Σ offsetₜ − Σ ln(inv_scaleₜ) + ln Σ α_T.
        let n = self.n;
        let last_sum: f64 = self.alpha[(n - 1) * self.k..].iter().sum();
        let ll = log_scale + last_sum.ln() + self.offset.iter().sum::<f64>();
        ll.is_finite().then_some(ll)
    }

    /// Forward recursion for K states; returns Σ ln(rescaling factors), None on failure.
    fn forward_k<const K: usize>(&mut self, p: &Params) -> Option<f64> {
        let n = self.n;
        let mut trans = [[0.0; K]; K];
        for (i, row) in trans.iter_mut().enumerate() {
            row.copy_from_slice(&p.trans[i * K..(i + 1) * K]);
        }
        let e: [&[f64]; K] = std::array::from_fn(|j| &self.emis[j * n..(j + 1) * n]);
        let mut log_scale = 0.0;
        let mut prev = [0.0f64; K];
        for j in 0..K {
            prev[j] = p.initial[j] * e[j][0];
        }
        let (first, rest) = self.alpha.split_at_mut(K);
        log_scale += Self::rescale(&mut prev, &mut self.inv_scale[0])?;
        first.copy_from_slice(&prev);
        for (t, (cur_out, inv)) in rest
            .chunks_exact_mut(K)
            .zip(&mut self.inv_scale[1..])
            .enumerate()
        {
            let t = t + 1;
            // Aᵢⱼ bₜ(j) does not depend on the previous step: folding the emission into the
            // matrix takes a multiplication off the chain that links consecutive steps.
            let mut cur = [0.0f64; K];
            for j in 0..K {
                let b = e[j][t];
                let mut s = prev[0] * (trans[0][j] * b);
                for i in 1..K {
                    s += prev[i] * (trans[i][j] * b);
                }
                cur[j] = s;
            }
            log_scale += Self::rescale(&mut cur, inv)?;
            cur_out.copy_from_slice(&cur);
            prev = cur;
        }
        Some(log_scale)
    }

    /// Rescales `a` to sum 1 when its sum is below [`RESCALE_BELOW`] (or not finite), records
    /// the inverse factor in `inv` and returns ln(factor); None if the sum is not positive and
    /// finite.
    #[inline(always)]
    fn rescale(a: &mut [f64], inv: &mut f64) -> Option<f64> {
        let s: f64 = a.iter().sum();
        if s < RESCALE_BELOW || !s.is_finite() {
            if !(s > 0.0 && s.is_finite()) {
                return None;
            }
            let r = 1.0 / s;
            for x in a.iter_mut() {
                *x *= r;
            }
            *inv = r;
            Some(s.ln())
        } else {
            *inv = 1.0;
            Some(0.0)
        }
    }

    /// Backward pass with the E-step statistics; requires `forward` on the same parameters.
    /// Returns false on a numerical failure.
    fn backward(&mut self, y: &[f64], p: &Params) -> bool {
        match self.k {
            1 => self.backward_k::<1>(y, p),
            2 => self.backward_k::<2>(y, p),
            3 => self.backward_k::<3>(y, p),
            4 => self.backward_k::<4>(y, p),
            5 => self.backward_k::<5>(y, p),
            6 => self.backward_k::<6>(y, p),
            _ => self.backward_dyn(y, p),
        }
    }

    /// Backward pass for K states. One sweep gives β, the γ sums and the ξ sums for the
    /// transition update.
    fn backward_k<const K: usize>(&mut self, y: &[f64], p: &Params) -> bool {
        let mut trans = [[0.0; K]; K];
        for (i, row) in trans.iter_mut().enumerate() {
            row.copy_from_slice(&p.trans[i * K..(i + 1) * K]);
        }
        let n = self.n;
        let e: [&[f64]; K] = std::array::from_fn(|j| &self.emis[j * n..(j + 1) * n]);
        // Σᵢ αₜ(i) βₜ(i) is the same for every t (the forward and backward variables share
        // their scaling factors), so γ is normalised once, by its value at the last step.
        let total: f64 = self.alpha[(n - 1) * K..n * K].iter().sum();
        if !(total > 0.0 && total.is_finite()) {
            return false;
        }
        let mut beta = [1.0f64; K];
        let mut g_sum = [0.0f64; K];
        let mut g_y = [0.0f64; K];
        let mut g_yy = [0.0f64; K];
        let mut outer = [[0.0f64; K]; K];
        for t in (1..n).rev() {
            let alpha = &self.alpha[t * K..(t + 1) * K];
            let yt = y[t];
            for i in 0..K {
                let g = alpha[i] * beta[i];
                g_sum[i] += g;
                g_y[i] += g * yt;
                g_yy[i] += g * yt * yt;
            }
            // ξ_{t−1}(i, j) ∝ α_{t−1}(i) A_ij wₜ(j) with wₜ = b'ₜ βₜ × inv_scaleₜ; A_ij is
            // factored out of the sum over t. β_{t−1} = A wₜ, computed as Σⱼ (A_ij b'ₜ(j)
            // inv_scaleₜ) βₜ(j): the products are off the chain linking consecutive steps.
            let inv = self.inv_scale[t];
            let mut bi = [0.0f64; K];
            let mut w = [0.0f64; K];
            for j in 0..K {
                bi[j] = e[j][t] * inv;
                w[j] = bi[j] * beta[j];
            }
            let a_prev = &self.alpha[(t - 1) * K..t * K];
            let mut next = [0.0f64; K];
            for i in 0..K {
                let mut s = (trans[i][0] * bi[0]) * beta[0];
                for j in 1..K {
                    s += (trans[i][j] * bi[j]) * beta[j];
                }
                for j in 0..K {
                    outer[i][j] += a_prev[i] * w[j];
                }
                next[i] = s;
            }
            beta = next;
        }
        let yt = y[0];
        for i in 0..K {
            let g = self.alpha[i] * beta[i];
            g_sum[i] += g;
            g_y[i] += g * yt;
            g_yy[i] += g * yt * yt;
            self.gamma_first[i] = g;
        }
        let r = 1.0 / total;
        for i in 0..K {
            self.gamma_sum[i] = g_sum[i] * r;
            self.gamma_y[i] = g_y[i] * r;
            self.gamma_yy[i] = g_yy[i] * r;
            self.gamma_first[i] *= r;
            for j in 0..K {
                self.xi_sum[i * K + j] = trans[i][j] * outer[i][j] * r;
            }
        }
        self.statistics_finite()
    }

    fn statistics_finite(&self) -> bool {
        [
            &self.gamma_sum,
            &self.gamma_y,
            &self.gamma_yy,
            &self.gamma_first,
            &self.xi_sum,
        ]
        .iter()
        .all(|v| v.iter().all(|x| x.is_finite()))
    }

    /// M-step: new parameters from the E-step statistics. States with no weight keep theirs.
    fn m_step(&self, p: &mut Params, floor: f64) {
        let k = self.k;
        let g_total: f64 = self.gamma_first.iter().sum();
        for i in 0..k {
            p.initial[i] = self.gamma_first[i] / g_total;
        }
        for i in 0..k {
            let row = &self.xi_sum[i * k..(i + 1) * k];
            let s: f64 = row.iter().sum();
            if s > 0.0 && s.is_finite() {
                for (t, x) in p.trans[i * k..(i + 1) * k].iter_mut().zip(row) {
                    *t = x / s;
                }
            }
            let w = self.gamma_sum[i];
            if w > 1e-300 {
                let mean = self.gamma_y[i] / w;
                // E[y²] − mean² loses precision when the mean is large against the spread;
                // the floor bounds the damage and keeps the variance positive.
                let var = self.gamma_yy[i] / w - mean * mean;
                p.means[i] = mean;
                p.variances[i] = if var.is_finite() {
                    var.max(floor)
                } else {
                    floor
                };
            }
        }
    }
}

/// One EM run from `init`; None if it fails numerically.
pub(super) fn em(
    y: &[f64],
    mut p: Params,
    floor: f64,
    settings: &HmmSettings,
    ws: &mut Workspace,
) -> Option<(Params, Run)> {
    let n = y.len() as f64;
    let mut ll = ws.forward(y, &p)?;
    let mut trace = vec![ll];
    let mut iterations = 0;
    let mut converged = false;
    let mut slow = 0;
    // Two parameter sets swapped each iteration: no allocation inside the loop.
    let mut next = p.clone();
    while iterations < settings.max_iterations {
        if !ws.backward(y, &p) {
            return None;
        }
        // The M-step keeps the old values of states without weight, so it starts from `p`.
        next.clone_from(&p);
        ws.m_step(&mut next, floor);
        let next_ll = ws.forward(y, &next)?;
        iterations += 1;
        trace.push(next_ll);
        let gain = next_ll - ll;
        std::mem::swap(&mut p, &mut next);
        ll = next_ll;
        slow = if gain < settings.tolerance * n {
            slow + 1
        } else {
            0
        };
        if slow >= settings.patience {
            converged = true;
            break;
        }
    }
    Some((
        p,
        Run {
            log_likelihood: ll,
            trace,
            iterations,
            converged,
        },
    ))
}

#[path = "em_general.rs"]
mod general;

#[cfg(test)]
#[path = "em_tests.rs"]
mod tests;
