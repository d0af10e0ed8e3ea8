//! The sample poses refined onto a sub-grid (issue 17), so that a velocity prediction can place
//! an estimate between them.
//!
//! Each sample pose stands for the poses nearer to it than to any other sample, within
//! √2/2 × the largest nearest-neighbour distance (a square mesh's cells exactly), capped at
//! [`MAX_REACH_IN_SPACINGS`] typical spacings. A belief over the sample poses extends vacuously
//! onto the points of a sub-grid of [`SUBDIVISIONS`] per typical spacing. Combined by Dempster's
//! rule with a consonant belief whose contour is exp(−|x − x̂|²/2σ²) around a predicted pose x̂,
//! its relative plausibility at a point x of sample s is w(s)·exp(−|x − x̂|²/2σ²): the estimate
//! never leaves the poses the sample weights allow, and a prediction far from them only pulls
//! the estimate to their nearest edge.

/// Sub-grid points per typical spacing (the median nearest-neighbour distance).
pub const SUBDIVISIONS: f64 = 16.0;

/// At most this many sub-grid points: sample poses much closer together than their extent get a
/// coarser sub-grid rather than an unbounded one.
pub const MAX_POINTS: f64 = 4e6;

/// The largest region radius, in typical spacings (an isolated sample does not get a huge cell).
pub const MAX_REACH_IN_SPACINGS: f64 = 4.0;

/// Samples whose weight is below this share of the largest are left out (their points could not
/// move a weighted mean by more than this relative amount).
const NEGLIGIBLE_WEIGHT: f64 = 1e-12;

/// The refinement of a set of sample poses.
#[derive(Debug, Clone)]
pub struct Refinement {
    /// Median distance from a sample to its nearest distinct neighbour.
    spacing: f64,
    /// The lattice: point (i, j) is at `lo + (i + ½, j + ½)·step`.
    lo: [f64; 2],
    step: f64,
    /// The sub-grid points, sample by sample, as runs of a lattice row (j, first i, end i),
    /// in lattice order: a few per sample instead of a few hundred points.
    runs: Vec<[u32; 3]>,
    /// Sample s owns `runs[start[s]..start[s + 1]]`.
    start: Vec<usize>,
}

impl Refinement {
    /// Refines `poses`; `None` without two distinct finite poses.
    pub fn new(poses: &[[f64; 2]]) -> Option<Self> {
        if poses
            .iter()
            .any(|p| !(p[0].is_finite() && p[1].is_finite()))
        {
            return None;
        }
        let nearest = sorted_nearest(poses)?;
        let spacing = nearest[nearest.len() / 2];
        let widest = nearest[nearest.len() - 1];
        let reach = (widest * std::f64::consts::FRAC_1_SQRT_2).min(MAX_REACH_IN_SPACINGS * spacing);
        let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        for p in poses {
            for d in 0..2 {
                lo[d] = lo[d].min(p[d] - reach);
                hi[d] = hi[d].max(p[d] + reach);
            }
        }
        let area = (hi[0] - lo[0]) * (hi[1] - lo[1]);
        let step = (spacing / SUBDIVISIONS).max((area / MAX_POINTS).sqrt());
        // Every sample reaches its nearest lattice point (a sample closer to another than the
        // step may still own none: its weight is then left out of [`Refinement::estimate`]).
        let reach = reach.max(step);
        // The lattice is anchored on the first sample, half a step off it, so that a square
        // mesh's cell borders fall between points.
        for d in 0..2 {
            lo[d] = poses[0][d] - ((poses[0][d] - lo[d]) / step).ceil() * step;
        }
        let size = |d: usize| ((hi[d] - lo[d]) / step).ceil() as usize + 1;
        let (nx, ny) = (size(0), size(1));
        let at = |i: usize, j: usize| {
            [
                lo[0] + (i as f64 + 0.5) * step,
                lo[1] + (j as f64 + 0.5) * step,
            ]
        };
        // Each point goes to its nearest sample within the reach (ties: the lower index). Only
        // the owner is kept: its distance is recomputed, bit for bit, when another sample
        // competes for the point.
        let mut owner: Vec<u32> = vec![u32::MAX; nx * ny];
        let span = (reach / step).ceil() as isize + 1;
        let d2_of = |x: [f64; 2], p: [f64; 2]| (x[0] - p[0]).powi(2) + (x[1] - p[1]).powi(2);
        for (s, p) in poses.iter().enumerate() {
            let (ci, cj) = (
                ((p[0] - lo[0]) / step) as isize,
                ((p[1] - lo[1]) / step) as isize,
            );
            let (i0, i1) = ((ci - span).max(0), (ci + span + 1).min(nx as isize));
            if i0 >= i1 {
                continue;
            }
            for j in (cj - span).max(0)..(cj + span + 1).min(ny as isize) {
                // Along a row the distance only grows away from the pose: the points within
                // the reach are one run, found from the pose outwards (the same points and
                // distances as a scan of the whole row of the box).
                let row = j as usize;
                let mut first_right = ci.clamp(i0, i1 - 1);
                while first_right > i0 && at((first_right - 1) as usize, row)[0] >= p[0] {
                    first_right -= 1;
                }
                while first_right < i1 && at(first_right as usize, row)[0] < p[0] {
                    first_right += 1;
                }
                // Claims point i when within the reach and nearer than its owner; false
                // beyond the reach.
                let mut claim = |i: isize| {
                    let x = at(i as usize, row);
                    let d2 = d2_of(x, *p);
                    if d2 > reach * reach || d2.is_nan() {
                        return false;
                    }
                    let cell = &mut owner[row * nx + i as usize];
                    if *cell == u32::MAX || d2 < d2_of(x, poses[*cell as usize]) {
                        *cell = s as u32;
                    }
                    true
                };
                for i in first_right..i1 {
                    if !claim(i) {
                        break;
                    }
                }
                for i in (i0..first_right).rev() {
                    if !claim(i) {
                        break;
                    }
                }
            }
        }
        let (runs, start) = runs_of(&owner, nx, poses.len());
        Some(Self {
            spacing,
            lo,
            step,
            runs,
            start,
        })
    }

