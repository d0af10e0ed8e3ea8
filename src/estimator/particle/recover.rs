//! Recovery after struck frames (issue 27): a defensive mixture proposal. A share β
//! (`recovery_share`) of the particles is drawn each frame around the frame's own estimate
//! (the continuous tracker's single-frame fit on the same maps, its covariance widened), the
//! others are predicted as before, so the cloud is a weighted sample of
//! q = (1 − β)·p̂ + β·g. Each weight is then multiplied by p̂/q, so the posterior stays the
//! filter's (likelihood × prediction), only better sampled where the frame says the pose is.
//!
//! p̂, the predicted density, is taken from the last posterior's mean and covariance (a
//! Gaussian-moment approximation, O(1) per particle instead of a sum over every particle): the
//! line's share as a Gaussian about the shifted mean with the step's spread added, the reach's
//! share as uniform over the disc of the reach about the mean, widened by the cloud's spread;
//! before any prediction, uniform over the sample poses' box (the first cloud).

use super::ParticleFilter;
use crate::estimator::PoseEstimator;

/// The frame's estimate's covariance is widened by this factor (in σ), so that the draws
/// cover the truth when the fit's own spread is too sure.
const WIDEN: f64 = 2.0;
/// Spread floor (mm) of the draws, per axis: about the clean error of the maps' fit.
const FLOOR: f64 = 0.01;
/// Beyond this squared Mahalanobis distance under g, g/p̂ is taken as 0 (e^−30).
const FAR: f64 = 60.0;

/// g: the Gaussian about the frame's own estimate.
#[derive(Clone, Copy)]
pub(super) struct Guess {
    mean: [f64; 2],
    /// Lower Cholesky factor of the covariance, and the inverse covariance.
    chol: [[f64; 2]; 2],
    precision: [[f64; 2]; 2],
    /// 1/(2π·√det).
    norm: f64,
}

impl Guess {
    /// The frame's own estimate by the filter's maps, `None` when the fit gives no pose or no
    /// usable covariance.
    pub(super) fn of_frame(filter: &ParticleFilter, features: &[Option<f64>]) -> Option<Self> {
        let fit = filter.maps.estimate(features).ok()?;
        let (mean, c) = (fit.pose?, fit.covariance?);
        let floor = FLOOR * FLOOR;
        let w = WIDEN * WIDEN;
        Self::new(
            mean,
            [
                [w * c[0][0] + floor, w * c[0][1]],
                [w * c[1][0], w * c[1][1] + floor],
            ],
        )
    }

    fn new(mean: [f64; 2], cov: [[f64; 2]; 2]) -> Option<Self> {
        let det = cov[0][0] * cov[1][1] - cov[0][1] * cov[1][0];
        if !(mean.iter().all(|v| v.is_finite()) && det > 0.0 && det.is_finite() && cov[0][0] > 0.0)
        {
            return None;
        }
        let l00 = cov[0][0].sqrt();
        let l10 = cov[1][0] / l00;
        let l11 = (cov[1][1] - l10 * l10).max(0.0).sqrt();
        Some(Self {
            mean,
            chol: [[l00, 0.0], [l10, l11]],
            precision: [
                [cov[1][1] / det, -cov[0][1] / det],
                [-cov[1][0] / det, cov[0][0] / det],
            ],
            norm: 1.0 / (std::f64::consts::TAU * det.sqrt()),
        })
    }

    /// The point of standard normals `d`.
    pub(super) fn point(&self, d: [f64; 2]) -> [f64; 2] {
        let l = self.chol;
        [
            self.mean[0] + l[0][0] * d[0],
            self.mean[1] + l[1][0] * d[0] + l[1][1] * d[1],
        ]
    }

    /// g(p), 0 beyond `FAR`.
    fn density(&self, p: [f64; 2]) -> f64 {
        let d2 = mahalanobis2(&self.precision, [p[0] - self.mean[0], p[1] - self.mean[1]]);
        if d2 > FAR {
            return 0.0;
        }
        self.norm * (-0.5 * d2).exp()
    }
}

fn mahalanobis2(precision: &[[f64; 2]; 2], d: [f64; 2]) -> f64 {
    precision[0][0] * d[0] * d[0]
        + 2.0 * precision[0][1] * d[0] * d[1]
        + precision[1][1] * d[1] * d[1]
}

/// p̂, the predicted density, approximated from the last posterior's moments.
#[derive(Clone, Copy)]
pub(super) enum Predicted {
    /// The first cloud: uniform over the box of this area (mm²).
    Uniform(f64),
    /// The line's share `line` of a Gaussian (its precision and normaliser) about `centre`;
    /// the rest uniform (density `disc`) within `radius` of `mean`.
    Moved {
        line: f64,
        centre: [f64; 2],
        precision: [[f64; 2]; 2],
        norm: f64,
        mean: [f64; 2],
        radius: f64,
        disc: f64,
    },
}

