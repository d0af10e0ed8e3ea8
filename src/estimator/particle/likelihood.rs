//! The frame's likelihood at every particle, in blocks (issue 32), bit for bit the per-feature
//! formula (`ParticleFilter::log_likelihood`): each block's maps come from one cell lookup per
//! particle ([`Continuous::feature_maps_block`], feature-major, bit-identical to the single
//! pose), the features the frame lacks are dropped once per frame, and a term whose Gaussian
//! part is below a quarter unit in the last place of its uniform floor is the floor exactly, so
//! its logarithm is taken once per frame instead of an exponential and a logarithm per particle.
//! Per feature and block, one pass over the particles (vectorised, AVX where the processor has
//! it) forms every exponent and adds the floors; the particles above their floor are listed
//! without a branch, and only they call the exponential and the logarithm: no mispredicted
//! branch per term, and the same operations per term, so the same bits.
//!
//! Not faster arithmetic: an exponential of our own and one logarithm per product of terms
//! were measured 1.4× faster again, but they move the last bits, and the filter amplifies
//! those to different estimates within tens of frames on struck frames
//! (`scenarios/confidence.toml`'s bright box).

use crate::estimator::Continuous;

/// Particles weighed together: a block's maps (features × `BLOCK`) stay in the L1/L2 cache;
/// also the filter's chunk of work for its two threads (`motion`).
pub(super) const BLOCK: usize = 256;
/// Below this, e^x rounds to 0 (under half the least subnormal, e^−745.13).
const EXP_ZERO_BELOW: f64 = -746.0;

/// The frame's usable features and their constants; kept between frames so that a frame
/// allocates nothing.
#[derive(Default)]
pub(super) struct FrameLikelihood {
    /// Per usable feature: index, measured value, σ, σ·√(2π), ε/W, ln max(ε/W, MIN_POSITIVE)
    /// and the exponent below which the term is ε/W exactly.
    index: Vec<usize>,
    value: Vec<f64>,
    sigma: Vec<f64>,
    norm: Vec<f64>,
    floor: Vec<f64>,
    floor_log: Vec<f64>,
    floor_below: Vec<f64>,
    keep: f64,
}

/// One thread's scratch for a block, kept between frames: the block's maps (feature-major),
/// one feature's exponents −z²/2 over the block, and the particles (indices in the block) whose
/// term is above its floor.
#[derive(Default)]
pub(super) struct BlockScratch {
    mapped: Vec<f64>,
    exponents: Vec<f64>,
    above: Vec<u32>,
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
        self.keep = 1.0 - outlier_share;
        for v in [
            &mut self.value,
            &mut self.sigma,
            &mut self.norm,
            &mut self.floor,
            &mut self.floor_log,
            &mut self.floor_below,
        ] {
            v.clear();
        }
        self.index.clear();
        for (i, v) in values.iter().enumerate() {
            let Some(v) = v else { continue };
            let (norm, floor) = (norms[i], uniforms[i]);
            self.index.push(i);
            self.value.push(*v);
            self.sigma.push(scales[i]);
            self.norm.push(norm);
            self.floor.push(floor);
            self.floor_log.push(floor.max(f64::MIN_POSITIVE).ln());
            // keep·e^x/norm < floor·ε/8 below this (one more in the exponent for the rounding of
            // the logarithm and the quotient): the sum then rounds to the floor.
            let peak = self.keep / norm;
            let below = match peak > 0.0 {
                true => (floor * f64::EPSILON / 8.0 / peak).ln() - 1.0,
                false => f64::INFINITY,
            };
            self.floor_below.push(below.max(EXP_ZERO_BELOW));
        }
    }

    /// log p(frame | q) at each of `particles` into `logs` (cleared first), block by block.
    #[cfg(test)]
    pub(super) fn log_likelihoods(
        &self,
        maps: &Continuous,
        particles: &[[f64; 2]],
        scratch: &mut BlockScratch,
        logs: &mut Vec<f64>,
    ) {
        logs.clear();
        logs.resize(particles.len(), 0.0);
        for (block, logs) in particles.chunks(BLOCK).zip(logs.chunks_mut(BLOCK)) {
            self.block(maps, block, scratch, logs);
        }
    }

    /// log p(frame | q) at each of at most `BLOCK` `particles` into `logs` (as long).
    pub(super) fn block(
        &self,
        maps: &Continuous,
        particles: &[[f64; 2]],
        scratch: &mut BlockScratch,
        logs: &mut [f64],
    ) {
        let dim = maps.residual_scales().len();
        let m = particles.len();
        debug_assert!(m <= BLOCK && logs.len() == m);
        scratch.mapped.resize(dim * BLOCK, 0.0);
        scratch.exponents.resize(BLOCK, 0.0);
        scratch.above.resize(BLOCK, 0);
        logs.fill(0.0);
        let keep = self.keep;
        maps.feature_maps_block(particles, &mut scratch.mapped[..dim * m]);
        for (j, &i) in self.index.iter().enumerate() {
            let (norm, floor, below) = (self.norm[j], self.floor[j], self.floor_below[j]);
            let term = Term {
                value: self.value[j],
                sigma: self.sigma[j],
                floor_log: self.floor_log[j],
                below,
            };
            let exponents = &mut scratch.exponents[..m];
            exponents_and_floors(&term, &scratch.mapped[i * m..(i + 1) * m], exponents, logs);
            // Branch-free listing of the terms above their floor (not below it: a NaN
            // exponent takes the formula's path, as in `exponents_and_floors_in`).
            let mut count = 0;
            for (p, &x) in exponents.iter().enumerate() {
                scratch.above[count] = p as u32;
                count += usize::from(x.partial_cmp(&below) != Some(std::cmp::Ordering::Less));
            }
            for &p in &scratch.above[..count] {
                let p = p as usize;
                let gaussian = exponents[p].exp() / norm;
                logs[p] += (keep * gaussian + floor).max(f64::MIN_POSITIVE).ln();
            }
        }
    }
}