    /// The points of sample `s`, in lattice order.
    fn points(&self, s: usize) -> impl Iterator<Item = [f64; 2]> + '_ {
        let (lo, step) = (self.lo, self.step);
        self.runs[self.start[s]..self.start[s + 1]]
            .iter()
            .flat_map(move |&[j, i0, i1]| {
                let y = lo[1] + (j as f64 + 0.5) * step;
                (i0..i1).map(move |i| [lo[0] + (i as f64 + 0.5) * step, y])
            })
    }

    /// The median distance between a sample pose and its nearest neighbour.
    pub fn spacing(&self) -> f64 {
        self.spacing
    }

    /// The estimate of `weights` over the sample poses combined with a consonant belief of
    /// contour exp(−|x − predicted|²/2σ²), σ = `spread`, on the sub-grid: the weighted mean, or
    /// with `map` the point of highest plausibility (ties: the first). `None` when the weights
    /// do not fit the samples or are nowhere positive on points (the caller keeps the sample
    /// poses' estimate).
    pub fn estimate(
        &self,
        weights: &[f64],
        predicted: [f64; 2],
        spread: f64,
        map: bool,
    ) -> Option<[f64; 2]> {
        if weights.len() + 1 != self.start.len() || !(spread.is_finite() && spread > 0.0) {
            return None;
        }
        let max = weights.iter().copied().fold(0.0f64, f64::max);
        if !(max > 0.0 && max.is_finite()) {
            return None;
        }
        let scale = -0.5 / (spread * spread);
        // ln of each point's plausibility, relative to the largest weight.
        let log_plausibilities = || {
            weights
                .iter()
                .enumerate()
                .filter(move |(_, &w)| w >= max * NEGLIGIBLE_WEIGHT)
                .flat_map(move |(s, &w)| {
                    let lw = (w / max).ln();
                    self.points(s).map(move |x| {
                        let d2 = (x[0] - predicted[0]).powi(2) + (x[1] - predicted[1]).powi(2);
                        (x, lw + scale * d2)
                    })
                })
        };
        // With no point at all, `top` stays −∞ and the estimate is `None`.
        let (best, top) =
            log_plausibilities().fold((None, f64::NEG_INFINITY), |(best, top), (x, l)| {
                if l > top {
                    (Some(x), l)
                } else {
                    (best, top)
                }
            });
        if map {
            return best;
        }
        let (mut sx, mut sy, mut sw) = (0.0, 0.0, 0.0);
        for (x, l) in log_plausibilities() {
            let w = (l - top).exp();
            sx += w * x[0];
            sy += w * x[1];
            sw += w;
        }
        (sw > 0.0).then(|| [sx / sw, sy / sw])
    }
}

