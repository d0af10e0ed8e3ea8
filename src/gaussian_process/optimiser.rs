//! A box-constrained L-BFGS over the log hyperparameters.

use super::likelihood::Objective;
use super::{LOG_LENGTH, LOG_NOISE_RATIO, LOG_SIGNAL};

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
pub fn minimise(
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
        // The gradient only once the value is accepted: as `eval` would, a non-finite one
        // rejects the step.
        if let Some(mut point) = objective.value(&trial) {
            if point.value <= f + 1e-4 * decrease {
                if let Some(gt) = objective.gradient(&mut point) {
                    return Some((trial, point.value, gt));
                }
            }
        }
        step *= 0.5;
    }
    None
}

pub fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

pub(super) fn axpy(a: f64, x: &[f64], y: &mut [f64]) {
    y.iter_mut().zip(x).for_each(|(y, x)| *y += a * x);
}
