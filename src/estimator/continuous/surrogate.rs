//! The feature maps learned as smooth functions of the pose: one Gaussian process per feature
//! (squared-exponential kernel with a length scale per pose axis, σf and σn, in standardised
//! units), hyperparameters by that feature's log marginal likelihood. Each feature has its own
//! noise and smoothness: the barycentre is a hundred times less noisy, relative to its range,
//! than a size function, and a shared kernel over-smooths it.

mod block;
mod grid;
pub(super) mod share;

use std::sync::{Arc, OnceLock};

use nalgebra::DMatrix;
use serde::{Deserialize, Serialize};

use super::grid_share;
use crate::estimator::MAX_EXACT_GP_SAMPLES;

use crate::gaussian_process::{cholesky, minimise, upper_inverse, Objective};
use crate::standardisation::Standardisation;

/// Jitter tried, relative to σf², when the factorisation fails.
const JITTERS: [f64; 7] = [1e-10, 1e-9, 1e-8, 1e-7, 1e-6, 1e-5, 1e-4];

/// One feature's fitted kernel hyperparameters, in standardised units (pose coordinates and
/// the feature scaled to unit standard deviation on the samples).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SurrogateHyperparameters {
    /// Length scale of x and of y.
    pub length_scales: [f64; 2],
    /// Signal standard deviation σf.
    pub signal_std: f64,
    /// Noise standard deviation σn.
    pub noise_std: f64,
    /// The log marginal likelihood reached on the fit samples.
    pub log_marginal_likelihood: f64,
}

/// One feature's map, ready to evaluate.
#[derive(Debug, Clone)]
struct FeatureKernel {
    /// Standardised sample poses divided by the length scales.
    inputs: Vec<[f64; 2]>,
    /// K⁻¹y per sample (standardised units).
    alpha: Vec<f64>,
    signal_var: f64,
    /// 1 / length scale per axis.
    inverse_length: [f64; 2],
    /// Diagonal of K⁻¹ (for leave-one-out residuals), when asked for: n³/3 more work.
    inverse_diagonal: Option<Vec<f64>>,
}

/// The learned feature maps f_i(q), ready to evaluate: each Gaussian process tabulated on a
/// regular grid over the sample poses' bounding box (value, both slopes and the mixed
/// derivative at every node, exact), and evaluated between nodes by bicubic Hermite
/// interpolation, which reproduces the process to O(h⁴): far below the features' noise for the
/// default 0.25 mm against length scales of millimetres, at a few hundred flops per pose
/// instead of one exponential per sample and feature.
#[derive(Debug, Clone)]
pub(super) struct Surrogate {
    // Read only by the tests' comparison with the process itself.
    #[cfg_attr(not(test), allow(dead_code))]
    pose: Standardisation,
    features: Standardisation,
    /// Shared with every live fit of the same feature map ([`share::kernel`]).
    kernels: Vec<Arc<FeatureKernel>>,
    grid: Grid,
}

/// The tabulated maps: node (c, r) at origin + (c·step_x, r·step_y).
#[derive(Debug, Clone)]
struct Grid {
    origin: [f64; 2],
    step: [f64; 2],
    nodes: [usize; 2],
    /// Per node, per feature: f, ∂f/∂x, ∂f/∂y, ∂²f/∂x∂y (raw units, mm), node-major; shared
    /// by every live fit that tabulates the same maps ([`grid_share`]).
    table: Arc<Vec<[f64; 4]>>,
    /// The table regrouped for `Continuous::feature_maps_block` with AVX, made on its first
    /// use (block.rs, `Grid::lanes`): per node and group of four features, each node value of
    /// the four side by side.
    lanes: Arc<OnceLock<Vec<[[f64; 4]; 4]>>>,
}

/// A grid's origin, step (mm), nodes per axis and table.
pub(super) type GridView<'a> = ([f64; 2], [f64; 2], [usize; 2], &'a [[f64; 4]]);

/// Most grid nodes along one axis.
pub(super) const MAX_GRID_NODES: usize = 1000;

/// Nodes per axis of a grid of about `spacing` mm over a box of `extent` mm (what the memory
/// estimate counts too).
pub(crate) fn grid_nodes(extent: [f64; 2], spacing: f64) -> [usize; 2] {
    extent.map(|e| match e > 0.0 {
        true => ((e / spacing).ceil() as usize + 1).clamp(2, MAX_GRID_NODES),
        false => 2,
    })
}

