//! What the report measures without ground truth: spread, missing and non-finite shares, and
//! the correlation between features.

use super::FeatureEntry;

/// The finite value of a cell (a NaN or infinity counts as no value).
fn finite(cell: Option<f64>) -> Option<f64> {
    cell.filter(|v| v.is_finite())
}

/// One entry per feature with its spread and missing/non-finite shares filled.
pub(super) fn entries(names: &[String], rows: &[Vec<Option<f64>>]) -> Vec<FeatureEntry> {
    let frames = rows.len() as f64;
    names
        .iter()
        .enumerate()
        .map(|(j, name)| {
            let values: Vec<f64> = rows.iter().filter_map(|r| finite(r[j])).collect();
            let missing = rows.iter().filter(|r| r[j].is_none()).count() as f64;
            let non_finite = rows
                .iter()
                .filter(|r| r[j].is_some_and(|v| !v.is_finite()))
                .count() as f64;
            let (mean, sd, min, max) = if values.is_empty() {
                (None, None, None, None)
            } else {
                let count = values.len() as f64;
                let mean = values.iter().sum::<f64>() / count;
                let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / count;
                let min = values.iter().copied().fold(f64::INFINITY, f64::min);
                let max = values.iter().copied().fold(f64::NEG_INFINITY, f64::max);
                (Some(mean), Some(var.sqrt()), Some(min), Some(max))
            };
            FeatureEntry {
                name: name.clone(),
                mean,
                sd,
                min,
                max,
                missing_share: missing / frames,
                non_finite_share: non_finite / frames,
                ..FeatureEntry::default()
            }
        })
        .collect()
}

/// Pearson correlation of every pair over the frames where both are finite; `None` with fewer
/// than 3 such frames or a feature constant over them.
pub(super) fn correlation(rows: &[Vec<Option<f64>>], n: usize) -> Vec<Vec<Option<f64>>> {
    let mut out = vec![vec![None; n]; n];
    for i in 0..n {
        for j in i..n {
            let pairs: Vec<(f64, f64)> = rows
                .iter()
                .filter_map(|r| Some((finite(r[i])?, finite(r[j])?)))
                .collect();
            let r = pearson(&pairs);
            out[i][j] = r;
            out[j][i] = r;
        }
    }
    out
}

fn pearson(pairs: &[(f64, f64)]) -> Option<f64> {
    if pairs.len() < 3 {
        return None;
    }
    let count = pairs.len() as f64;
    let (ma, mb) = pairs
        .iter()
        .fold((0.0, 0.0), |(a, b), (x, y)| (a + x / count, b + y / count));
    let (mut ab, mut aa, mut bb) = (0.0, 0.0, 0.0);
    for (x, y) in pairs {
        ab += (x - ma) * (y - mb);
        aa += (x - ma).powi(2);
        bb += (y - mb).powi(2);
    }
    // A constant (to rounding: the mean's own rounding leaves tiny deviations) has none.
    let (sa, sb) = pairs
        .iter()
        .fold((0.0, 0.0), |(a, b), (x, y)| (a + x * x, b + y * y));
    let r = ab / (aa * bb).sqrt();
    (aa > 1e-20 * sa && bb > 1e-20 * sb && aa > 0.0 && bb > 0.0 && r.is_finite())
        .then(|| r.clamp(-1.0, 1.0))
}

/// Each feature's most correlated other feature (by |r|).
pub(super) fn most_correlated(entries: &mut [FeatureEntry], correlation: &[Vec<Option<f64>>]) {
    let names: Vec<String> = entries.iter().map(|e| e.name.clone()).collect();
    for (i, entry) in entries.iter_mut().enumerate() {
        entry.most_correlated = (0..names.len())
            .filter(|&j| j != i)
            .filter_map(|j| Some((j, correlation[i][j]?)))
            .max_by(|a, b| a.1.abs().total_cmp(&b.1.abs()))
            .map(|(j, r)| (names[j].clone(), r));
    }
}
