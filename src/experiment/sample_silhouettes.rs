//! The robot's silhouette at a pose, predicted from the sample frames: the render check without
//! a renderer (`[confidence] render_from = "samples"`).
//!
//! Each sample frame's silhouette becomes a signed distance field (pixels from the edge, exact
//! Euclidean, positive inside). The silhouette at a pose p is the zero level of a local linear
//! fit of the fields of the [`NEIGHBOURS`] samples nearest p (Gaussian weights, the farthest
//! one's distance as bandwidth), evaluated at p. A field that changes linearly with the pose (an
//! edge that translates) is reproduced exactly, so an edge is placed between the samples' edges
//! as the pose lies between theirs, where the nearest sample's silhouette would be off by up to
//! half the spacing. It holds where the silhouette moves nearly linearly between neighbouring
//! samples: on the 1 mm mesh it catches what the simulator's renderer catches, on a 2 mm mesh
//! far less (docs/results.md).

use nalgebra::{Matrix3, Vector3};

/// Samples in each local fit: the fewest that fix a plane, and one more.
pub const NEIGHBOURS: usize = 4;

/// Fields are stored in 1/32 px, in an `i16`: ±1,023 px, more than any frame's size.
const FIELD_UNITS_PER_PX: f32 = 32.0;

/// The sample frames' silhouettes as signed distance fields, with their poses.
#[derive(Debug, Clone)]
pub struct SampleSilhouettes {
    width: usize,
    height: usize,
    poses: Vec<[f64; 2]>,
    fields: Vec<Vec<i16>>,
}

impl SampleSilhouettes {
    /// The fields of `samples` (a pose and its silhouette, `width × height` row-major pixel
    /// flags). `None` with fewer than 3 samples or a pose that is not finite: no plane can be
    /// fitted then.
    ///
    /// # Panics
    /// If a silhouette does not have `width × height` pixels (a caller's bug).
    pub fn new(
        width: usize,
        height: usize,
        samples: impl IntoIterator<Item = ([f64; 2], Vec<bool>)>,
    ) -> Option<Self> {
        let (mut poses, mut fields) = (Vec::new(), Vec::new());
        for (pose, mask) in samples {
            assert_eq!(
                mask.len(),
                width * height,
                "a silhouette of the frame's size"
            );
            if !pose.iter().all(|v| v.is_finite()) {
                return None;
            }
            poses.push(pose);
            fields.push(signed_distances(&mask, width, height));
        }
        (poses.len() >= 3).then_some(Self {
            width,
            height,
            poses,
            fields,
        })
    }

    /// The samples it predicts from.
    pub fn len(&self) -> usize {
        self.poses.len()
    }

    /// Whether it has no samples (never: [`SampleSilhouettes::new`] refuses fewer than 3).
    pub fn is_empty(&self) -> bool {
        self.poses.is_empty()
    }

    /// The silhouette predicted at `at` (row-major pixel flags); `None` where `at` is not finite.
    pub fn predict(&self, at: [f64; 2]) -> Option<Vec<bool>> {
        let weights = self.weights(at)?;
        let mut field = vec![0.0f32; self.width * self.height];
        for (n, w) in weights {
            let w = w as f32;
            for (value, &sample) in field.iter_mut().zip(&self.fields[n]) {
                *value += w * f32::from(sample);
            }
        }
        Some(field.into_iter().map(|v| v > 0.0).collect())
    }

    /// The local linear fit's value at `at` as weights of the nearest samples' fields.
    fn weights(&self, at: [f64; 2]) -> Option<Vec<(usize, f64)>> {
        if !at.iter().all(|v| v.is_finite()) {
            return None;
        }
        let offset = |n: usize| [self.poses[n][0] - at[0], self.poses[n][1] - at[1]];
        let mut near: Vec<(f64, usize)> = (0..self.poses.len())
            .map(|n| (offset(n)[0].hypot(offset(n)[1]), n))
            .collect();
        let k = NEIGHBOURS.min(near.len());
        near.select_nth_unstable_by(k - 1, |a, b| a.0.total_cmp(&b.0));
        near.truncate(k);
        // Offsets in bandwidths, so the system's scale is 1 whatever the spacing.
        let bandwidth = near.iter().map(|p| p.0).fold(0.0, f64::max).max(1e-9);
        let rows: Vec<(usize, f64, Vector3<f64>)> = (near.iter())
            .map(|&(d, n)| {
                let [dx, dy] = offset(n);
                let x = Vector3::new(1.0, dx / bandwidth, dy / bandwidth);
                (n, (-(d / bandwidth).powi(2)).exp(), x)
            })
            .collect();
        let normal: Matrix3<f64> = rows.iter().map(|(_, k, x)| *k * x * x.transpose()).sum();
        // Samples on a line fix no plane: their kernel-weighted mean instead.
        let intercept = (normal.determinant().abs() > 1e-9)
            .then(|| normal.try_inverse())
            .flatten()
            .map(|inverse| inverse.row(0).transpose());
        let total: f64 = rows.iter().map(|r| r.1).sum();
        Some(
            (rows.into_iter())
                .map(|(n, k, x)| match intercept {
                    Some(row) => (n, k * row.dot(&x)),
                    None => (n, k / total),
                })
                .collect(),
        )
    }
}

