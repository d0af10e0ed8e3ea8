//! What needs ground truth: σ from the held-out residuals of the continuous tracker's feature
//! maps, each feature's Fisher information over a grid of the workspace and what leaving it out
//! costs the Cramér–Rao limit, and the neighbour separation of §3.1 (condition 2).

use crate::adaptive::{neighbour_pairs, neighbour_radius};
use crate::estimator::{Continuous, ContinuousSettings, Labelled, TrainingSet};
use crate::information::NoiseModel;
use crate::planar::Rect;

use super::{FeatureEntry, FeatureReport, FeatureReportError, Grid, Inputs};

/// Most poses the neighbour separation is measured on (its pairs cost O(n²)).
const MAX_NEIGHBOUR_POSES: usize = 5000;

/// Fewest held-out frames inside a feature's range that σ is measured on.
const MIN_INSIDE: usize = 5;

/// The frames the maps and methods are fitted on and those σ and errors are measured on.
pub(super) struct Split {
    pub fit_poses: Vec<[f64; 2]>,
    pub fit_rows: Vec<Vec<Option<f64>>>,
    pub held_poses: Vec<[f64; 2]>,
    pub held_rows: Vec<Vec<Option<f64>>>,
    from_validation: bool,
    /// The error a held-out frame without an estimate counts as (mm): the workspace diagonal.
    pub missing_penalty: f64,
}

impl Split {
    /// Even frames to fit, odd ones held out; or every frame to fit and the validation dataset
    /// held out.
    pub fn new(inputs: &Inputs<'_>, poses: &[[f64; 2]]) -> Result<Self, FeatureReportError> {
        let rect = workspace(inputs.workspace, poses);
        let missing_penalty = (rect.x_max - rect.x_min).hypot(rect.y_max - rect.y_min);
        if let Some(Labelled {
            poses: held_poses,
            rows: held_rows,
        }) = inputs.validation
        {
            let n = inputs.names.len();
            if held_rows.is_empty() || held_poses.len() != held_rows.len() {
                return Err(FeatureReportError::Input(
                    "the validation dataset has no frames with ground truth".into(),
                ));
            }
            if let Some(i) = held_rows.iter().position(|r| r.len() != n) {
                return Err(FeatureReportError::Input(format!(
                    "validation frame {i} has {} feature values for {n} features",
                    held_rows[i].len()
                )));
            }
            return Ok(Self {
                fit_poses: poses.to_vec(),
                fit_rows: inputs.rows.to_vec(),
                held_poses: held_poses.to_vec(),
                held_rows: held_rows.to_vec(),
                from_validation: true,
                missing_penalty,
            });
        }
        if poses.len() < 4 {
            return Err(FeatureReportError::Input(format!(
                "{} frames with ground truth: the report fits on the even frames and measures on \
                 the odd ones, so it needs at least 4 (or give --validation)",
                poses.len()
            )));
        }
        let pick = |parity: usize| {
            let poses: Vec<[f64; 2]> = poses.iter().skip(parity).step_by(2).copied().collect();
            let rows: Vec<_> = inputs
                .rows
                .iter()
                .skip(parity)
                .step_by(2)
                .cloned()
                .collect();
            (poses, rows)
        };
        let (fit_poses, fit_rows) = pick(0);
        let (held_poses, held_rows) = pick(1);
        Ok(Self {
            fit_poses,
            fit_rows,
            held_poses,
            held_rows,
            from_validation: false,
            missing_penalty,
        })
    }

    /// One line for the report.
    pub fn describe(&self) -> String {
        if self.from_validation {
            format!(
                "fitted on every frame ({}), σ and errors on the {} validation frames",
                self.fit_poses.len(),
                self.held_poses.len()
            )
        } else {
            format!(
                "fitted on the {} even frames, σ and errors on the {} odd frames",
                self.fit_poses.len(),
                self.held_poses.len()
            )
        }
    }
}

/// The declared workspace, else the poses' bounding box.
fn workspace(declared: Option<Rect>, poses: &[[f64; 2]]) -> Rect {
    declared.unwrap_or_else(|| {
        let fold = |k: usize| {
            poses
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| {
                    (a.min(p[k]), b.max(p[k]))
                })
        };
        let ((x_min, x_max), (y_min, y_max)) = (fold(0), fold(1));
        Rect {
            x_min,
            x_max,
            y_min,
            y_max,
        }
    })
}