/// Fits each feature's hyperparameters on at most `max_fit` evenly spaced samples: L-BFGS from
/// two starts (length scale 1 and ¼ in standardised units), the better one wins; the features
/// in parallel on two threads. `None` for a feature whose every start has a singular kernel.
/// A feature fitted alike by a live fit is taken from it ([`share::hyperparameters`]); the
/// caller keeps the results to share them on.
pub(super) fn fit_hyperparameters(
    pose: &Standardisation,
    features: &Standardisation,
    poses: &[[f64; 2]],
    rows: &[Vec<f64>],
    max_fit: usize,
    iterations: usize,
) -> Vec<Arc<share::Fitted>> {
    let inputs = pose.apply_rows(&poses.iter().map(|p| p.to_vec()).collect::<Vec<_>>());
    let outputs = features.apply_rows(rows);
    let dim = features.means.len();
    let (n, m) = (poses.len(), poses.len().min(max_fit));
    let subset: Vec<usize> = (0..m).map(|i| i * n / m).collect();
    let fit_one = |i: usize, wait: bool| {
        let column: Vec<f64> = outputs.iter().skip(i).step_by(dim).copied().collect();
        share::hyperparameters(&inputs, &column, m, iterations, wait, || {
            let objective = Objective::new(&inputs, &column, 2, &subset);
            let mut best: Option<(Vec<f64>, f64)> = None;
            for length in [1.0f64, 0.25] {
                let start = vec![length.ln(), length.ln(), 0.0, (1e-2f64).ln()];
                if let Some(found) = minimise(&objective, start, iterations) {
                    if best.as_ref().is_none_or(|b| found.1 < b.1) {
                        best = Some(found);
                    }
                }
            }
            best.map(|(theta, value)| SurrogateHyperparameters {
                length_scales: [theta[0].exp(), theta[1].exp()],
                signal_std: theta[2].exp(),
                noise_std: (theta[2] + theta[3]).exp(),
                log_marginal_likelihood: -value * m as f64,
            })
        })
    };
    on_two_threads_busy_last(dim, fit_one)
}

impl Surrogate {
    /// Factors each feature's kernel matrix on every sample and tabulates the maps on a grid of
    /// about `spacing` mm (the same operations whether fitted or loaded); with `leave_one_out`,
    /// also what [`Surrogate::leave_one_out`] needs.
    pub(super) fn new(
        pose: Standardisation,
        features: Standardisation,
        hyper: &[SurrogateHyperparameters],
        poses: &[[f64; 2]],
        rows: &[Vec<f64>],
        spacing: f64,
        leave_one_out: bool,
    ) -> Result<Self, String> {
        if poses.len() > MAX_EXACT_GP_SAMPLES {
            return Err(format!(
                "{} samples are more than the {MAX_EXACT_GP_SAMPLES} an exact Gaussian process \
                 factors (n³/3 work per feature); fit on fewer samples",
                poses.len()
            ));
        }
        let dim = features.means.len();
        let standardised: Vec<[f64; 2]> = poses
            .iter()
            .map(|p| [pose.apply(0, p[0]), pose.apply(1, p[1])])
            .collect();
        let outputs = features.apply_rows(rows);
        // Factored on two threads (each kernel alone); the first failure in feature order is
        // the error, as when they were factored one after the other.
        let kernels = on_two_threads_busy_last(hyper.len(), |i, wait| {
            let column: Vec<f64> = outputs.iter().skip(i).step_by(dim).copied().collect();
            let h = &hyper[i];
            let built = share::kernel(h, &standardised, &column, leave_one_out, wait, || {
                FeatureKernel::new(h, &standardised, &column, leave_one_out)
            })?;
            Some(built.map_err(|e| format!("feature {i}: {e}")))
        });
        let kernels = kernels.into_iter().collect::<Result<Vec<_>, _>>()?;
        let grid = Grid::tabulate(&pose, &features, &kernels, poses, spacing);
        Ok(Self {
            pose,
            features,
            kernels,
            grid,
        })
    }

    /// Number of features.
    pub(super) fn dim(&self) -> usize {
        self.kernels.len()
    }

