//! A region quantile per part of the workspace (`[confidence] cells`): Mondrian split-conformal
//! prediction. The calibration frames are sorted into the cells of an nx × ny grid over the
//! workspace by where the method's *estimate* fell (the truth is unknown at test time), and each
//! cell takes the quantile of its own frames' scores; a test frame's region uses the quantile of
//! its estimate's cell. If the frames within a cell are exchangeable, the regions hold the truth
//! with at least the nominal share in every cell, not only over all frames (Vovk et al.,
//! Mondrian conformal prediction). A cell with fewer than [`MIN_CELL_FRAMES`] calibration frames
//! keeps the global quantile.

use serde::{Deserialize, Serialize};

use super::conformal_quantile;
use crate::planar::Rect;

/// A cell needs this many calibration frames for a quantile of its own: at 90 % coverage the
/// 19th of 20 scores, so one frame more or less moves it by a rank, not by the tail.
pub const MIN_CELL_FRAMES: usize = 20;

/// The largest grid side: cells of about a millimetre on the 19 mm workspace.
pub const MAX_CELLS: usize = 20;

/// The per-cell quantiles of a calibration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CellRadii {
    /// The grid: cells along x and along y.
    pub cells: [usize; 2],
    /// Row by row from (x_min, y_min), x fastest: the quantile of the calibration frames whose
    /// estimate fell in the cell (`None`: too few frames, so the global radius serves).
    pub radii: Vec<Option<f64>>,
    /// The calibration frames each cell held, in the same order.
    pub frames: Vec<usize>,
}

/// Checks a grid's size: a sentence naming the field otherwise.
pub(super) fn check_cells(cells: [usize; 2]) -> Result<(), String> {
    if cells.iter().all(|&n| (1..=MAX_CELLS).contains(&n)) {
        Ok(())
    } else {
        Err(format!(
            "`confidence.cells` is {cells:?}: each side must be 1 to {MAX_CELLS}"
        ))
    }
}

/// The cell of `p` in the `cells` grid over `workspace` (a pose outside it counts in the nearest
/// cell); `None` for a pose that is not finite.
fn cell_of(cells: [usize; 2], workspace: &Rect, p: [f64; 2]) -> Option<usize> {
    let index = |v: f64, lo: f64, hi: f64, n: usize| {
        let t = ((v - lo) / (hi - lo) * n as f64).floor();
        (t.max(0.0) as usize).min(n - 1)
    };
    p.iter().all(|v| v.is_finite()).then(|| {
        let ix = index(p[0], workspace.x_min, workspace.x_max, cells[0]);
        let iy = index(p[1], workspace.y_min, workspace.y_max, cells[1]);
        iy * cells[0] + ix
    })
}

impl CellRadii {
    /// Each cell's quantile at `coverage` of the `scores` whose `estimates` fell in it.
    pub(super) fn learn(
        cells: [usize; 2],
        workspace: &Rect,
        estimates: &[Option<[f64; 2]>],
        scores: &[f64],
        coverage: f64,
    ) -> Self {
        let mut by_cell = vec![Vec::new(); cells[0] * cells[1]];
        for (pose, &score) in estimates.iter().zip(scores) {
            if let Some(cell) = pose.and_then(|p| cell_of(cells, workspace, p)) {
                by_cell[cell].push(score);
            }
        }
        Self {
            cells,
            radii: (by_cell.iter())
                .map(|s| match s.len() >= MIN_CELL_FRAMES {
                    true => conformal_quantile(s, coverage),
                    false => None,
                })
                .collect(),
            frames: by_cell.iter().map(Vec::len).collect(),
        }
    }

    /// The quantile of `pose`'s cell, `None` where the cell has none of its own.
    pub(super) fn radius_at(&self, workspace: &Rect, pose: [f64; 2]) -> Option<f64> {
        cell_of(self.cells, workspace, pose)
            .and_then(|cell| self.radii.get(cell).copied().flatten())
    }

