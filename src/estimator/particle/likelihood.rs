//! The frame's likelihood at every particle, in blocks (issue 32): each block's maps come from
//! one cell lookup per particle ([`Continuous::feature_maps_block`], feature-major), the
//! features the frame lacks are dropped once per frame, and the loops over a block's particles
//! are straight-line arithmetic the compiler vectorises: an exponential of our own
//! ([`exp_nonpositive`]) instead of the library's, and one logarithm per [`CHUNK`] features
//! (of their terms' product) instead of one per feature.
//!
//! Against the per-feature formula (`ParticleFilter::log_likelihood`) the result moves by a
//! few units in the last place (the tests bound it); wherever a product could leave the normal
//! range, or a term falls below the formula's floor (`f64::MIN_POSITIVE`), the particle's
//! chunk is summed term by term as the formula does.

use crate::estimator::Continuous;

/// Particles weighed together: a block's maps (features × `BLOCK`) stay in the L1/L2 cache.
const BLOCK: usize = 256;
/// Features whose terms are multiplied before one logarithm; each term lies in
/// [`f64::MIN_POSITIVE`, 1/(σ√(2π)) + ε/W], so few chunks leave the normal range.
const CHUNK: usize = 8;
/// Below this exponent e^x is subnormal, which [`exp_nonpositive`] does not produce: such
/// values are recomputed with `f64::exp`.
const SUBNORMAL_BELOW: f64 = -708.0;

/// The frame's usable features and their constants, and the scratch of a block; kept between
/// frames so that a frame allocates nothing.
#[derive(Default)]
pub(super) struct FrameLikelihood {
    /// Per usable feature: index, measured value, 1/σ, (1 − ε)/(σ√(2π)) and ε/W.
    index: Vec<usize>,
    value: Vec<f64>,
    inverse_sigma: Vec<f64>,
    peak: Vec<f64>,
    floor: Vec<f64>,
    /// A block's maps (feature-major), exponents, exponentials, chunk products and lowest terms.
    mapped: Vec<f64>,
    exponent: Vec<f64>,
    exponential: Vec<f64>,
    product: Vec<f64>,
    lowest: Vec<f64>,
}

impl FrameLikelihood {
    /// Takes the frame's `values` (`None` for a feature left out) with each feature's σ, the
    /// constants σ·√(2π) (`norms`) and ε/W (`uniforms`), and ε.
    pub(super) fn prepare(
        &mut self,
        values: &[Option<f64>],
        scales: &[f64],
        (norms, uniforms): (&[f64], &[f64]),
        outlier_share: f64,
    ) {
        let keep = 1.0 - outlier_share;
        self.index.clear();
        self.value.clear();
        self.inverse_sigma.clear();
        self.peak.clear();
        self.floor.clear();
        for (i, v) in values.iter().enumerate() {
            let Some(v) = v else { continue };
            self.index.push(i);
            self.value.push(*v);
            self.inverse_sigma.push(1.0 / scales[i]);
            self.peak.push(keep / norms[i]);
            self.floor.push(uniforms[i]);
        }
    }

    /// log p(frame | q) at each of `particles` into `logs` (cleared first).
    pub(super) fn log_likelihoods(
        &mut self,
        maps: &Continuous,
        particles: &[[f64; 2]],
        logs: &mut Vec<f64>,
    ) {
        let dim = maps.residual_scales().len();
        logs.clear();
        self.mapped.resize(dim * BLOCK, 0.0);
        for v in [
            &mut self.exponent,
            &mut self.exponential,
            &mut self.product,
            &mut self.lowest,
        ] {
            v.resize(BLOCK, 0.0);
        }
        for block in particles.chunks(BLOCK) {
            let m = block.len();
            maps.feature_maps_block(block, &mut self.mapped[..dim * m]);
            let start = logs.len();
            logs.resize(start + m, 0.0);
            let logs = &mut logs[start..];
            for first in (0..self.index.len()).step_by(CHUNK) {
                let chunk = first..(first + CHUNK).min(self.index.len());
                self.chunk_products(chunk.clone(), m);
                for (p, log) in logs.iter_mut().enumerate() {
                    let (product, lowest) = (self.product[p], self.lowest[p]);
                    *log += if lowest >= f64::MIN_POSITIVE
                        && product >= f64::MIN_POSITIVE
                        && product <= f64::MAX
                    {
                        product.ln()
                    } else {
                        self.chunk_log_by_term(chunk.clone(), p, m)
                    };
                }
            }
        }
    }

    /// Per particle of the block (`m` of them): the product of the terms of the features in
    /// `chunk` and the lowest of them.
    fn chunk_products(&mut self, chunk: std::ops::Range<usize>, m: usize) {
        self.product[..m].fill(1.0);
        self.lowest[..m].fill(f64::INFINITY);
        for j in chunk {
            let i = self.index[j];
            let (v, inverse) = (self.value[j], self.inverse_sigma[j]);
            let mapped = &self.mapped[i * m..(i + 1) * m];
            let (exponent, exponential) = (&mut self.exponent[..m], &mut self.exponential[..m]);
            for ((x, e), mu) in exponent.iter_mut().zip(exponential.iter_mut()).zip(mapped) {
                let z = (v - mu) * inverse;
                *x = -0.5 * z * z;
                *e = exp_nonpositive(*x);
            }
            if exponent.iter().any(|&x| x < SUBNORMAL_BELOW) {
                for (x, e) in exponent.iter().zip(exponential.iter_mut()) {
                    if *x < SUBNORMAL_BELOW {
                        *e = x.exp();
                    }
                }
            }
            let (peak, floor) = (self.peak[j], self.floor[j]);
            let products = self.product[..m].iter_mut().zip(&mut self.lowest[..m]);
            for ((product, lowest), e) in products.zip(exponential.iter()) {
                let term = peak * e + floor;
                *product *= term;
                *lowest = lowest.min(term);
            }
        }
    }