    /// Every feature's value at pose `q` (mm, inside the grid; outside it, at the nearest point
    /// of the grid's box) into `values`, and with `jacobian` its gradient (∂f_i/∂x, ∂f_i/∂y), in
    /// raw feature units.
    pub(super) fn eval(&self, q: [f64; 2], values: &mut [f64], jacobian: Option<&mut [[f64; 2]]>) {
        self.grid.eval(q, self.kernels.len(), values, jacobian);
    }

    /// The grid's origin, step (mm), nodes per axis and table (node-major; per feature f,
    /// ∂f/∂x, ∂f/∂y, ∂²f/∂x∂y): what the group levels scan (`super::grid_levels`).
    pub(super) fn grid(&self) -> GridView<'_> {
        let g = &self.grid;
        (g.origin, g.step, g.nodes, &g.table)
    }

    /// Feature `i`'s value and gradient at `q` from the Gaussian process itself (what the grid
    /// interpolates).
    #[cfg(test)]
    fn exact(&self, i: usize, q: [f64; 2]) -> (f64, [f64; 2]) {
        let z = [self.pose.apply(0, q[0]), self.pose.apply(1, q[1])];
        let [v, gx, gy, _] = self.kernels[i].value_gradient_cross(z);
        let s = self.features.scales[i];
        (
            self.features.means[i] + s * v,
            [s * gx / self.pose.scales[0], s * gy / self.pose.scales[1]],
        )
    }

    /// Each feature's RMS leave-one-out residual (raw units): how far each sample's value lies
    /// from the process fitted without that sample, α_j / (K⁻¹)_jj. `None` unless built with
    /// `leave_one_out`.
    pub(super) fn leave_one_out_rms(&self) -> Option<Vec<f64>> {
        (self.kernels.iter().enumerate())
            .map(|(i, k)| {
                let inverse = k.inverse_diagonal.as_ref()?;
                let n = inverse.len().max(1) as f64;
                let sum: f64 = (k.alpha.iter().zip(inverse))
                    .map(|(a, d)| (a / d) * (a / d))
                    .sum();
                Some(self.features.scales[i] * (sum / n).sqrt())
            })
            .collect()
    }
}

impl FeatureKernel {
    fn new(
        h: &SurrogateHyperparameters,
        standardised: &[[f64; 2]],
        y: &[f64],
        leave_one_out: bool,
    ) -> Result<Self, String> {
        let inverse_length = [1.0 / h.length_scales[0], 1.0 / h.length_scales[1]];
        let inputs: Vec<[f64; 2]> = standardised
            .iter()
            .map(|p| [p[0] * inverse_length[0], p[1] * inverse_length[1]])
            .collect();
        let n = inputs.len();
        let signal_var = h.signal_std * h.signal_std;
        let mut kernel = DMatrix::zeros(n, n);
        for j in 0..n {
            for i in 0..j {
                let k = signal_var * (-0.5 * squared(inputs[i], inputs[j])).exp();
                kernel[(i, j)] = k;
                kernel[(j, i)] = k;
            }
        }
        let y = DMatrix::from_column_slice(n, 1, y);
        let base = h.noise_std * h.noise_std;
        for noise_var in std::iter::once(base).chain(JITTERS.iter().map(|j| base + j * signal_var))
        {
            let mut k = kernel.clone();
            for i in 0..n {
                k[(i, i)] = signal_var + noise_var;
            }
            let Some(chol) = cholesky(k) else {
                continue;
            };
            let alpha = chol.solve(&y).iter().copied().collect();
            let inverse_diagonal = leave_one_out.then(|| {
                let inverse = upper_inverse(chol.l_dirty());
                (0..n).map(|i| inverse[i + i * n]).collect()
            });
            return Ok(Self {
                inputs,
                alpha,
                signal_var,
                inverse_length,
                inverse_diagonal,
            });
        }
        Err("the kernel matrix is not positive definite, even with jitter".into())
    }

    /// The standardised value, its gradient and its mixed second derivative ∂²/∂z_x∂z_y, in
    /// standardised pose units.
    fn value_gradient_cross(&self, z: [f64; 2]) -> [f64; 4] {
        let u = [z[0] * self.inverse_length[0], z[1] * self.inverse_length[1]];
        let (mut v, mut gx, mut gy, mut gxy) = (0.0, 0.0, 0.0, 0.0);
        for (x, a) in self.inputs.iter().zip(&self.alpha) {
            let k = a * (-0.5 * squared(u, *x)).exp();
            let (dx, dy) = (u[0] - x[0], u[1] - x[1]);
            v += k;
            gx -= k * dx;
            gy -= k * dy;
            gxy += k * dx * dy;
        }
        let s = self.signal_var;
        let [lx, ly] = self.inverse_length;
        [s * v, s * gx * lx, s * gy * ly, s * gxy * lx * ly]
    }
}