/// The variance per axis of the poses a sample pose stands for (mm²): s²/12 for the typical
/// spacing s, a uniform distribution's over a square cell of side s (Sheppard's correction for
/// grouped values); 0 without two distinct finite poses. An estimate on the sample poses adds it to
/// the spread of its weights, which is zero when they sit on one pose.
pub fn cell_variance(poses: &[[f64; 2]]) -> f64 {
    typical_spacing(poses).map_or(0.0, |s| s * s / 12.0)
}

/// The typical spacing of `poses`: the median distance from a pose to its nearest distinct one;
/// `None` without two distinct finite poses.
fn typical_spacing(poses: &[[f64; 2]]) -> Option<f64> {
    if !poses.iter().flatten().all(|v| v.is_finite()) {
        return None;
    }
    let nearest = sorted_nearest(poses)?;
    Some(nearest[nearest.len() / 2])
}

/// The finite nearest-distinct distances of `poses`, ascending; `None` when there is none.
fn sorted_nearest(poses: &[[f64; 2]]) -> Option<Vec<f64>> {
    let mut nearest: Vec<f64> = nearest_distinct(poses)
        .into_iter()
        .filter(|d| d.is_finite())
        .collect();
    nearest.sort_by(f64::total_cmp);
    (!nearest.is_empty()).then_some(nearest)
}

/// Each pose's distance to its nearest pose farther than 1e-9 (∞ without one): the poses
/// scanned outwards in x order, stopping where the x gap alone exceeds the nearest found
/// (a distance is never below its x gap), so each pose meets only its neighbourhood.
fn nearest_distinct(poses: &[[f64; 2]]) -> Vec<f64> {
    let mut order: Vec<usize> = (0..poses.len()).collect();
    order.sort_by(|&a, &b| poses[a][0].total_cmp(&poses[b][0]));
    let mut nearest = vec![f64::INFINITY; poses.len()];
    for (rank, &a) in order.iter().enumerate() {
        let p = poses[a];
        let mut best = f64::INFINITY;
        let mut visit = |b: usize| {
            let q = poses[b];
            if (p[0] - q[0]).abs() > best {
                return false;
            }
            let d = (p[0] - q[0]).hypot(p[1] - q[1]);
            if d > 1e-9 {
                best = best.min(d);
            }
            true
        };
        for &b in &order[rank + 1..] {
            if !visit(b) {
                break;
            }
        }
        for &b in order[..rank].iter().rev() {
            if !visit(b) {
                break;
            }
        }
        nearest[a] = best;
    }
    nearest
}