/// One feature's constants in [`exponents_and_floors`].
#[derive(Clone, Copy)]
struct Term {
    value: f64,
    sigma: f64,
    floor_log: f64,
    below: f64,
}

crate::simd::with_avx!(
    /// [`exponents_and_floors_in`], with AVX where the processor has it.
    fn exponents_and_floors(
        term: &Term,
        mapped: &[f64],
        exponents: &mut [f64],
        logs: &mut [f64]
    ) -> () = exponents_and_floors_in
);

/// Each particle's exponent −z²/2 of one feature (`mapped`: the feature's map at the block's
/// particles) into `exponents`, and the feature's floor logarithm added to `logs` where the
/// term is its floor; the other terms are left to the caller. Branch-free, so it vectorises.
#[inline(always)]
fn exponents_and_floors_in(term: &Term, mapped: &[f64], exponents: &mut [f64], logs: &mut [f64]) {
    let Term {
        value,
        sigma,
        floor_log,
        below,
    } = *term;
    for ((total, mu), exponent) in logs.iter_mut().zip(mapped).zip(exponents) {
        let z = (value - mu) / sigma;
        let x = -0.5 * z * z;
        *exponent = x;
        let floored = *total + floor_log;
        *total = if x < below { floored } else { *total };
    }
}

/// e^x as `f64::exp` gives it, without its slow underflow path where the result is 0.
pub(super) fn exp(x: f64) -> f64 {
    match x < EXP_ZERO_BELOW {
        true => 0.0,
        false => x.exp(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_vectorised_exponents_and_floors_are_the_plain_ones_bit_for_bit() {
        // Maps near the value (above the floor), far from it (at the floor), exactly at the
        // threshold, and not numbers; two totals so far per particle.
        let term = Term {
            value: 0.5,
            sigma: 0.01,
            floor_log: -2.9957,
            below: -45.5,
        };
        let at_threshold = 0.5 - 0.01 * 91.0f64.sqrt();
        let mapped: Vec<f64> = (0..103)
            .map(|k| match k % 7 {
                0 => f64::NAN,
                1 => at_threshold,
                2 => -40.0,
                _ => 0.5 + 0.013 * (k as f64 - 50.0) / 7.0,
            })
            .collect();
        for start in [0.0, -17.25] {
            let (mut plain, mut wide) = (vec![start; 103], vec![start; 103]);
            let (mut x_plain, mut x_wide) = (vec![0.0; 103], vec![0.0; 103]);
            exponents_and_floors_in(&term, &mapped, &mut x_plain, &mut plain);
            exponents_and_floors(&term, &mapped, &mut x_wide, &mut wide);
            for k in 0..103 {
                assert_eq!(plain[k].to_bits(), wide[k].to_bits(), "{k}");
                assert_eq!(x_plain[k].to_bits(), x_wide[k].to_bits(), "{k}");
                // The floor is added exactly where the exponent is below the threshold.
                let floored = x_plain[k] < term.below;
                assert_eq!(plain[k] != start, floored, "{k}");
            }
        }
    }

    #[test]
    fn below_the_threshold_the_exponential_is_zero_as_the_library_s() {
        for x in [-746.0, -746.5, -800.0, -1e6, f64::NEG_INFINITY] {
            assert_eq!(super::exp(x), x.exp(), "{x}");
        }
        // Just above it, a subnormal.
        assert!(super::exp(-745.0) > 0.0);
        assert_eq!(super::exp(-745.0), (-745.0f64).exp());
    }
}
