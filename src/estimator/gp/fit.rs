//! Fitting the Gaussian process's hyperparameters: the log marginal likelihood with its analytic
//! gradient, and a box-constrained L-BFGS over the log hyperparameters.

use super::*;

/// Minus the log marginal likelihood per fit sample, summed over the outputs (one kernel shared
/// by all), as a function of θ = (log ℓ_1 … log ℓ_D, log σf, log(σn/σf)) (a ratio, so that every
/// bound is a box).
pub(in crate::estimator) struct Objective {
    m: usize,
    dim: usize,
    /// Outputs per sample.
    outputs: usize,
    /// (z_i,d − z_j,d)² for each pair i < j (j-major), then each d.
    diffs: Vec<f64>,
    /// Scaled outputs of the fit samples (m × outputs).
    y: DMatrix<f64>,
}

impl Objective {
    /// The objective on the samples `subset` of row-major `inputs` (`dim` per sample) and
    /// row-major `outputs` (`outputs.len() / samples` per sample).
    pub(in crate::estimator) fn new(
        inputs: &[f64],
        outputs: &[f64],
        dim: usize,
        subset: &[usize],
    ) -> Self {
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
        }
    }

    /// Value and gradient at θ; `None` where the kernel matrix is not positive definite.
    pub(in crate::estimator) fn eval(&self, theta: &[f64]) -> Option<(f64, Vec<f64>)> {
        let (m, dim, outputs) = (self.m, self.dim, self.outputs as f64);
        let inv_l2: Vec<f64> = theta[..dim].iter().map(|t| (-2.0 * t).exp()).collect();
        let sf2 = (2.0 * theta[dim]).exp();
        let sn2 = (2.0 * (theta[dim] + theta[dim + 1])).exp();
        let mut kernel = DMatrix::zeros(m, m);
        let mut kf = Vec::with_capacity(self.diffs.len() / dim.max(1));
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
        let chol = Cholesky::new(kernel)?;
        let alpha = chol.solve(&self.y);
        let log_det: f64 = 2.0 * (0..m).map(|i| chol.l_dirty()[(i, i)].ln()).sum::<f64>();
        let fit: f64 = self.y.iter().zip(alpha.iter()).map(|(a, b)| a * b).sum();
        // Grouped so that two outputs give the same bits as the two-output formula.
        let lml = -0.5 * fit
            - 0.5 * outputs * log_det
            - 0.5 * outputs * m as f64 * (2.0 * std::f64::consts::PI).ln();
        // W = Σ_o α_o α_oᵀ − (outputs)·K⁻¹; ∂L/∂θ = ½ tr(W ∂K/∂θ).
        let inverse = upper_inverse(chol.l_dirty());
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
        for (((i, j), k), diff) in pairs.zip(&kf).zip(self.diffs.chunks_exact(dim)) {
            let wk = w(i, j) * k;
            off_diagonal += wk;
            for ((g, d), il) in grad.iter_mut().zip(diff).zip(&inv_l2) {
                *g += wk * d * il;
            }
        }
        let trace: f64 = (0..m).map(|i| w(i, i)).sum();
        // σn = σf·ratio, so log σf moves σn too.
        grad[dim + 1] = sn2 * trace;
        grad[dim] = 2.0 * off_diagonal + sf2 * trace + grad[dim + 1];
        let scale = -1.0 / m as f64;
        let value = scale * lml;
        let grad: Vec<f64> = grad.iter().map(|g| scale * g).collect();
        (value.is_finite() && grad.iter().all(|g| g.is_finite())).then_some((value, grad))
    }
}

