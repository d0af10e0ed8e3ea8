//! The information limit: the Cramér–Rao bound of a pose measured by features with Gaussian
//! noise. With feature maps f(q) (their n × 2 Jacobian G at the true pose) and the noise
//! covariance Σ of y − f(q), the Fisher information is I = Gᵀ Σ⁻¹ G and no unbiased estimator
//! has E|q̂ − q|² below tr I⁻¹ (mm²). A leaf: it knows no method; the harness gives it the
//! slopes (the continuous tracker's surrogates) and the residuals (the validation motion's).

use nalgebra::{DMatrix, SymmetricEigen};

#[cfg(test)]
mod tests;

/// Failures while building a noise model.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum InformationError {
    /// A residual row or a noise scale list has the wrong length.
    #[error("a residual row has {found} values for {expected} features")]
    Length {
        /// Features expected.
        expected: usize,
        /// Values found.
        found: usize,
    },
    /// A feature's noise scale is not a positive finite number.
    #[error("feature {feature}'s noise scale is {value}, not a positive finite number")]
    Scale {
        /// The feature's index.
        feature: usize,
        /// The value given.
        value: f64,
    },
    /// No features.
    #[error("no features to measure a noise covariance of")]
    Empty,
}

/// The noise covariance Σ of the features, full (with the correlations measured between them)
/// or diagonal, kept positive definite.
#[derive(Debug, Clone, PartialEq)]
pub struct NoiseModel {
    covariance: DMatrix<f64>,
    /// Σ⁻¹ of every feature at once (the common frame: none missing).
    precision: DMatrix<f64>,
    /// Eigenvalues of the correlation matrix raised to the floor.
    floored: usize,
    /// The floor those eigenvalues were raised to.
    floor: f64,
}

impl NoiseModel {
    /// Independent features with noise scales `sigmas`.
    ///
    /// # Errors
    /// [`InformationError::Empty`], [`InformationError::Scale`].
    pub fn diagonal(sigmas: &[f64]) -> Result<Self, InformationError> {
        check_scales(sigmas)?;
        let covariance = DMatrix::from_diagonal(&nalgebra::DVector::from_iterator(
            sigmas.len(),
            sigmas.iter().map(|s| s * s),
        ));
        Ok(Self::new(covariance, 0, 0.0))
    }

    /// The full covariance of `residuals` (rows of y − f(q_true), a value missing where the
    /// feature was): each variance the given `sigmas[i]²` (the RMS residual the tracker uses),
    /// each correlation the mean of the products over the rows where both features are
    /// present, divided by the two RMS values over those same rows (no common row: 0). So the
    /// diagonal model is the same with every correlation 0.
    ///
    /// A correlation matrix estimated from N rows resolves no direction with a variance much
    /// below 1/N, and pairwise-complete estimates need not be positive definite: its
    /// eigenvalues are raised to 1/N (N the fewest rows any pair shares) before Σ is built.
    ///
    /// # Errors
    /// [`InformationError::Empty`], [`InformationError::Scale`], [`InformationError::Length`].
    pub fn from_residuals(
        sigmas: &[f64],
        residuals: &[Vec<Option<f64>>],
    ) -> Result<Self, InformationError> {
        check_scales(sigmas)?;
        let n = sigmas.len();
        // Per pair: Σ r_i r_j, Σ r_i², Σ r_j², count.
        let mut sums = vec![[0.0f64, 0.0, 0.0, 0.0]; n * n];
        for row in residuals {
            if row.len() != n {
                return Err(InformationError::Length {
                    expected: n,
                    found: row.len(),
                });
            }
            for i in 0..n {
                let Some(a) = row[i].filter(|v| v.is_finite()) else {
                    continue;
                };
                for j in 0..n {
                    if let Some(b) = row[j].filter(|v| v.is_finite()) {
                        let s = &mut sums[i * n + j];
                        s[0] += a * b;
                        s[1] += a * a;
                        s[2] += b * b;
                        s[3] += 1.0;
                    }
                }
            }
        }
        let mut correlation = DMatrix::identity(n, n);
        let mut fewest = f64::INFINITY;
        for i in 0..n {
            for j in 0..n {
                let [ab, aa, bb, count] = sums[i * n + j];
                fewest = fewest.min(count);
                if i != j && aa > 0.0 && bb > 0.0 {
                    correlation[(i, j)] = (ab / (aa * bb).sqrt()).clamp(-1.0, 1.0);
                }
            }
        }
        let floor = if fewest >= 1.0 { 1.0 / fewest } else { 1.0 };
        let eigen = SymmetricEigen::new(correlation);
        let floored = eigen.eigenvalues.iter().filter(|&&l| l < floor).count();
        let raised = eigen.eigenvalues.map(|l| l.max(floor));
        let correlation =
            &eigen.eigenvectors * DMatrix::from_diagonal(&raised) * eigen.eigenvectors.transpose();
        let covariance = DMatrix::from_fn(n, n, |i, j| {
            // Back to unit diagonal, so that each σ_i stays the tracker's.
            let r = correlation[(i, j)] / (correlation[(i, i)] * correlation[(j, j)]).sqrt();
            r * sigmas[i] * sigmas[j]
        });
        Ok(Self::new(covariance, floored, floor))
    }