/// Whether a feature is constant over the report's frames (to rounding).
fn constant(entry: &FeatureEntry) -> bool {
    match (entry.min, entry.max) {
        (Some(lo), Some(hi)) => hi - lo <= 1e-12 * lo.abs().max(hi.abs()),
        _ => true,
    }
}

/// Fills σ, the information shares and maps, the limit's increases and the grid; what cannot be
/// measured goes to `notes`.
pub(super) fn fill(
    report: &mut FeatureReport,
    inputs: &Inputs<'_>,
    split: &Split,
    points: usize,
    notes: &mut Vec<String>,
) {
    let names = inputs.names;
    let n = names.len();
    let training = TrainingSet {
        missing_penalty: split.missing_penalty,
        ..TrainingSet::new(
            names,
            Labelled {
                poses: &split.fit_poses,
                rows: &split.fit_rows,
            },
        )
    };
    let continuous = match Continuous::fit(&ContinuousSettings::default(), &training) {
        Ok(c) => c,
        Err(e) => {
            notes.push(format!(
                "no feature maps (so no σ or information): the continuous tracker's fit: {e}"
            ));
            return;
        }
    };
    // σ: the RMS of the held-out residuals.
    let residuals: Vec<Vec<Option<f64>>> = (split.held_poses.iter().zip(&split.held_rows))
        .map(|(&q, row)| {
            let f = continuous.feature_map(q);
            (row.iter().zip(&f))
                .map(|(y, fi)| y.filter(|y| y.is_finite()).map(|y| y - fi))
                .collect()
        })
        .collect();
    let mut usable = Vec::new();
    let mut sigmas = Vec::new();
    for (i, entry) in report.features.iter_mut().enumerate() {
        // Only frames where the value lies inside its range: a feature held at a bound (a tile
        // the arm is not in reads exactly 0) has no noise there, and those frames would make σ
        // tiny and the information where it varies huge.
        let inside = |y: f64| {
            entry
                .min
                .zip(entry.max)
                .is_none_or(|(lo, hi)| y > lo && y < hi)
        };
        let r: Vec<f64> = (residuals.iter().zip(&split.held_rows))
            .filter_map(|(res, row)| row[i].filter(|&y| inside(y)).and(res[i]))
            .collect();
        let sigma = if r.len() >= MIN_INSIDE {
            (r.iter().map(|v| v * v).sum::<f64>() / r.len() as f64).sqrt()
        } else if residuals.iter().any(|row| row[i].is_some()) {
            // Too few held-out frames where it varies: the maps' own leave-one-out scale.
            notes.push(format!(
                "`{}`: {} held-out frames inside its range; σ is the feature map's \
                 leave-one-out residual on the fitted frames",
                entry.name,
                r.len()
            ));
            continuous.residual_scales()[i]
        } else {
            continue;
        };
        entry.sigma = Some(sigma);
        if sigma > 0.0 && !constant(entry) {
            usable.push(i);
            sigmas.push(sigma);
        }
    }
    if usable.is_empty() {
        notes.push("no feature varies with a measurable σ: no information".into());
        return;
    }
    let kept: Vec<Vec<Option<f64>>> = residuals
        .iter()
        .map(|row| usable.iter().map(|&i| row[i]).collect())
        .collect();
    let model = match NoiseModel::from_residuals(&sigmas, &kept) {
        Ok(m) => m,
        Err(e) => {
            notes.push(format!("no noise model: {e}"));
            return;
        }
    };
    let rect = workspace(inputs.workspace, inputs.poses.unwrap_or(&split.fit_poses));
    let axis = |lo: f64, hi: f64| -> Vec<f64> {
        (0..points)
            .map(|k| lo + (k as f64 + 0.5) * (hi - lo) / points as f64)
            .collect()
    };
    let grid = Grid {
        x: axis(rect.x_min, rect.x_max),
        y: axis(rect.y_min, rect.y_max),
    };
    let mut maps = vec![Vec::with_capacity(points * points); n];
    let (mut values, mut slopes) = (vec![0.0; n], vec![[0.0; 2]; n]);
    let m = usable.len();
    let all = vec![true; m];
    // Per usable feature: Σ bound without it, Σ bound with all on the same points, points
    // where it is singular without it.
    let mut without = vec![(0.0f64, 0.0f64, 0usize); m];
    let (mut bound_sum, mut bound_points) = (0.0, 0usize);
    for &y in &grid.y {
        for &x in &grid.x {
            continuous.feature_slopes_into([x, y], &mut values, &mut slopes);
            for (i, map) in maps.iter_mut().enumerate() {
                let own = usable.iter().position(|&u| u == i).map_or(0.0, |k| {
                    (slopes[i][0].powi(2) + slopes[i][1].powi(2)) / sigmas[k].powi(2)
                });
                map.push(own);
            }
            let jacobian: Vec<[f64; 2]> = usable.iter().map(|&i| slopes[i]).collect();
            let Some(full) = model.bound(&jacobian, &all) else {
                continue;
            };
            bound_sum += full;
            bound_points += 1;
            for (k, w) in without.iter_mut().enumerate() {
                let mut present = all.clone();
                present[k] = false;
                match model.bound(&jacobian, &present) {
                    Some(b) => {
                        w.0 += b;
                        w.1 += full;
                    }
                    None => w.2 += 1,
                }
            }
        }
    }
    if bound_points > 0 {
        report.limit_rms = Some((bound_sum / bound_points as f64).sqrt());
    } else {
        notes.push("the information is singular everywhere on the grid: no limit".into());
    }
    let totals: Vec<f64> = maps.iter().map(|m| m.iter().sum()).collect();
    let total: f64 = totals.iter().sum();
    for (i, entry) in report.features.iter_mut().enumerate() {
        if entry.sigma.is_none() {
            continue;
        }
        entry.information_share = (total > 0.0).then(|| totals[i] / total);
        entry.information_map = Some(maps[i].clone());
        match usable.iter().position(|&u| u == i) {
            Some(k) if bound_points > 0 => {
                let (b, full, singular) = without[k];
                entry.singular_without = Some(singular as f64 / bound_points as f64);
                entry.limit_increase = (full > 0.0 && b > 0.0).then(|| (b / full).sqrt() - 1.0);
            }
            // Neither a constant feature nor one without slope changes the limit.
            None if bound_points > 0 => {
                entry.singular_without = Some(0.0);
                entry.limit_increase = Some(0.0);
            }
            _ => {}
        }
    }
    report.grid = Some(grid);
}

