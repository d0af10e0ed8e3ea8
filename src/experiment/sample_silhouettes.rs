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
    /// The fields of the silhouettes `silhouette` makes of `frames` (a pose and its `width ×
    /// height` row-major pixel flags; `None` skips the frame). `None` with fewer than 3 samples
    /// or a pose that is not finite: no plane can be fitted then.
    ///
    /// The fields are made on two threads when `threads` is 2 or more (the same fields); each
    /// silhouette becomes its field where it is made, so one at a time per thread is held.
    ///
    /// # Panics
    /// If a silhouette does not have `width × height` pixels (a caller's bug).
    pub fn new<T: Sync>(
        width: usize,
        height: usize,
        frames: &[T],
        silhouette: impl Fn(&T) -> Option<([f64; 2], Vec<bool>)> + Sync,
        threads: usize,
    ) -> Option<Self> {
        // A sweep's other job waits for these fields.
        let made = on_threads(threads, frames, |frame| {
            let (pose, mask) = silhouette(frame)?;
            assert_eq!(
                mask.len(),
                width * height,
                "a silhouette of the frame's size"
            );
            Some((pose, signed_distances(&mask, width, height)))
        });
        let (poses, fields): (Vec<[f64; 2]>, Vec<Vec<i16>>) = made.into_iter().flatten().unzip();
        if poses.len() < 3 || !poses.iter().flatten().all(|v| v.is_finite()) {
            return None;
        }
        Some(Self {
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
        let words = self.predict_packed(at)?;
        Some(
            (0..self.width * self.height)
                .map(|i| words[i / 64] >> (i % 64) & 1 == 1)
                .collect(),
        )
    }

    /// [`SampleSilhouettes::predict`]'s flags packed into words (pixel i is bit i % 64 of word
    /// i / 64), made 64 pixels at a time ([`predict_words`]): no frame-sized buffer per call.
    pub fn predict_packed(&self, at: [f64; 2]) -> Option<Vec<u64>> {
        let weights: Vec<(f32, &[i16])> = (self.weights(at)?.into_iter())
            .map(|(n, w)| (w as f32, self.fields[n].as_slice()))
            .collect();
        let mut words = vec![0u64; (self.width * self.height).div_ceil(64)];
        predict_words(&weights, &mut words, self.width * self.height);
        Some(words)
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

crate::simd::with_avx!(
    /// The first `count` pixels of the field Σ weight·field, as the bits of `words`, with the
    /// widest vectors the processor has: each pixel sums the same products in the same order
    /// as a whole-frame pass would, so every width gives the same bits.
    fn predict_words(weights: &[(f32, &[i16])], words: &mut [u64], count: usize) -> () =
        predict_words_plain,
    avx512 = predict_words_plain
);

#[inline(always)]
fn predict_words_plain(weights: &[(f32, &[i16])], words: &mut [u64], count: usize) {
    // Whole blocks of 64 as arrays, so the compiler keeps them in vector registers.
    let whole = count / 64;
    for (b, word) in words.iter_mut().enumerate().take(whole) {
        let mut block = [0.0f32; 64];
        for &(w, field) in weights {
            let samples: &[i16; 64] = field[b * 64..b * 64 + 64].try_into().expect("64");
            for (value, &sample) in block.iter_mut().zip(samples) {
                *value += w * f32::from(sample);
            }
        }
        *word = bits(&block);
    }
    if !count.is_multiple_of(64) {
        let mut block = [0.0f32; 64];
        let tail = &mut block[..count % 64];
        for &(w, field) in weights {
            for (value, &sample) in tail.iter_mut().zip(&field[whole * 64..]) {
                *value += w * f32::from(sample);
            }
        }
        // The pixels past the frame stay 0, so their bits stay clear.
        words[whole] = bits(&block);
    }
}

/// `f` of every item, in order; with `threads` 2 or more, half of them on a second thread (a
/// panic there goes on here, as without the thread).
pub(super) fn on_threads<T: Sync, U: Send>(
    threads: usize,
    items: &[T],
    f: impl Fn(&T) -> U + Sync,
) -> Vec<U> {
    if threads < 2 {
        return items.iter().map(f).collect();
    }
    let (first, second) = items.split_at(items.len() / 2);
    std::thread::scope(|scope| {
        let f = &f;
        let other = scope.spawn(move || second.iter().map(f).collect::<Vec<U>>());
        let mut all: Vec<U> = first.iter().map(f).collect();
        all.extend(
            other
                .join()
                .unwrap_or_else(|p| std::panic::resume_unwind(p)),
        );
        all
    })
}

/// Bit i set where `values[i]` is positive (above 0; not 0, not NaN), four at a time with SSE2's
/// compare and movemask, which every x86_64 processor has (packing flag by flag cost more than
/// the sums it packs).
#[inline(always)]
fn bits(values: &[f32; 64]) -> u64 {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{_mm_cmpgt_ps, _mm_loadu_ps, _mm_movemask_ps, _mm_setzero_ps};
        let mut word = 0u64;
        for (i, quad) in values.chunks_exact(4).enumerate() {
            // SAFETY: SSE2 is part of x86_64; `quad` holds the 4 floats the load reads.
            let mask = unsafe {
                _mm_movemask_ps(_mm_cmpgt_ps(_mm_loadu_ps(quad.as_ptr()), _mm_setzero_ps()))
            };
            word |= u64::from(mask as u32) << (4 * i);
        }
        word
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        (values.iter().enumerate()).fold(0, |word, (i, &v)| word | u64::from(v > 0.0) << i)
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