/// The upper triangle (i ≤ j, column-major, at `i + j·n`) of K⁻¹ = L⁻ᵀL⁻¹ from the lower
/// Cholesky factor (column-major, upper part ignored): n³/3 multiply-adds, four columns at a
/// time so that each loaded value serves four sums (several times faster than solving against
/// the identity).
pub(in crate::estimator) fn upper_inverse(l: &DMatrix<f64>) -> Vec<f64> {
    let n = l.nrows();
    let l = l.as_slice();
    let width = n.div_ceil(4) * 4;
    // Columns of M = L⁻¹ (lower) by forward substitution, padded with zero columns to a
    // multiple of 4. Column j starts as e_j; its rows above j stay exactly 0 throughout.
    let mut m = vec![0.0; n * width];
    for (b, block) in m.chunks_exact_mut(4 * n).enumerate() {
        let j0 = 4 * b;
        for c in 0..4 {
            if j0 + c < n {
                block[c * n + j0 + c] = 1.0;
            }
        }
        let (x0, rest) = block.split_at_mut(n);
        let (x1, rest) = rest.split_at_mut(n);
        let (x2, x3) = rest.split_at_mut(n);
        for k in j0..n {
            let d = l[k + k * n];
            let a = [x0[k] / d, x1[k] / d, x2[k] / d, x3[k] / d];
            [x0[k], x1[k], x2[k], x3[k]] = a;
            let column = &l[k * n + k + 1..(k + 1) * n];
            let rows = x0[k + 1..]
                .iter_mut()
                .zip(x1[k + 1..].iter_mut())
                .zip(x2[k + 1..].iter_mut().zip(x3[k + 1..].iter_mut()));
            for (((y0, y1), (y2, y3)), lik) in rows.zip(column) {
                *y0 -= a[0] * lik;
                *y1 -= a[1] * lik;
                *y2 -= a[2] * lik;
                *y3 -= a[3] * lik;
            }
        }
    }
    // (K⁻¹)_ij = Σ_k M_ki M_kj, over k ≥ j0 for the block of j0 (the rest is exactly 0).
    let mut inverse = vec![0.0; n * n];
    for j0 in (0..n).step_by(4) {
        let columns: [&[f64]; 4] = std::array::from_fn(|c| &m[(j0 + c) * n + j0..(j0 + c + 1) * n]);
        for i in 0..(j0 + 4).min(n) {
            let mut sums = [0.0; 4];
            for (k, v) in m[i * n + j0..(i + 1) * n].iter().enumerate() {
                for c in 0..4 {
                    sums[c] += v * columns[c][k];
                }
            }
            for (c, sum) in sums.into_iter().enumerate() {
                if i <= j0 + c && j0 + c < n {
                    inverse[i + (j0 + c) * n] = sum;
                }
            }
        }
    }
    inverse
}

/// The box of θ: each log ℓ, log σf, and log(σn/σf).
pub(super) fn bounds(dim: usize) -> (Vec<f64>, Vec<f64>) {
    let mut lower = vec![LOG_LENGTH.0; dim];
    let mut upper = vec![LOG_LENGTH.1; dim];
    lower.extend([LOG_SIGNAL.0, LOG_NOISE_RATIO.0]);
    upper.extend([LOG_SIGNAL.1, LOG_NOISE_RATIO.1]);
    (lower, upper)
}

/// Clamps θ into its box.
pub(super) fn project(theta: &mut [f64], lower: &[f64], upper: &[f64]) {
    for ((t, lo), hi) in theta.iter_mut().zip(lower).zip(upper) {
        *t = t.clamp(*lo, *hi);
    }
}