    /// Checks a grid read from a file: its size, one radius and count per cell, radii positive.
    pub(super) fn check(&self) -> Result<(), String> {
        check_cells(self.cells).map_err(|e| format!("`calibration.cell_radii`: {e}"))?;
        let n = self.cells[0] * self.cells[1];
        if self.radii.len() != n || self.frames.len() != n {
            return Err(format!(
                "`calibration.cell_radii` has {} radii and {} counts for {n} cells",
                self.radii.len(),
                self.frames.len()
            ));
        }
        match self
            .radii
            .iter()
            .flatten()
            .find(|q| !(q.is_finite() && **q > 0.0))
        {
            Some(q) => Err(format!(
                "`calibration.cell_radii` holds {q}: each radius must be a positive number"
            )),
            None => Ok(()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn workspace() -> Rect {
        Rect {
            x_min: -10.0,
            x_max: 10.0,
            y_min: 40.0,
            y_max: 60.0,
        }
    }

    #[test]
    fn poses_fall_in_their_cell_and_outside_poses_in_the_nearest() {
        let w = workspace();
        assert_eq!(cell_of([2, 2], &w, [-5.0, 45.0]), Some(0));
        assert_eq!(cell_of([2, 2], &w, [5.0, 45.0]), Some(1));
        assert_eq!(cell_of([2, 2], &w, [-5.0, 55.0]), Some(2));
        assert_eq!(cell_of([2, 2], &w, [5.0, 55.0]), Some(3));
        assert_eq!(cell_of([2, 2], &w, [-30.0, 100.0]), Some(2));
        assert_eq!(cell_of([2, 2], &w, [10.0, 60.0]), Some(3));
        assert_eq!(cell_of([2, 2], &w, [f64::NAN, 50.0]), None);
        assert_eq!(cell_of([1, 1], &w, [3.0, 41.0]), Some(0));
    }

    #[test]
    fn each_cell_takes_its_own_quantile_or_none_with_too_few_frames() {
        let w = workspace();
        // 40 frames left (scores 1..=40), 5 right, one without an estimate.
        let mut estimates = Vec::new();
        let mut scores = Vec::new();
        for k in 1..=40 {
            estimates.push(Some([-5.0, 50.0]));
            scores.push(k as f64);
        }
        for k in 1..=5 {
            estimates.push(Some([5.0, 50.0]));
            scores.push(100.0 * k as f64);
        }
        estimates.push(None);
        scores.push(f64::INFINITY);
        let cells = CellRadii::learn([2, 1], &w, &estimates, &scores, 0.9);
        // ⌈41 · 0.9⌉ = 37th of the left cell's 40.
        assert_eq!(cells.radii, vec![Some(37.0), None]);
        assert_eq!(cells.frames, vec![40, 5]);
        assert_eq!(cells.radius_at(&w, [-1.0, 41.0]), Some(37.0));
        assert_eq!(cells.radius_at(&w, [1.0, 41.0]), None);
        assert!(cells.check().is_ok());
    }

    #[test]
    fn a_grid_from_a_file_is_checked() {
        let good = CellRadii {
            cells: [2, 1],
            radii: vec![Some(1.0), None],
            frames: vec![30, 3],
        };
        assert!(good.check().is_ok());
        let short = CellRadii {
            radii: vec![Some(1.0)],
            ..good.clone()
        };
        assert!(short.check().unwrap_err().contains("1 radii and 2 counts"));
        let negative = CellRadii {
            radii: vec![Some(-1.0), None],
            ..good.clone()
        };
        assert!(negative.check().unwrap_err().contains("positive"));
        let big = CellRadii {
            cells: [21, 1],
            ..good
        };
        assert!(big.check().unwrap_err().contains("1 to 20"));
        assert!(check_cells([0, 2]).is_err());
        assert!(check_cells([4, 4]).is_ok());
    }
}