/// The runs (row j, first i, end i) of each sample's points in the lattice of `nx` columns
/// whose points are owned as `owner` says (`u32::MAX`: nobody), sample by sample in lattice
/// order, and where each sample's runs start.
fn runs_of(owner: &[u32], nx: usize, samples: usize) -> (Vec<[u32; 3]>, Vec<usize>) {
    let starts_run =
        |k: usize| owner[k] != u32::MAX && (k.is_multiple_of(nx) || owner[k - 1] != owner[k]);
    let mut start = vec![0usize; samples + 1];
    for k in (0..owner.len()).filter(|&k| starts_run(k)) {
        start[owner[k] as usize + 1] += 1;
    }
    for s in 0..samples {
        start[s + 1] += start[s];
    }
    let mut runs = vec![[0u32; 3]; start[samples]];
    let mut next = start.clone();
    let mut k = 0;
    while k < owner.len() {
        if !starts_run(k) {
            k += 1;
            continue;
        }
        let (s, j, i0) = (owner[k] as usize, k / nx, k % nx);
        let mut i1 = i0 + 1;
        while i1 < nx && owner[j * nx + i1] == owner[k] {
            i1 += 1;
        }
        runs[next[s]] = [j as u32, i0 as u32, i1 as u32];
        next[s] += 1;
        k = j * nx + i1;
    }
    (runs, start)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mesh() -> Vec<[f64; 2]> {
        (0..4)
            .flat_map(|j| (0..4).map(move |i| [i as f64, j as f64]))
            .collect()
    }

    /// The construction before the runs and the x-ordered scan: every pair of poses, every
    /// point stored.
    fn reference(poses: &[[f64; 2]]) -> Option<(f64, Vec<Vec<[f64; 2]>>)> {
        if poses
            .iter()
            .any(|p| !(p[0].is_finite() && p[1].is_finite()))
        {
            return None;
        }
        let mut nearest: Vec<f64> = poses
            .iter()
            .map(|p| {
                poses
                    .iter()
                    .map(|q| (p[0] - q[0]).hypot(p[1] - q[1]))
                    .filter(|&d| d > 1e-9)
                    .fold(f64::INFINITY, f64::min)
            })
            .filter(|d| d.is_finite())
            .collect();
        if nearest.is_empty() {
            return None;
        }
        nearest.sort_by(f64::total_cmp);
        let spacing = nearest[nearest.len() / 2];
        let widest = nearest[nearest.len() - 1];
        let reach = (widest * std::f64::consts::FRAC_1_SQRT_2).min(MAX_REACH_IN_SPACINGS * spacing);
        let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        for p in poses {
            for d in 0..2 {
                lo[d] = lo[d].min(p[d] - reach);
                hi[d] = hi[d].max(p[d] + reach);
            }
        }
        let area = (hi[0] - lo[0]) * (hi[1] - lo[1]);
        let step = (spacing / SUBDIVISIONS).max((area / MAX_POINTS).sqrt());
        // Every sample reaches its nearest lattice point (a sample closer to another than the
        // step may still own none: its weight is then left out of [`Refinement::estimate`]).
        let reach = reach.max(step);
        // The lattice is anchored on the first sample, half a step off it, so that a square
        // mesh's cell borders fall between points.
        for d in 0..2 {
            lo[d] = poses[0][d] - ((poses[0][d] - lo[d]) / step).ceil() * step;
        }
        let size = |d: usize| ((hi[d] - lo[d]) / step).ceil() as usize + 1;
        let (nx, ny) = (size(0), size(1));
        let at = |i: usize, j: usize| {
            [
                lo[0] + (i as f64 + 0.5) * step,
                lo[1] + (j as f64 + 0.5) * step,
            ]
        };
        // Each point goes to its nearest sample within the reach (ties: the lower index).
        let mut owner: Vec<(u32, f64)> = vec![(u32::MAX, f64::INFINITY); nx * ny];
        let span = (reach / step).ceil() as isize + 1;
        for (s, p) in poses.iter().enumerate() {
            let (ci, cj) = (
                ((p[0] - lo[0]) / step) as isize,
                ((p[1] - lo[1]) / step) as isize,
            );
            for j in (cj - span).max(0)..(cj + span + 1).min(ny as isize) {
                for i in (ci - span).max(0)..(ci + span + 1).min(nx as isize) {
                    let x = at(i as usize, j as usize);
                    let d2 = (x[0] - p[0]).powi(2) + (x[1] - p[1]).powi(2);
                    let cell = &mut owner[j as usize * nx + i as usize];
                    if d2 <= reach * reach && d2 < cell.1 {
                        *cell = (s as u32, d2);
                    }
                }
            }
        }
        let mut count = vec![0usize; poses.len() + 1];
        for &(s, _) in &owner {
            if s != u32::MAX {
                count[s as usize + 1] += 1;
            }
        }
        for s in 0..poses.len() {
            count[s + 1] += count[s];
        }
        let start = count.clone();
        let mut points = vec![[0.0; 2]; start[poses.len()]];
        let mut next = count;
        for (k, &(s, _)) in owner.iter().enumerate() {
            if s != u32::MAX {
                points[next[s as usize]] = at(k % nx, k / nx);
                next[s as usize] += 1;
            }
        }
        Some((
            spacing,
            (0..poses.len())
                .map(|s| points[start[s]..start[s + 1]].to_vec())
                .collect(),
        ))
    }

    #[test]
    fn the_runs_hold_the_direct_construction_bit_for_bit() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let scattered: Vec<[f64; 2]> = (0..150)
            .map(|_| [rng.random_range(-10.0..10.0), rng.random_range(35.0..60.0)])
            .collect();
        let mut duplicated = mesh();
        duplicated.extend([[1.0, 1.0], [2.0, 2.0 + 1e-12], [-3.0, 0.5]]);
        let line: Vec<[f64; 2]> = (0..30).map(|k| [0.0, 0.7 * k as f64]).collect();
        for poses in [mesh(), scattered, duplicated, line] {
            let r = Refinement::new(&poses).unwrap();
            let (spacing, points) = reference(&poses).unwrap();
            assert_eq!(r.spacing(), spacing);
            for (s, expected) in points.iter().enumerate() {
                assert_eq!(&r.points(s).collect::<Vec<_>>(), expected, "sample {s}");
            }
        }
    }

    #[test]
    fn a_square_mesh_refines_into_its_cells() {
        let r = Refinement::new(&mesh()).unwrap();
        assert_eq!(r.spacing(), 1.0);
        // An inner sample owns the unit square around it: 16 × 16 points.
        let s = 5; // pose [1, 1]
        let own: Vec<[f64; 2]> = r.points(s).collect();
        assert_eq!(own.len(), 256);
        assert!(own
            .iter()
            .all(|x| (x[0] - 1.0).abs() < 0.5 && (x[1] - 1.0).abs() < 0.5));
        // A belief on that sample alone, with a prediction at its centre, estimates the centre;
        // a prediction beside it moves the estimate towards it, inside the cell.
        let mut w = vec![0.0; 16];
        w[s] = 1.0;
        let centre = r.estimate(&w, [1.0, 1.0], 0.5, false).unwrap();
        assert!((centre[0] - 1.0).abs() < 1e-9 && (centre[1] - 1.0).abs() < 1e-9);
        let pulled = r.estimate(&w, [1.4, 1.0], 0.3, false).unwrap();
        assert!(pulled[0] > 1.1 && pulled[0] < 1.5, "{pulled:?}");
        assert!((pulled[1] - 1.0).abs() < 1e-9);
        // Far away, it stops at the cell's edge; MAP takes the nearest point.
        let far = r.estimate(&w, [9.0, 1.0], 0.3, true).unwrap();
        assert!((far[0] - (1.5 - 1.0 / 32.0)).abs() < 1e-9, "{far:?}");
        let far_mean = r.estimate(&w, [9.0, 1.0], 0.3, false).unwrap();
        assert!(far_mean[0] > 1.45 && far_mean[0] < 1.5, "{far_mean:?}");
    }

    #[test]
    fn a_broad_prediction_gives_the_weighted_mean_of_the_cells() {
        let r = Refinement::new(&mesh()).unwrap();
        let mut w = vec![0.0; 16];
        w[5] = 1.0;
        w[6] = 1.0; // [2, 1]
        let e = r.estimate(&w, [1.5, 1.0], 1e6, false).unwrap();
        assert!(
            (e[0] - 1.5).abs() < 1e-9 && (e[1] - 1.0).abs() < 1e-9,
            "{e:?}"
        );
    }

    #[test]
    fn close_samples_far_apart_get_a_bounded_sub_grid() {
        // Pairs 1 µm apart, 19 mm between pairs: the spacing alone would ask for 10¹² points.
        let poses = [[0.0, 0.0], [1e-3, 0.0], [19.0, 19.0], [19.0, 19.001]];
        let r = Refinement::new(&poses).unwrap();
        let points: u32 = r.runs.iter().map(|[_, a, b]| b - a).sum();
        assert!(points as f64 <= MAX_POINTS, "{points}");
        let e = r.estimate(&[0.0, 0.0, 1.0, 0.0], [19.0, 19.0], 1.0, false);
        let e = e.unwrap();
        assert!(
            (e[0] - 19.0).abs() < 0.1 && (e[1] - 19.0).abs() < 0.1,
            "{e:?}"
        );
    }

    #[test]
    fn the_typical_spacing_is_the_median_nearest_distance() {
        assert_eq!(typical_spacing(&mesh()), Some(1.0));
        // One outlier far off does not move the median.
        let mut poses = mesh();
        poses.push([100.0, 100.0]);
        assert_eq!(typical_spacing(&poses), Some(1.0));
        assert_eq!(typical_spacing(&[[1.0, 2.0], [1.0, 2.0]]), None);
        assert_eq!(typical_spacing(&[[0.0, 0.0], [f64::NAN, 1.0]]), None);
        assert_eq!(typical_spacing(&[]), None);
        assert_eq!(cell_variance(&mesh()), 1.0 / 12.0);
        assert_eq!(cell_variance(&[[1.0, 2.0]]), 0.0);
    }

    #[test]
    fn bad_inputs_give_none() {
        assert!(Refinement::new(&[[0.0, 0.0]]).is_none());
        assert!(Refinement::new(&[[0.0, 0.0], [0.0, 0.0]]).is_none());
        assert!(Refinement::new(&[[0.0, 0.0], [f64::NAN, 1.0]]).is_none());
        let r = Refinement::new(&mesh()).unwrap();
        assert!(r.estimate(&[1.0; 3], [0.0, 0.0], 0.5, false).is_none());
        assert!(r.estimate(&[0.0; 16], [0.0, 0.0], 0.5, false).is_none());
        assert!(r.estimate(&[1.0; 16], [0.0, 0.0], 0.0, false).is_none());
        assert!(r
            .estimate(&[1.0; 16], [0.0, 0.0], f64::NAN, false)
            .is_none());
    }
}