    /// Σ ln max(term, MIN_POSITIVE) over the features in `chunk` at particle `p` of the
    /// block: the formula itself, where the product cannot stand for it.
    fn chunk_log_by_term(&self, chunk: std::ops::Range<usize>, p: usize, m: usize) -> f64 {
        chunk
            .map(|j| {
                let z =
                    (self.value[j] - self.mapped[self.index[j] * m + p]) * self.inverse_sigma[j];
                let x = -0.5 * z * z;
                let e = match x < SUBNORMAL_BELOW {
                    true => x.exp(),
                    false => exp_nonpositive(x),
                };
                (self.peak[j] * e + self.floor[j])
                    .max(f64::MIN_POSITIVE)
                    .ln()
            })
            .sum()
    }
}

/// e^x for x ≤ 0 within a few units in the last place of `f64::exp`, without branches or
/// calls, so that a loop of it vectorises: x = n·ln 2 + r with |r| ≤ ln 2 / 2 (ln 2 split in
/// two so that n·ln 2's high part is exact), e^r by its Taylor series to r¹³/13! (the rest is
/// below 10⁻¹⁷ relative), times 2ⁿ built from the exponent bits. Inputs below −708 are taken
/// as −708 (e^x would be subnormal): callers recompute those with `f64::exp`.
#[inline(always)]
pub(super) fn exp_nonpositive(x: f64) -> f64 {
    // 1.5·2⁵²: adding it rounds to an integer held in the low mantissa bits.
    const SHIFT: f64 = 6_755_399_441_055_744.0;
    const LN2_HI: f64 = 6.931_471_803_691_238_164_9e-1;
    const LN2_LO: f64 = 1.908_214_929_270_587_700_02e-10;
    // 1/k! for k = 13 down to 2.
    const TAYLOR: [f64; 12] = [
        1.0 / 6_227_020_800.0,
        1.0 / 479_001_600.0,
        1.0 / 39_916_800.0,
        1.0 / 3_628_800.0,
        1.0 / 362_880.0,
        1.0 / 40_320.0,
        1.0 / 5_040.0,
        1.0 / 720.0,
        1.0 / 120.0,
        1.0 / 24.0,
        1.0 / 6.0,
        0.5,
    ];
    let x = x.clamp(SUBNORMAL_BELOW, 0.0);
    let shifted = x * std::f64::consts::LOG2_E + SHIFT;
    let n = shifted - SHIFT;
    let r = (x - n * LN2_HI) - n * LN2_LO;
    let mut p = TAYLOR[0];
    for c in &TAYLOR[1..] {
        p = p * r + c;
    }
    p = (p * r + 1.0) * r + 1.0;
    // n ∈ [−1022, 0]: its low 12 bits plus the bias are the exponent field of 2ⁿ.
    let scale = f64::from_bits(shifted.to_bits().wrapping_add(1023) << 52);
    p * scale
}

/// e^x for each x ≤ 0 of `xs`, in place: [`exp_nonpositive`], with `f64::exp` where the result
/// is subnormal.
pub(super) fn exp_nonpositive_in_place(xs: &mut [f64]) {
    let subnormal = xs.iter().any(|&x| x < SUBNORMAL_BELOW);
    if subnormal {
        for x in xs.iter_mut() {
            *x = match *x < SUBNORMAL_BELOW {
                true => x.exp(),
                false => exp_nonpositive(*x),
            };
        }
    } else {
        for x in xs.iter_mut() {
            *x = exp_nonpositive(*x);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// Relative difference in units of f64::EPSILON.
    fn ulps(a: f64, b: f64) -> f64 {
        ((a - b) / b).abs() / f64::EPSILON
    }

    #[test]
    fn the_exponential_is_the_library_s_within_a_few_units_in_the_last_place() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let mut worst = 0.0f64;
        let xs = (0..200_000)
            .map(|k| match k % 3 {
                0 => -rng.random::<f64>() * 708.0,
                1 => -rng.random::<f64>() * 2.0,
                _ => -rng.random::<f64>() * 1e-6,
            })
            .chain([0.0, -0.0, -1e-300, -0.5 * std::f64::consts::LN_2, -708.0]);
        for x in xs {
            worst = worst.max(ulps(exp_nonpositive(x), x.exp()));
        }
        assert!(worst <= 4.0, "{worst} ulps");
        // Below −708 the in-place form defers to the library (subnormal or zero results).
        let mut xs = vec![-1.0, -720.0, -745.0, -1e6, f64::NEG_INFINITY];
        let expected: Vec<f64> = xs.iter().map(|x| x.exp()).collect();
        exp_nonpositive_in_place(&mut xs);
        assert!(ulps(xs[0], expected[0]) <= 4.0);
        assert_eq!(xs[1..], expected[1..]);
    }
}
