//! The frame's likelihood at every particle, in blocks (issue 32), bit for bit the per-feature
//! formula (`ParticleFilter::log_likelihood`): each block's maps come from one cell lookup per
//! particle ([`Continuous::feature_maps_block`], feature-major, bit-identical to the single
//! pose), the features the frame lacks are dropped once per frame, and a term whose Gaussian
//! part is below a quarter unit in the last place of its uniform floor is the floor exactly, so
//! its logarithm is taken once per frame instead of an exponential and a logarithm per particle.
//!
//! Not faster arithmetic: an exponential of our own and one logarithm per product of terms
//! were measured 1.4× faster again, but they move the last bits, and the filter amplifies
//! those to different estimates within tens of frames on struck frames
//! (`scenarios/confidence.toml`'s bright box).

use crate::estimator::Continuous;

/// Particles weighed together: a block's maps (features × `BLOCK`) stay in the L1/L2 cache.
const BLOCK: usize = 256;
/// Below this, e^x rounds to 0 (under half the least subnormal, e^−745.13).
const EXP_ZERO_BELOW: f64 = -746.0;

/// The frame's usable features and their constants, and a block's maps; kept between frames
/// so that a frame allocates nothing.
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
    /// A block's maps, feature-major.
    mapped: Vec<f64>,
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
        let keep = self.keep;
        for block in particles.chunks(BLOCK) {
            let m = block.len();
            maps.feature_maps_block(block, &mut self.mapped[..dim * m]);
            let start = logs.len();
            logs.resize(start + m, 0.0);
            let logs = &mut logs[start..];
            for (j, &i) in self.index.iter().enumerate() {
                let (v, sigma, norm, floor) =
                    (self.value[j], self.sigma[j], self.norm[j], self.floor[j]);
                let (floor_log, below) = (self.floor_log[j], self.floor_below[j]);
                let mapped = &self.mapped[i * m..(i + 1) * m];
                for (total, mu) in logs.iter_mut().zip(mapped) {
                    let z = (v - mu) / sigma;
                    let x = -0.5 * z * z;
                    *total += match x < below {
                        true => floor_log,
                        false => {
                            let gaussian = x.exp() / norm;
                            (keep * gaussian + floor).max(f64::MIN_POSITIVE).ln()
                        }
                    };
                }
            }
        }
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