/// `f(i, wait)` for i in 0..count on two threads, each taking every other index, where `f`
/// gives `None` without `wait` when another fit is computing the same shared value: those
/// indices wait until the thread's others are done (so two fits that share values split them
/// instead of one waiting for the other). A panic in `f` is resumed here.
fn on_two_threads_busy_last<T: Send>(
    count: usize,
    f: impl Fn(usize, bool) -> Option<T> + Sync,
) -> Vec<T> {
    let mut slots: Vec<Option<T>> = (0..count).map(|_| None).collect();
    std::thread::scope(|scope| {
        let f = &f;
        let handles: Vec<_> = (0..2)
            .map(|t| {
                scope.spawn(move || {
                    let mut done = Vec::new();
                    let mut later = Vec::new();
                    for i in (t..count).step_by(2) {
                        match f(i, false) {
                            Some(value) => done.push((i, value)),
                            None => later.push(i),
                        }
                    }
                    // With `wait`, `f` always gives a value.
                    done.extend(later.into_iter().filter_map(|i| Some((i, f(i, true)?))));
                    done
                })
            })
            .collect();
        for handle in handles {
            let done = handle
                .join()
                .unwrap_or_else(|panic| std::panic::resume_unwind(panic));
            for (i, value) in done {
                slots[i] = Some(value);
            }
        }
    });
    slots.into_iter().flatten().collect()
}

/// Fills each `row_len` row of `table` with `fill(row, slice)`, rows alternating between two
/// threads: every value is computed as on one. A panic in `fill` is resumed here.
fn rows_on_two_threads(
    table: &mut [[f64; 4]],
    row_len: usize,
    fill: impl Fn(usize, &mut [[f64; 4]]) + Sync,
) {
    if row_len == 0 {
        return;
    }
    let (even, odd): (Vec<_>, Vec<_>) = table
        .chunks_mut(row_len)
        .enumerate()
        .partition(|(r, _)| r % 2 == 0);
    std::thread::scope(|scope| {
        let fill = &fill;
        let handle = scope.spawn(move || odd.into_iter().for_each(|(r, row)| fill(r, row)));
        even.into_iter().for_each(|(r, row)| fill(r, row));
        handle
            .join()
            .unwrap_or_else(|panic| std::panic::resume_unwind(panic));
    });
}

/// Everything a grid's table depends on, bit for bit: equal keys tabulate equal tables.
fn grid_key(
    pose: &Standardisation,
    features: &Standardisation,
    kernels: &[Arc<FeatureKernel>],
    origin: [f64; 2],
    step: [f64; 2],
    nodes: [usize; 2],
) -> Vec<u8> {
    let mut numbers: Vec<f64> = [origin, step].concat();
    numbers.extend(nodes.map(|n| n as f64));
    let samples = kernels.first().map_or(0, |k| k.inputs.len());
    numbers.extend([kernels.len() as f64, samples as f64]);
    for s in [pose, features] {
        numbers.extend(&s.means);
        numbers.extend(&s.scales);
    }
    for k in kernels {
        numbers.extend([
            k.signal_var,
            k.inverse_length[0],
            k.inverse_length[1],
            f64::NAN,
        ]);
        numbers.extend(k.inputs.iter().flatten());
        numbers.extend(&k.alpha);
    }
    numbers
        .iter()
        .flat_map(|x| x.to_bits().to_le_bytes())
        .collect()
}