impl Predicted {
    /// From the last posterior's `mean` and `covariance`, the line's `shift`, the Gaussian
    /// step's spread `step` (mm) and the disc's radius `reach` (mm).
    pub(super) fn moved(
        mean: [f64; 2],
        covariance: [[f64; 2]; 2],
        shift: [f64; 2],
        step: f64,
        reach: f64,
        line: f64,
    ) -> Self {
        let s2 = (step * step).max(1e-12);
        let c = [
            [covariance[0][0] + s2, covariance[0][1]],
            [covariance[1][0], covariance[1][1] + s2],
        ];
        let det = (c[0][0] * c[1][1] - c[0][1] * c[1][0]).max(s2 * s2);
        // The cloud's spread widens the disc: two standard deviations along its longer axis.
        let spread = 2.0 * (covariance[0][0] + covariance[1][1]).max(0.0).sqrt();
        let radius = reach + spread;
        Self::Moved {
            line,
            centre: [mean[0] + shift[0], mean[1] + shift[1]],
            precision: [
                [c[1][1] / det, -c[0][1] / det],
                [-c[1][0] / det, c[0][0] / det],
            ],
            norm: 1.0 / (std::f64::consts::TAU * det.sqrt()),
            mean,
            radius,
            disc: (1.0 - line) / (std::f64::consts::PI * radius * radius).max(f64::MIN_POSITIVE),
        }
    }

    fn density(&self, p: [f64; 2]) -> f64 {
        match *self {
            Self::Uniform(area) => 1.0 / area.max(f64::MIN_POSITIVE),
            Self::Moved {
                line,
                centre,
                precision,
                norm,
                mean,
                radius,
                disc,
            } => {
                let d2 = mahalanobis2(&precision, [p[0] - centre[0], p[1] - centre[1]]);
                let gaussian = line * norm * (-0.5 * d2).exp();
                let (dx, dy) = (p[0] - mean[0], p[1] - mean[1]);
                let inside = dx * dx + dy * dy <= radius * radius;
                gaussian + if inside { disc } else { 0.0 }
            }
        }
    }
}

/// The frame's mixture: g, p̂ and the share β drawn from g.
pub(super) struct Mixture {
    pub(super) guess: Guess,
    pub(super) predicted: Predicted,
    pub(super) share: f64,
}

impl Mixture {
    /// p̂/q at `p`: 1/(1 − β) where g is negligible.
    pub(super) fn correction(&self, p: [f64; 2]) -> f64 {
        let g = self.guess.density(p);
        let keep = 1.0 - self.share;
        if g == 0.0 {
            return 1.0 / keep;
        }
        let predicted = self.predicted.density(p);
        predicted / (keep * predicted + self.share * g)
    }

    /// Multiplies each weight by its p̂/q (`corrections`, from [`Mixture::correction`]) and
    /// normalises; returns the corrected weights' sum (the filter's own predictive likelihood,
    /// up to the weights' scale), `None` (weights untouched) when they sum to nothing.
    pub(super) fn correct(weights: &mut [f64], corrections: &[f64]) -> Option<f64> {
        let mut total = 0.0;
        for (w, c) in weights.iter().zip(corrections) {
            total += w * c;
        }
        if !(total > 0.0 && total.is_finite()) {
            return None;
        }
        for (w, c) in weights.iter_mut().zip(corrections) {
            *w *= c / total;
        }
        Some(total)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn draws_follow_the_covariance_and_the_density_integrates_to_one() {
        let g = Guess::new([1.0, 2.0], [[0.04, 0.01], [0.01, 0.09]]).unwrap();
        // L·Lᵀ is the covariance.
        let l = g.chol;
        assert!((l[0][0] * l[0][0] - 0.04).abs() < 1e-12);
        assert!((l[1][0] * l[0][0] - 0.01).abs() < 1e-12);
        assert!((l[1][0] * l[1][0] + l[1][1] * l[1][1] - 0.09).abs() < 1e-12);
        let h = 0.01;
        let mut total = 0.0;
        for i in -200..200 {
            for j in -200..200 {
                total += g.density([1.0 + h * i as f64, 2.0 + h * j as f64]) * h * h;
            }
        }
        assert!((total - 1.0).abs() < 1e-3, "{total}");
        assert!(Guess::new([0.0, 0.0], [[0.0, 0.0], [0.0, 1.0]]).is_none());
    }

    #[test]
    fn the_correction_is_flat_away_from_the_guess_and_small_where_the_prediction_is_not() {
        let guess = Guess::new([0.0, 0.0], [[1e-4, 0.0], [0.0, 1e-4]]).unwrap();
        let predicted = Predicted::moved(
            [5.0, 0.0],
            [[1e-4, 0.0], [0.0, 1e-4]],
            [0.0; 2],
            0.05,
            1.0,
            0.5,
        );
        let mixture = Mixture {
            guess,
            predicted,
            share: 0.1,
        };
        // Far from g: 1/(1 − β).
        assert!((mixture.correction([5.0, 0.0]) - 1.0 / 0.9).abs() < 1e-12);
        // At g's mean, outside the prediction's reach: nothing (the prediction rules it out).
        assert_eq!(mixture.correction([0.0, 0.0]), 0.0);
        // Within the reach's disc: below 1/(1 − β), above 0.
        let near = Mixture {
            predicted: Predicted::moved(
                [0.5, 0.0],
                [[1e-4, 0.0], [0.0, 1e-4]],
                [0.0; 2],
                0.05,
                1.0,
                0.5,
            ),
            ..mixture
        };
        let c = near.correction([0.0, 0.0]);
        assert!(c > 0.0 && c < 1.0 / 0.9, "{c}");
        let mut weights = vec![0.5, 0.5];
        let corrections: Vec<f64> = [[0.0, 0.0], [0.5, 0.0]]
            .iter()
            .map(|&p| near.correction(p))
            .collect();
        let corrected = Mixture::correct(&mut weights, &corrections).expect("weights left");
        // The filter's own predictive sum: the old weights times p̂/q.
        assert_eq!(corrected, 0.5 * corrections[0] + 0.5 * corrections[1]);
        assert!((weights.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        assert!(weights[0] < weights[1]);
    }
}