/// Box-constrained L-BFGS (memory 8): coordinates at a bound that the gradient pushes outwards
/// are held, the quasi-Newton direction is taken on the others (the memory restarts when that
/// set changes), and a backtracking Armijo search runs along the projected path. Deterministic.
/// Returns the final point and value, or `None` when the start is infeasible.
pub(in crate::estimator) fn minimise(
    objective: &Objective,
    start: Vec<f64>,
    iterations: usize,
) -> Option<(Vec<f64>, f64)> {
    const MEMORY: usize = 8;
    let (lower, upper) = bounds(start.len() - 2);
    let mut x = start;
    project(&mut x, &lower, &upper);
    let (mut f, mut g) = objective.eval(&x)?;
    let mut history: Vec<(Vec<f64>, Vec<f64>, f64)> = Vec::new();
    let mut held: Vec<bool> = Vec::new();
    let mut stalled = 0;
    for _ in 0..iterations {
        let now_held: Vec<bool> = (0..x.len())
            .map(|k| (x[k] <= lower[k] && g[k] > 0.0) || (x[k] >= upper[k] && g[k] < 0.0))
            .collect();
        if now_held != held {
            history.clear();
            held = now_held;
        }
        let unheld = |v: &[f64]| -> Vec<f64> {
            v.iter()
                .zip(&held)
                .map(|(v, &h)| if h { 0.0 } else { *v })
                .collect()
        };
        let free = unheld(&g);
        if free.iter().all(|v| v.abs() < 1e-7) {
            break;
        }
        let mut direction = unheld(&lbfgs_direction(&history, &free));
        let steepest: Vec<f64> = free.iter().map(|v| -v).collect();
        if dot(&direction, &free) >= 0.0 {
            history.clear();
            direction = steepest.clone();
        }
        let mut accepted = line_search(objective, &x, f, &g, &direction, &lower, &upper);
        if accepted.is_none() && !history.is_empty() {
            history.clear();
            accepted = line_search(objective, &x, f, &g, &steepest, &lower, &upper);
        }
        let Some((trial, ft, gt)) = accepted else {
            break;
        };
        let s: Vec<f64> = trial.iter().zip(&x).map(|(a, b)| a - b).collect();
        let y: Vec<f64> = gt.iter().zip(&g).map(|(a, b)| a - b).collect();
        let sy = dot(&s, &y);
        if sy > 1e-12 * dot(&y, &y).sqrt() * dot(&s, &s).sqrt() {
            history.push((s, y, 1.0 / sy));
            if history.len() > MEMORY {
                history.remove(0);
            }
        }
        let improvement = f - ft;
        (x, f, g) = (trial, ft, gt);
        // A single short step is no proof of convergence: wait for three in a row.
        if improvement <= 1e-9 * f.abs().max(1.0) {
            stalled += 1;
            if stalled == 3 {
                break;
            }
        } else {
            stalled = 0;
        }
    }
    Some((x, f))
}

/// The two-loop recursion: an approximation of −H⁻¹g from the stored steps; the first step
/// moves at most 1 along any coordinate.
pub(super) fn lbfgs_direction(history: &[(Vec<f64>, Vec<f64>, f64)], g: &[f64]) -> Vec<f64> {
    let mut q = g.to_vec();
    let mut coefficients = Vec::with_capacity(history.len());
    for (s, y, rho) in history.iter().rev() {
        let a = rho * dot(s, &q);
        axpy(-a, y, &mut q);
        coefficients.push(a);
    }
    let gamma = match history.last() {
        Some((s, y, _)) => dot(s, y) / dot(y, y),
        None => 1.0 / g.iter().fold(1.0f64, |a, v| a.max(v.abs())),
    };
    q.iter_mut().for_each(|v| *v *= gamma);
    for ((s, y, rho), a) in history.iter().zip(coefficients.iter().rev()) {
        let b = rho * dot(y, &q);
        axpy(a - b, s, &mut q);
    }
    q.iter().map(|v| -v).collect()
}

/// Backtracking along the projected path from x: the first step (1, ½, ¼ …) with a sufficient
/// decrease, as (point, value, gradient).
pub(super) fn line_search(
    objective: &Objective,
    x: &[f64],
    f: f64,
    g: &[f64],
    direction: &[f64],
    lower: &[f64],
    upper: &[f64],
) -> Option<(Vec<f64>, f64, Vec<f64>)> {
    let mut step = 1.0;
    for _ in 0..40 {
        let mut trial: Vec<f64> = x.iter().zip(direction).map(|(a, d)| a + step * d).collect();
        project(&mut trial, lower, upper);
        let moved: Vec<f64> = trial.iter().zip(x).map(|(a, b)| a - b).collect();
        let decrease = dot(g, &moved);
        if decrease >= 0.0 {
            return None; // the projection left no descent along this direction
        }
        if let Some((ft, gt)) = objective.eval(&trial) {
            if ft <= f + 1e-4 * decrease {
                return Some((trial, ft, gt));
            }
        }
        step *= 0.5;
    }
    None
}

