//! The detection score the GP and k-NN share: how far a frame's standardised features lie from
//! those the samples show at the method's answer. Every feature counts alike, whatever weight
//! the method itself gives it, so a corrupted feature it ignores (an occluded tile under the
//! GP's long length scale) or outvotes (salt-and-pepper on a few features among many under
//! k-NN's distance) still shows the frame is unlike any sample near its answer.

use nalgebra::{Matrix3, Vector3};

use super::inputs::scaled_norm;

/// Samples nearest the answer that the local plane goes through (a 3 × 3 block of a mesh).
pub(super) const LOCAL_SAMPLES: usize = 9;

/// The [`LOCAL_SAMPLES`] sample poses nearest `pose` (all when fewer), by a scan: ties to the
/// lower index, in the order the selection leaves them (the GP's, which its figures rest on).
pub(super) fn nearest_by_scan(pose: [f64; 2], poses: &[[f64; 2]]) -> Vec<usize> {
    let mut near: Vec<(f64, usize)> = (poses.iter().enumerate())
        .map(|(i, p)| (squared_distance(*p, pose), i))
        .collect();
    let m = near.len().min(LOCAL_SAMPLES);
    if m == 0 {
        return Vec::new();
    }
    near.select_nth_unstable_by(m - 1, |a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    near[..m].iter().map(|&(_, i)| i).collect()
}

fn squared_distance(p: [f64; 2], q: [f64; 2]) -> f64 {
    (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2)
}

/// The Euclidean norm, over the features `mask` keeps (all when `None`; a mask value of 0
/// drops a missing feature), of the standardised `query` less a plane through the samples
/// `near` (least squares, per feature, in pose offsets from `pose`). `rows` holds the samples'
/// standardised features, row-major, one row per pose of `poses`. Infinite when `near` is empty
/// or the plane cannot be solved; a residual beyond the double range gives its scaled norm.
pub(super) fn plane_distance(
    query: &[f64],
    mask: Option<&[f64]>,
    pose: [f64; 2],
    poses: &[[f64; 2]],
    rows: &[f64],
    near: &[usize],
) -> f64 {
    let dim = query.len();
    if near.is_empty() {
        return f64::INFINITY;
    }
    let offsets: Vec<(Vector3<f64>, usize)> = (near.iter())
        .map(|&i| {
            let u = Vector3::new(1.0, poses[i][0] - pose[0], poses[i][1] - pose[1]);
            (u, i)
        })
        .collect();
    // Normal equations of f ≈ a + b·(p − pose); a little ridge on the slopes keeps them
    // solvable when the poses are collinear (then a is their mean).
    let mut gram = Matrix3::<f64>::zeros();
    for (u, _) in &offsets {
        gram += u * u.transpose();
    }
    gram[(1, 1)] += 1e-9;
    gram[(2, 2)] += 1e-9;
    let Some(inverse) = gram.try_inverse() else {
        return f64::INFINITY;
    };
    let row = inverse.row(0);
    let residuals: Vec<f64> = (0..dim)
        .map(|d| {
            if mask.is_some_and(|m| m[d] == 0.0) {
                return 0.0;
            }
            let mut rhs = Vector3::zeros();
            for (u, i) in &offsets {
                rhs += u * rows[i * dim + d];
            }
            query[d] - row.dot(&rhs.transpose())
        })
        .collect();
    let squares: f64 = residuals.iter().map(|r| r.powi(2)).sum();
    if squares.is_finite() {
        squares.sqrt()
    } else {
        // A frame far beyond the samples overflows the squares: the norm itself.
        scaled_norm(residuals.iter().copied())
    }
}

/// The sample poses in square cells (about two a cell), so that the [`LOCAL_SAMPLES`] nearest
/// a pose cost a few cells, not a scan of every sample (k-NN's frames cost microseconds).
#[derive(Debug, Clone)]
pub(super) struct PoseGrid {
    origin: [f64; 2],
    cell: f64,
    size: [usize; 2],
    /// `items[starts[c]..starts[c + 1]]`: the samples of cell c (row-major), by index.
    starts: Vec<usize>,
    items: Vec<usize>,
}

impl PoseGrid {
    /// The grid of finite `poses`.
    pub(super) fn new(poses: &[[f64; 2]]) -> Self {
        let (lo, hi) = poses.iter().fold(
            ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]),
            |(lo, hi), p| {
                (
                    [lo[0].min(p[0]), lo[1].min(p[1])],
                    [hi[0].max(p[0]), hi[1].max(p[1])],
                )
            },
        );
        let n = poses.len().max(1) as f64;
        let (w, h) = (hi[0] - lo[0], hi[1] - lo[1]);
        // About two samples a cell over the box, and no more cells along a side than samples.
        let cell = (2.0 * w * h / n).sqrt().max(2.0 * w.max(h) / n);
        let cell = if cell > 0.0 && cell.is_finite() {
            cell
        } else {
            1.0
        };
        let origin = if poses.is_empty() { [0.0; 2] } else { lo };
        let size = [w, h].map(|e| {
            if e.is_finite() {
                (e / cell) as usize + 1
            } else {
                1
            }
        });
        let mut grid = Self {
            origin,
            cell,
            size,
            starts: vec![0; size[0] * size[1] + 1],
            items: vec![0; poses.len()],
        };
        let cells: Vec<usize> = poses.iter().map(|p| grid.cell_of(*p)).collect();
        for &c in &cells {
            grid.starts[c + 1] += 1;
        }
        for c in 0..size[0] * size[1] {
            grid.starts[c + 1] += grid.starts[c];
        }
        let mut next = grid.starts.clone();
        for (i, &c) in cells.iter().enumerate() {
            grid.items[next[c]] = i;
            next[c] += 1;
        }
        grid
    }

    /// Column and row of the cell holding `p`, clamped to the grid.
    fn coordinates(&self, p: [f64; 2]) -> [usize; 2] {
        [0, 1].map(|a| {
            let t = ((p[a] - self.origin[a]) / self.cell).floor();
            if t > 0.0 {
                (t as usize).min(self.size[a] - 1)
            } else {
                0
            }
        })
    }

    fn cell_of(&self, p: [f64; 2]) -> usize {
        let [c, r] = self.coordinates(p);
        r * self.size[0] + c
    }

    /// The [`LOCAL_SAMPLES`] of `poses` (the poses the grid was built on) nearest `pose`: the
    /// same samples as [`nearest_by_scan`] (ties to the lower index), by increasing distance.
    /// Rings of cells around the pose's are searched until no cell beyond can hold a nearer one.
    pub(super) fn nearest(&self, pose: [f64; 2], poses: &[[f64; 2]]) -> Vec<usize> {
        let m = poses.len().min(LOCAL_SAMPLES);
        let mut best: Vec<(f64, usize)> = Vec::with_capacity(m + 1);
        let [cx, cy] = self.coordinates(pose).map(|c| c as isize);
        let [nx, ny] = self.size.map(|s| s as isize);
        let key = |a: &(f64, usize), b: &(f64, usize)| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1));
        for r in 0..=nx.max(ny) {
            for y in (cy - r).max(0)..=(cy + r).min(ny - 1) {
                // The ring: every column on its top and bottom rows, the two ends elsewhere.
                let edge = (y - cy).abs() == r;
                let step = if edge { 1 } else { (2 * r).max(1) };
                let mut x = cx - r;
                while x <= cx + r {
                    if (0..nx).contains(&x) {
                        let c = (y * nx + x) as usize;
                        for &i in &self.items[self.starts[c]..self.starts[c + 1]] {
                            let d = (squared_distance(poses[i], pose), i);
                            if best.len() == m && key(&d, &best[m - 1]).is_ge() {
                                continue;
                            }
                            let at = best.partition_point(|b| key(b, &d).is_lt());
                            best.insert(at, d);
                            best.truncate(m);
                        }
                    }
                    x += step;
                }
            }
            if best.len() == m && m > 0 {
                // Any sample outside the searched block lies at least this far (less a margin
                // for the rounding of the cell a pose was put in).
                let gap = [0, 1]
                    .map(|a| {
                        let (c, n) = ([cx, cy][a], [nx, ny][a]);
                        let low = if c - r > 0 {
                            pose[a] - (self.origin[a] + (c - r) as f64 * self.cell)
                        } else {
                            f64::INFINITY
                        };
                        let high = if c + r < n - 1 {
                            self.origin[a] + (c + r + 1) as f64 * self.cell - pose[a]
                        } else {
                            f64::INFINITY
                        };
                        low.min(high)
                    })
                    .into_iter()
                    .fold(f64::INFINITY, f64::min)
                    - 1e-9 * self.cell;
                if gap > 0.0 && best[m - 1].0 < gap * gap {
                    break;
                }
            }
        }
        best.into_iter().map(|(_, i)| i).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn sorted(mut v: Vec<usize>, pose: [f64; 2], poses: &[[f64; 2]]) -> Vec<usize> {
        v.sort_by(|&a, &b| {
            let (da, db) = (
                squared_distance(poses[a], pose),
                squared_distance(poses[b], pose),
            );
            da.total_cmp(&db).then(a.cmp(&b))
        });
        v
    }

    #[test]
    fn the_grid_finds_the_scans_samples_on_meshes_paths_and_lines() {
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let mesh: Vec<[f64; 2]> = (0..400)
            .map(|i| [(i % 20) as f64 - 9.5, (i / 20) as f64 + 38.0])
            .collect();
        let random: Vec<[f64; 2]> = (0..3000)
            .map(|_| [rng.random_range(-9.5..9.5), rng.random_range(38.0..57.0)])
            .collect();
        let line: Vec<[f64; 2]> = (0..50).map(|i| [i as f64 * 0.3, 40.0]).collect();
        let few: Vec<[f64; 2]> = vec![[1.0, 2.0], [1.0, 2.0], [3.0, 5.0]];
        for poses in [&mesh, &random, &line, &few] {
            let grid = PoseGrid::new(poses);
            let mut queries: Vec<[f64; 2]> = poses.iter().step_by(7).copied().collect();
            queries.extend(
                (0..200).map(|_| [rng.random_range(-12.0..12.0), rng.random_range(36.0..60.0)]),
            );
            // Halfway between mesh nodes: ties everywhere.
            queries.extend((0..50).map(|i| [(i % 10) as f64 - 9.0, (i / 10) as f64 + 40.5]));
            for q in queries {
                let scan = sorted(nearest_by_scan(q, poses), q, poses);
                assert_eq!(grid.nearest(q, poses), scan, "{q:?}");
            }
        }
    }
}
