//! Per-feature centring and scaling, fitted on samples and stored in model files: what the
//! baselines and the continuous tracker's feature maps measure their inputs in. A leaf.

use serde::{Deserialize, Serialize};

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
                if var.sqrt() > 0.0 {
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
        Ok(())
    }
}