pub(super) fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

pub(super) fn axpy(a: f64, x: &[f64], y: &mut [f64]) {
    y.iter_mut().zip(x).for_each(|(y, x)| *y += a * x);
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A small fit problem: a smooth function of 2 features on an 8 × 8 grid, plus noise of
    /// standard deviation about 0.1 (a fixed pseudo-random sequence), so the optimum is interior.
    fn objective() -> Objective {
        let n = 64;
        let inputs: Vec<f64> = (0..n)
            .flat_map(|i| [(i % 8) as f64 / 4.0 - 1.0, (i / 8) as f64 / 4.0 - 1.0])
            .collect();
        let mut state: u64 = 12345;
        let mut noise = move || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((state >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 0.35
        };
        let outputs: Vec<f64> = inputs
            .chunks(2)
            .flat_map(|x| {
                [
                    x[0] * x[1] + 0.5 * x[0] + noise(),
                    (x[0] - x[1]).sin() + noise(),
                ]
            })
            .collect();
        Objective::new(&inputs, &outputs, 2, &(0..n).collect::<Vec<_>>())
    }

    #[test]
    fn analytic_gradient_matches_finite_differences() {
        let objective = objective();
        let theta = [0.3, -0.2, 0.1, -1.5];
        let (_, grad) = objective.eval(&theta).unwrap();
        for k in 0..theta.len() {
            let h = 1e-6;
            let (mut up, mut down) = (theta, theta);
            up[k] += h;
            down[k] -= h;
            let numeric =
                (objective.eval(&up).unwrap().0 - objective.eval(&down).unwrap().0) / (2.0 * h);
            assert!(
                (numeric - grad[k]).abs() < 1e-6 * (1.0 + numeric.abs()),
                "θ[{k}]: analytic {} vs numeric {numeric}",
                grad[k]
            );
        }
    }

    #[test]
    fn the_optimiser_improves_the_likelihood_and_respects_the_bounds() {
        let objective = objective();
        let start = vec![0.0, 0.0, 0.0, (0.1f64).ln()];
        let (f0, _) = objective.eval(&start).unwrap();
        let (theta, f) = minimise(&objective, start, 200).unwrap();
        assert!(f < f0 - 0.01, "{f} vs {f0}");
        let (lower, upper) = bounds(2);
        let mut projected = theta.clone();
        project(&mut projected, &lower, &upper);
        assert_eq!(projected, theta);
        assert!(
            theta[3] > lower[3] + 1.0,
            "the noise found no interior optimum: {theta:?}"
        );
        // At an interior optimum the gradient vanishes on the free coordinates.
        let (_, grad) = objective.eval(&theta).unwrap();
        for (k, g) in grad.iter().enumerate() {
            if theta[k] > lower[k] + 1e-3 && theta[k] < upper[k] - 1e-3 {
                assert!(g.abs() < 1e-4, "gradient {g} on θ[{k}] at {theta:?}");
            }
        }
    }

    #[test]
    fn the_blocked_inverse_matches_solving_against_the_identity() {
        for n in [1, 2, 3, 4, 5, 7, 8, 33] {
            let k = DMatrix::from_fn(n, n, |i, j| {
                (-((i as f64 - j as f64) / 3.0).powi(2)).exp() + if i == j { 0.1 } else { 0.0 }
            });
            let chol = Cholesky::new(k).unwrap();
            let reference = chol.inverse();
            let upper = upper_inverse(chol.l_dirty());
            for j in 0..n {
                for i in 0..=j {
                    let diff = (reference[(i, j)] - upper[i + j * n]).abs();
                    assert!(diff < 1e-10, "n {n}, ({i}, {j}): off by {diff}");
                }
            }
        }
    }
}