/// The neighbour separation of §3.1 (condition 2) over the dataset's neighbouring poses.
pub(super) fn neighbours(
    entries: &mut [FeatureEntry],
    poses: &[[f64; 2]],
    rows: &[Vec<Option<f64>>],
    notes: &mut Vec<String>,
) {
    if poses.len() > MAX_NEIGHBOUR_POSES {
        notes.push(format!(
            "no neighbour separation: {} poses (its pairs cost O(n²); at most {MAX_NEIGHBOUR_POSES})",
            poses.len()
        ));
        return;
    }
    let pairs = match neighbour_radius(poses) {
        Ok(radius) => neighbour_pairs(poses, radius),
        Err(e) => {
            notes.push(format!("no neighbour separation: {e}"));
            return;
        }
    };
    for (j, entry) in entries.iter_mut().enumerate() {
        let changes: Vec<f64> = pairs
            .iter()
            .filter_map(|&(a, b)| {
                let (x, y) = (rows[a][j]?, rows[b][j]?);
                let d = (x - y).abs();
                d.is_finite().then_some(d)
            })
            .collect();
        if changes.is_empty() {
            continue;
        }
        let range = entry.max.zip(entry.min).map_or(0.0, |(hi, lo)| hi - lo);
        let largest = changes.iter().copied().fold(0.0, f64::max);
        entry.neighbour_max_change = Some(if constant(entry) {
            0.0
        } else {
            largest / range
        });
        if let Some(sigma) = entry.sigma.filter(|&s| s > 0.0 && !constant(entry)) {
            let mut scaled: Vec<f64> = changes.iter().map(|d| d / sigma).collect();
            scaled.sort_by(f64::total_cmp);
            let k = scaled.len();
            let median = if k % 2 == 1 {
                scaled[k / 2]
            } else {
                0.5 * (scaled[k / 2 - 1] + scaled[k / 2])
            };
            entry.neighbour_median_sigmas = Some(median);
        }
    }
}