/// Distance (px) from each pixel centre to the silhouette's edge, positive inside, in
/// [`FIELD_UNITS_PER_PX`]: half a pixel less than the distance to the nearest pixel of the other
/// side, so the edge lies between a pixel in and its neighbour out.
fn signed_distances(mask: &[bool], width: usize, height: usize) -> Vec<i16> {
    let to_inside = squared_distances(mask, width, height, true);
    let to_outside = squared_distances(mask, width, height, false);
    let units = |px: f64| (px * f64::from(FIELD_UNITS_PER_PX)).round() as i16;
    (mask.iter().enumerate())
        .map(|(i, &inside)| match inside {
            true => units(to_outside[i].sqrt() - 0.5),
            false => -units(to_inside[i].sqrt() - 0.5),
        })
        .collect()
}

/// Squared Euclidean distance from each pixel to the nearest pixel whose flag is `target`
/// (infinite where there is none): Felzenszwalb and Huttenlocher's separable transform, columns
/// then rows.
fn squared_distances(mask: &[bool], width: usize, height: usize, target: bool) -> Vec<f64> {
    let mut grid: Vec<f64> = (mask.iter())
        .map(|&m| if m == target { 0.0 } else { f64::INFINITY })
        .collect();
    let mut line = LowerEnvelope::new(width.max(height));
    let mut column = vec![0.0; height];
    for x in 0..width {
        for (y, value) in column.iter_mut().enumerate() {
            *value = grid[y * width + x];
        }
        line.transform(&mut column);
        for (y, value) in column.iter().enumerate() {
            grid[y * width + x] = *value;
        }
    }
    for row in grid.chunks_mut(width) {
        line.transform(row);
    }
    grid
}

/// The 1-D squared distance transform by the lower envelope of parabolas, its buffers reused.
struct LowerEnvelope {
    vertices: Vec<usize>,
    bounds: Vec<f64>,
    input: Vec<f64>,
}

impl LowerEnvelope {
    fn new(length: usize) -> Self {
        Self {
            vertices: vec![0; length],
            bounds: vec![0.0; length + 1],
            input: vec![0.0; length],
        }
    }

    /// Replaces each `f[q]` by min over p of (q − p)² + f[p].
    fn transform(&mut self, f: &mut [f64]) {
        let n = f.len();
        self.input[..n].copy_from_slice(f);
        let g = &self.input;
        let Some(first) = (0..n).find(|&q| g[q].is_finite()) else {
            return;
        };
        let (v, z) = (&mut self.vertices, &mut self.bounds);
        let mut k = 0;
        v[0] = first;
        z[0] = f64::NEG_INFINITY;
        z[1] = f64::INFINITY;
        for q in first + 1..n {
            if !g[q].is_finite() {
                continue;
            }
            let meet = |p: usize| {
                ((g[q] + (q * q) as f64) - (g[p] + (p * p) as f64)) / (2.0 * (q - p) as f64)
            };
            let mut s = meet(v[k]);
            while s <= z[k] {
                k -= 1;
                s = meet(v[k]);
            }
            k += 1;
            v[k] = q;
            z[k] = s;
            z[k + 1] = f64::INFINITY;
        }
        k = 0;
        for (q, out) in f.iter_mut().enumerate() {
            while z[k + 1] < q as f64 {
                k += 1;
            }
            let p = v[k];
            *out = (q as f64 - p as f64).powi(2) + g[p];
        }
    }
}

#[cfg(test)]
#[path = "sample_silhouettes_tests.rs"]
mod tests;