fn squared(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]) * (a[0] - b[0]) + (a[1] - b[1]) * (a[1] - b[1])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimator::test_maps::{workspace_mesh, workspace_points};
    use rand::SeedableRng;

    /// A surrogate of two smooth maps on the 1 mm mesh, with fixed hyperparameters.
    fn surrogate(spacing: f64, leave_one_out: bool) -> Surrogate {
        let poses = workspace_mesh(20);
        let rows: Vec<Vec<f64>> = poses
            .iter()
            .map(|q| {
                vec![
                    (q[0] / 6.0).sin() + q[1] / 20.0,
                    (q[0] * q[1] / 300.0).cos(),
                ]
            })
            .collect();
        let pose = Standardisation::fit(&poses.iter().map(|p| p.to_vec()).collect::<Vec<_>>(), 2);
        let features = Standardisation::fit(&rows, 2);
        let h = SurrogateHyperparameters {
            length_scales: [0.8, 1.1],
            signal_std: 1.0,
            noise_std: 1e-3,
            log_marginal_likelihood: 0.0,
        };
        Surrogate::new(
            pose,
            features,
            &[h.clone(), h],
            &poses,
            &rows,
            spacing,
            leave_one_out,
        )
        .unwrap()
    }

    #[test]
    fn the_grid_reproduces_the_process_and_its_slopes() {
        let s = surrogate(0.25, false);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let (mut values, mut jac) = (vec![0.0; 2], vec![[0.0; 2]; 2]);
        for q in workspace_points(200, &mut rng) {
            s.eval(q, &mut values, Some(&mut jac));
            for i in 0..2 {
                let (v, g) = s.exact(i, q);
                assert!(
                    (values[i] - v).abs() < 1e-7,
                    "{q:?} value {} vs {v}",
                    values[i]
                );
                for k in 0..2 {
                    assert!(
                        (jac[i][k] - g[k]).abs() < 1e-5,
                        "{q:?} slope {:?} vs {g:?}",
                        jac[i]
                    );
                }
            }
            // The value alone is the same interpolation.
            let mut alone = vec![0.0; 2];
            s.eval(q, &mut alone, None);
            assert_eq!(alone, values);
        }
    }

    #[test]
    fn a_coarse_grid_is_measurably_worse() {
        // Guards the interpolation itself: with nodes 4 mm apart the error is visible.
        let s = surrogate(4.0, false);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(4);
        let mut values = vec![0.0; 2];
        let worst = workspace_points(200, &mut rng)
            .into_iter()
            .map(|q| {
                s.eval(q, &mut values, None);
                (values[0] - s.exact(0, q).0).abs()
            })
            .fold(0.0f64, f64::max);
        assert!(worst > 1e-5 && worst < 1e-1, "{worst}");
    }

    #[test]
    fn leave_one_out_only_when_asked() {
        assert!(surrogate(0.25, false).leave_one_out_rms().is_none());
        let rms = surrogate(0.25, true).leave_one_out_rms().unwrap();
        // Smooth maps on a 1 mm mesh: held-out residuals are small but not zero.
        for r in rms {
            assert!(r > 0.0 && r < 1e-2, "{r}");
        }
    }

    #[test]
    fn a_feature_fitted_alike_is_shared_with_the_bits_of_a_fit_alone() {
        let poses = workspace_mesh(8);
        let value = |q: [f64; 2], i: usize| match i {
            0 => (q[0] / 5.0).sin() + q[1] / 30.0,
            1 => (q[0] * q[1] / 200.0).cos(),
            _ => q[0] + 0.1 * q[1],
        };
        let rows = |count: usize| -> Vec<Vec<f64>> {
            (poses.iter())
                .map(|q| (0..count).map(|i| value(*q, i)).collect())
                .collect()
        };
        let pose = Standardisation::fit(&poses.iter().map(|p| p.to_vec()).collect::<Vec<_>>(), 2);
        let fit = |count: usize| {
            let rows = rows(count);
            let features = Standardisation::fit(&rows, count);
            fit_hyperparameters(&pose, &features, &poses, &rows, 40, 15)
        };
        let two = fit(2);
        let alone: Vec<_> = two.iter().map(|h| h.as_ref().clone()).collect();
        let three = fit(3);
        for i in 0..2 {
            assert!(Arc::ptr_eq(&two[i], &three[i]), "feature {i} fitted twice");
        }
        assert!(three[2].is_some());
        drop((two, three));
        // Freed with its last holder: fitted again, to the same bits.
        let again = fit(2);
        for (h, a) in again.iter().zip(&alone) {
            assert_eq!(h.as_ref(), a);
        }
    }

    #[test]
    fn busy_indices_wait_and_every_result_lands_in_its_slot() {
        for count in 0..8 {
            let out = on_two_threads_busy_last(count, |i, wait| (wait || i % 3 != 0).then_some(i));
            assert_eq!(out, (0..count).collect::<Vec<_>>(), "{count}");
        }
    }
}
