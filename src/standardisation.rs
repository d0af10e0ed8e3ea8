//! Per-feature centring and scaling, fitted on samples and stored in model files: what the
//! baselines and the continuous tracker's feature maps measure their inputs in. A leaf.

use serde::{Deserialize, Serialize};

/// How many standard deviations from the mean a loaded sample may lie: fitted on n samples they
/// lie within √n (at most 317 for the 100,000 an adaptive trajectory may hold).
pub const MAX_STANDARDISED: f64 = 1e6;

/// Per-feature centring and scaling fitted on the samples: `z = (x − mean) / scale`, the scale
/// being the (population) standard deviation, or 1 for a feature constant on the samples.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Standardisation {
    /// Mean of each feature on the samples.
    pub means: Vec<f64>,
    /// Standard deviation of each feature (1 when constant).
    pub scales: Vec<f64>,
}

impl Standardisation {
    /// Fits on `rows` (at least one, all of the same length `dim`, all finite).
    pub fn fit(rows: &[Vec<f64>], dim: usize) -> Self {
        let n = rows.len().max(1) as f64;
        let mut means = vec![0.0; dim];
        let mut scales = vec![1.0; dim];
        for d in 0..dim {
            let column = rows.iter().map(|r| r[d]);
            let mean = column.clone().sum::<f64>() / n;
            let (lo, hi) = column
                .clone()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), x| {
                    (lo.min(x), hi.max(x))
                });
            // Exactly constant rather than a tiny rounding std, which would blow it up.
            if hi > lo {
                let var = column.map(|x| (x - mean) * (x - mean)).sum::<f64>() / n;
                // A subnormal scale would overflow every standardised value.
                if var.sqrt() >= f64::MIN_POSITIVE {
                    scales[d] = var.sqrt();
                }
            }
            means[d] = mean;
        }
        Self { means, scales }
    }

    /// The standardised value of feature `d`.
    pub fn apply(&self, d: usize, x: f64) -> f64 {
        (x - self.means[d]) / self.scales[d]
    }

    /// The standardised rows, flat (row-major).
    pub fn apply_rows(&self, rows: &[Vec<f64>]) -> Vec<f64> {
        rows.iter()
            .flat_map(|r| r.iter().enumerate().map(|(d, &x)| self.apply(d, x)))
            .collect()
    }

    /// Checks a loaded standardisation for `dim` features (`field` names it): what is wrong.
    pub fn check(&self, dim: usize, field: &str) -> Result<(), String> {
        for (name, values) in [("means", &self.means), ("scales", &self.scales)] {
            if values.len() != dim {
                return Err(format!(
                    "`{field}.{name}` has {} values where {dim} are expected",
                    values.len()
                ));
            }
            if let Some(i) = values.iter().position(|v| !v.is_finite()) {
                return Err(format!("`{field}.{name}[{i}]` is not finite"));
            }
        }
        if let Some(d) = self.scales.iter().position(|&s| s <= 0.0) {
            return Err(format!("`{field}.scales[{d}]` is not positive"));
        }
        if let Some(d) = self.scales.iter().position(|&s| s < f64::MIN_POSITIVE) {
            return Err(format!(
                "`{field}.scales[{d}]` is {:e}, below the smallest normal number {:e}: every \
                 standardised value would overflow",
                self.scales[d],
                f64::MIN_POSITIVE
            ));
        }
        Ok(())
    }

    /// Checks that the loaded `rows` (the file's `rows_field`) lie within
    /// [`MAX_STANDARDISED`] standard deviations of the means once standardised: a fitted file's
    /// samples lie within √n of them, and values far beyond overflow the distances and kernels
    /// computed from them. Call after [`Self::check`].
    pub fn check_rows<R: AsRef<[f64]>>(
        &self,
        rows: &[R],
        rows_field: &str,
        field: &str,
    ) -> Result<(), String> {
        for (i, row) in rows.iter().enumerate() {
            for (d, &x) in row.as_ref().iter().enumerate().take(self.means.len()) {
                let z = self.apply(d, x);
                if z.is_nan() || z.abs() > MAX_STANDARDISED {
                    return Err(format!(
                        "`{rows_field}[{i}][{d}]` is {z:e} standard deviations from \
                         `{field}.means[{d}]` (at most {MAX_STANDARDISED:e}; a fitted file's \
                         samples lie within √n): a mean, scale or sample value is corrupted"
                    ));
                }
            }
        }
        Ok(())
    }
}
