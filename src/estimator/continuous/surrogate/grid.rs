//! The tabulated maps: each feature's Gaussian process at every node of a regular grid (value,
//! both slopes and the mixed derivative), and its bicubic Hermite interpolation between nodes.

use super::{grid_key, grid_nodes, grid_share, rows_on_two_threads, FeatureKernel, Grid};
use std::sync::Arc;

use crate::planar::bounding_box;
use crate::standardisation::Standardisation;

impl Grid {
    /// The maps at every node of a grid of about `spacing` mm over the poses' bounding box (at
    /// least 2 and at most [`MAX_GRID_NODES`](super::MAX_GRID_NODES) nodes per axis).
    pub(super) fn tabulate(
        pose: &Standardisation,
        features: &Standardisation,
        kernels: &[Arc<FeatureKernel>],
        poses: &[[f64; 2]],
        spacing: f64,
    ) -> Self {
        let (lo, hi) = bounding_box(poses);
        let nodes = grid_nodes([hi[0] - lo[0], hi[1] - lo[1]], spacing);
        let mut step = [1.0; 2];
        for k in 0..2 {
            if hi[k] > lo[k] {
                step[k] = (hi[k] - lo[k]) / (nodes[k] - 1) as f64;
            }
        }
        let dim = kernels.len();
        let node = |c: usize, r: usize| [lo[0] + c as f64 * step[0], lo[1] + r as f64 * step[1]];
        let fill_row = |r: usize, out: &mut [[f64; 4]]| {
            for (c, slots) in out.chunks_exact_mut(dim).enumerate() {
                let q = node(c, r);
                let z = [pose.apply(0, q[0]), pose.apply(1, q[1])];
                for (i, (kernel, slot)) in kernels.iter().zip(slots).enumerate() {
                    let [v, gx, gy, gxy] = kernel.value_gradient_cross(z);
                    let (s, [sx, sy]) = (features.scales[i], [pose.scales[0], pose.scales[1]]);
                    *slot = [
                        features.means[i] + s * v,
                        s * gx / sx,
                        s * gy / sy,
                        s * gxy / (sx * sy),
                    ];
                }
            }
        };
        let key = grid_key(pose, features, kernels, lo, step, nodes);
        // Filled in place: the table is the run's largest allocation, so it is never held twice.
        let table = grid_share::shared(key, || {
            let mut table = vec![[0.0; 4]; nodes[0] * nodes[1] * dim];
            rows_on_two_threads(&mut table, nodes[0] * dim, fill_row);
            table
        });
        Self {
            origin: lo,
            step,
            nodes,
            table,
            lanes: Arc::default(),
        }
    }

    /// The cell holding `q` (its lower corner's node, clamped to the grid) and `q`'s position in
    /// it, 0 to 1 per axis.
    #[inline]
    pub(super) fn locate(&self, q: [f64; 2]) -> ([usize; 2], [f64; 2]) {
        let mut cell = [0usize; 2];
        let mut t = [0.0; 2];
        for k in 0..2 {
            let x = ((q[k] - self.origin[k]) / self.step[k]).clamp(0.0, (self.nodes[k] - 1) as f64);
            // x ≥ 0 (NaN gives 0 either way): truncation is the floor, without a call.
            let c = (x as usize).min(self.nodes[k] - 2);
            cell[k] = c;
            t[k] = x - c as f64;
        }
        (cell, t)
    }

    pub(super) fn eval(
        &self,
        q: [f64; 2],
        dim: usize,
        values: &mut [f64],
        jacobian: Option<&mut [[f64; 2]]>,
    ) {
        let (cell, t) = self.locate(q);
        // Hermite basis h00, h10, h01, h11 and their derivatives, per axis.
        let basis = |t: f64| (hermite(t), hermite_slopes(t));
        let ((bx, dbx), (by, dby)) = (basis(t[0]), basis(t[1]));
        let [hx, hy] = self.step;
        let corners = [(0, 0), (1, 0), (0, 1), (1, 1)];
        let index = |a: usize, b: usize| ((cell[1] + b) * self.nodes[0] + cell[0] + a) * dim;
        // Per corner: the weights of f, h·fx, h·fy, h²·fxy, and of their x and y derivatives.
        let weights = corners.map(|(a, b)| {
            let (v0, v1, w0, w1) = (bx[2 * a], bx[2 * a + 1], by[2 * b], by[2 * b + 1]);
            let (d0, d1, e0, e1) = (dbx[2 * a], dbx[2 * a + 1], dby[2 * b], dby[2 * b + 1]);
            (
                [v0 * w0, hx * v1 * w0, hy * v0 * w1, hx * hy * v1 * w1],
                [d0 * w0 / hx, d1 * w0, d0 * w1 * hy / hx, hy * d1 * w1],
                [v0 * e0 / hy, hx * v1 * e0 / hy, v0 * e1, hx * v1 * e1],
                index(a, b),
            )
        });
        match jacobian {
            None => {
                for (i, v) in values[..dim].iter_mut().enumerate() {
                    let mut sum = 0.0;
                    for (w, _, _, at) in &weights {
                        let n = &self.table[at + i];
                        sum += w[0] * n[0] + w[1] * n[1] + w[2] * n[2] + w[3] * n[3];
                    }
                    *v = sum;
                }
            }
            Some(jac) => {
                for (i, (v, g)) in values[..dim].iter_mut().zip(jac.iter_mut()).enumerate() {
                    let (mut sum, mut gx, mut gy) = (0.0, 0.0, 0.0);
                    for (w, wx, wy, at) in &weights {
                        let n = &self.table[at + i];
                        sum += w[0] * n[0] + w[1] * n[1] + w[2] * n[2] + w[3] * n[3];
                        gx += wx[0] * n[0] + wx[1] * n[1] + wx[2] * n[2] + wx[3] * n[3];
                        gy += wy[0] * n[0] + wy[1] * n[1] + wy[2] * n[2] + wy[3] * n[3];
                    }
                    *v = sum;
                    *g = [gx, gy];
                }
            }
        }
    }
}

/// The cubic Hermite basis h00, h10, h01, h11 at `t`.
#[inline]
pub(super) fn hermite(t: f64) -> [f64; 4] {
    let (t2, t3) = (t * t, t * t * t);
    [
        2.0 * t3 - 3.0 * t2 + 1.0,
        t3 - 2.0 * t2 + t,
        -2.0 * t3 + 3.0 * t2,
        t3 - t2,
    ]
}

/// The derivatives of [`hermite`]'s basis at `t`.
#[inline]
fn hermite_slopes(t: f64) -> [f64; 4] {
    let t2 = t * t;
    [
        6.0 * t2 - 6.0 * t,
        3.0 * t2 - 4.0 * t + 1.0,
        -6.0 * t2 + 6.0 * t,
        3.0 * t2 - 2.0 * t,
    ]
}