    fn new(covariance: DMatrix<f64>, floored: usize, floor: f64) -> Self {
        let n = covariance.nrows();
        // Positive definite by construction; the identity only if rounding says otherwise.
        let precision = covariance
            .clone()
            .cholesky()
            .map_or_else(|| DMatrix::identity(n, n), |c| c.inverse());
        Self {
            covariance,
            precision,
            floored,
            floor,
        }
    }

    /// Number of features.
    pub fn dim(&self) -> usize {
        self.covariance.nrows()
    }

    /// Σ (raw feature units squared).
    pub fn covariance(&self) -> &DMatrix<f64> {
        &self.covariance
    }

    /// How many eigenvalues of the measured correlation matrix were raised, and to what.
    pub fn floored(&self) -> (usize, f64) {
        (self.floored, self.floor)
    }

    /// The Fisher information I = G_Pᵀ Σ_PP⁻¹ G_P of the features `present` (P), with
    /// `jacobian[i]` = (∂f_i/∂x, ∂f_i/∂y) at the true pose, as (I_xx, I_xy, I_yy). A missing
    /// feature leaves the sum: its rows and columns of Σ go, the rest keep their correlations.
    ///
    /// # Panics
    /// Never: lengths other than [`NoiseModel::dim`] give `None`.
    pub fn information(&self, jacobian: &[[f64; 2]], present: &[bool]) -> Option<[f64; 3]> {
        let n = self.dim();
        if jacobian.len() != n || present.len() != n {
            return None;
        }
        let kept: Vec<usize> = (0..n)
            .filter(|&i| present[i] && jacobian[i].iter().all(|g| g.is_finite()))
            .collect();
        if kept.is_empty() {
            return None;
        }
        let quadratic = |m: &DMatrix<f64>, at: &dyn Fn(usize) -> usize| {
            let mut info = [0.0; 3];
            for (a, &i) in kept.iter().enumerate() {
                for (b, &j) in kept.iter().enumerate() {
                    let w = m[(at(a), at(b))];
                    let (gi, gj) = (jacobian[i], jacobian[j]);
                    info[0] += gi[0] * w * gj[0];
                    info[1] += gi[0] * w * gj[1];
                    info[2] += gi[1] * w * gj[1];
                }
            }
            info
        };
        let full = quadratic(&self.precision, &|a| kept[a]);
        if kept.len() == n {
            return Some(full);
        }
        let gone: Vec<usize> = (0..n).filter(|i| !kept.contains(i)).collect();
        if gone.len() > kept.len() {
            let block = self.covariance.select_rows(&kept).select_columns(&kept);
            let precision = block.cholesky()?.inverse();
            return Some(quadratic(&precision, &|a| a));
        }
        // Few gone (M): (Σ_PP)⁻¹ = Λ_PP − Λ_PM Λ_MM⁻¹ Λ_MP with Λ = Σ⁻¹ cached, so only an
        // M × M system is solved: O(n²M) instead of a fresh factorisation, O(n³).
        let mut projected = DMatrix::zeros(gone.len(), 2);
        for (a, &m) in gone.iter().enumerate() {
            for &j in &kept {
                let w = self.precision[(m, j)];
                projected[(a, 0)] += w * jacobian[j][0];
                projected[(a, 1)] += w * jacobian[j][1];
            }
        }
        let corner = self.precision.select_rows(&gone).select_columns(&gone);
        let solved = corner.cholesky()?.solve(&projected);
        let drop = projected.transpose() * solved;
        Some([
            full[0] - drop[(0, 0)],
            full[1] - drop[(0, 1)],
            full[2] - drop[(1, 1)],
        ])
    }

    /// The bound tr I⁻¹ (mm²) of the features `present`; `None` when I is singular (fewer
    /// than two features, or slopes all along one line: a curve of poses fits equally well).
    pub fn bound(&self, jacobian: &[[f64; 2]], present: &[bool]) -> Option<f64> {
        trace_of_inverse(self.information(jacobian, present)?)
    }
}

/// Relative size of det I below which I counts as singular (one feature gives det ≈ 0 up to
/// rounding, about 1e-16 of I_xx·I_yy).
const SINGULAR: f64 = 1e-10;

/// tr I⁻¹ of a symmetric 2 × 2 (I_xx, I_xy, I_yy); `None` when it is singular or not positive.
pub fn trace_of_inverse([xx, xy, yy]: [f64; 3]) -> Option<f64> {
    let det = xx * yy - xy * xy;
    let value = (xx + yy) / det;
    (xx > 0.0 && yy > 0.0 && det > SINGULAR * xx * yy && value.is_finite()).then_some(value)
}

fn check_scales(sigmas: &[f64]) -> Result<(), InformationError> {
    if sigmas.is_empty() {
        return Err(InformationError::Empty);
    }
    match sigmas.iter().position(|s| !(s.is_finite() && *s > 0.0)) {
        Some(feature) => Err(InformationError::Scale {
            feature,
            value: sigmas[feature],
        }),
        None => Ok(()),
    }
}
