//! The carried contour's dilation (the temporal evidential tracker's motion model): π′(p) =
//! max {π(q) : |q + shift − p| ≤ reach} over the sample poses, with the poses in square buckets
//! so that each pose looks only at the buckets its disc overlaps. A max does not depend on the
//! order it is taken in and every distance is computed as by the direct scan, so the result is
//! bit-identical to it.

/// The sample poses in square buckets of a fixed side.
#[derive(Debug, Clone)]
pub struct PoseBuckets {
    poses: Vec<[f64; 2]>,
    origin: [f64; 2],
    side: f64,
    size: [usize; 2],
    /// Bucket b holds `members[start[b]..start[b + 1]]` (pose indices, ascending).
    start: Vec<usize>,
    members: Vec<u32>,
    /// The members' coordinates, in bucket order.
    xs: Vec<f64>,
    ys: Vec<f64>,
    /// Each bucket's box around its members ([x0, x1, y0, y1]; empty buckets never looked at).
    boxes: Vec<[f64; 4]>,
}

/// About this many poses per bucket.
const POSES_PER_BUCKET: f64 = 4.0;

/// At most this many buckets per axis.
const MAX_BUCKETS: usize = 1024;

impl PoseBuckets {
    /// Buckets for `poses` (finite or not: a pose that is not finite goes to bucket 0 and is
    /// compared as by the direct scan).
    pub fn new(poses: &[[f64; 2]]) -> Self {
        let finite = || {
            poses
                .iter()
                .filter(|p| p[0].is_finite() && p[1].is_finite())
        };
        let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        for p in finite() {
            for d in 0..2 {
                lo[d] = lo[d].min(p[d]);
                hi[d] = hi[d].max(p[d]);
            }
        }
        if lo[0] > hi[0] {
            (lo, hi) = ([0.0; 2], [0.0; 2]);
        }
        let area = ((hi[0] - lo[0]) * (hi[1] - lo[1])).max(0.0);
        let extent = (hi[0] - lo[0]).max(hi[1] - lo[1]);
        let mut side = (area * POSES_PER_BUCKET / poses.len().max(1) as f64).sqrt();
        side = side.max(extent / MAX_BUCKETS as f64);
        if !(side.is_finite() && side > 0.0) {
            side = extent.max(1.0);
        }
        let count = |d: usize| (((hi[d] - lo[d]) / side) as usize + 1).min(MAX_BUCKETS);
        let size = [count(0), count(1)];
        let mut buckets = Self {
            poses: poses.to_vec(),
            origin: lo,
            side,
            size,
            start: vec![0; size[0] * size[1] + 1],
            members: vec![0; poses.len()],
            xs: Vec::new(),
            ys: Vec::new(),
            boxes: Vec::new(),
        };
        let of: Vec<usize> = poses.iter().map(|p| buckets.bucket_of(*p)).collect();
        for &b in &of {
            buckets.start[b + 1] += 1;
        }
        for b in 0..size[0] * size[1] {
            buckets.start[b + 1] += buckets.start[b];
        }
        let mut next = buckets.start.clone();
        for (k, &b) in of.iter().enumerate() {
            buckets.members[next[b]] = k as u32;
            next[b] += 1;
        }
        let at = |d: usize| {
            buckets
                .members
                .iter()
                .map(|&k| poses[k as usize][d])
                .collect()
        };
        (buckets.xs, buckets.ys) = (at(0), at(1));
        buckets.boxes = (0..size[0] * size[1])
            .map(|b| {
                let range = buckets.start[b]..buckets.start[b + 1];
                let mut bounds = [
                    f64::INFINITY,
                    f64::NEG_INFINITY,
                    f64::INFINITY,
                    f64::NEG_INFINITY,
                ];
                for (&x, &y) in buckets.xs[range.clone()].iter().zip(&buckets.ys[range]) {
                    bounds = [
                        bounds[0].min(x),
                        bounds[1].max(x),
                        bounds[2].min(y),
                        bounds[3].max(y),
                    ];
                }
                bounds
            })
            .collect();
        buckets
    }

    /// The bucket of a pose (clamped to the grid; bucket 0 for a pose that is not finite).
    fn bucket_of(&self, p: [f64; 2]) -> usize {
        if !(p[0].is_finite() && p[1].is_finite()) {
            return 0;
        }
        let [i, j] = [0, 1].map(|d| self.index(d, p[d]));
        j * self.size[0] + i
    }

    /// The bucket index of coordinate `x` along axis `d`, clamped to the grid.
    fn index(&self, d: usize, x: f64) -> usize {
        // Truncation is the floor above 0, and everything up to 1 (or NaN) goes to 0 anyway:
        // no call to `floor`, which the dilation made 4 times per pose.
        let k = (x - self.origin[d]) / self.side;
        if k > 0.0 {
            (k as usize).min(self.size[d] - 1)
        } else {
            0
        }
    }

    /// The `count` finite poses nearest `pose` (all when fewer), by increasing distance, ties to
    /// the lower index: the samples a scan finds (the local surface's, `local_surface.rs`). Rings
    /// of buckets around the pose's are searched until no bucket beyond can hold a nearer one.
    pub(crate) fn nearest(&self, pose: [f64; 2], count: usize) -> Vec<usize> {
        let poses = &self.poses;
        let m = poses.len().min(count);
        let mut best: Vec<(f64, usize)> = Vec::with_capacity(m + 1);
        let [cx, cy] = [0, 1].map(|d| self.index(d, pose[d]) as isize);
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
                        for &i in &self.members[self.start[c]..self.start[c + 1]] {
                            let i = i as usize;
                            let p = poses[i];
                            let d = ((p[0] - pose[0]).powi(2) + (p[1] - pose[1]).powi(2), i);
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
                            pose[a] - (self.origin[a] + (c - r) as f64 * self.side)
                        } else {
                            f64::INFINITY
                        };
                        let high = if c + r < n - 1 {
                            self.origin[a] + (c + r + 1) as f64 * self.side - pose[a]
                        } else {
                            f64::INFINITY
                        };
                        low.min(high)
                    })
                    .into_iter()
                    .fold(f64::INFINITY, f64::min)
                    - 1e-9 * self.side;
                if gap > 0.0 && best[m - 1].0 < gap * gap {
                    break;
                }
            }
        }
        best.into_iter().map(|(_, i)| i).collect()
    }

    /// π′ over the poses: each pose's value of `contour` moved by `shift` and spread over
    /// `reach` (the direct scan's result, bit for bit).
    pub fn dilate(&self, contour: &[f64], reach: f64, shift: [f64; 2]) -> Vec<f64> {
        if reach <= 0.0 && shift == [0.0; 2] {
            return contour.to_vec();
        }
        let r2 = reach * reach;
        let within =
            |q: &[f64; 2], t: [f64; 2]| (q[0] - t[0]).powi(2) + (q[1] - t[1]).powi(2) <= r2;
        // The contour in bucket order, each bucket's largest value, and the poses' coordinates
        // in that order: each bucket's scan reads contiguous memory.
        let values: Vec<f64> = (self.members.iter())
            .map(|&k| contour.get(k as usize).copied().unwrap_or(0.0))
            .collect();
        let top: Vec<f64> = (0..self.size[0] * self.size[1])
            .map(|b| {
                values[self.start[b]..self.start[b + 1]]
                    .iter()
                    .fold(f64::NEG_INFINITY, |a, &c| a.max(c))
            })
            .collect();
        // The buckets that can raise a max from 0, largest value first: each pose walks them in
        // that order, so it stops at the first one whose value is no larger than its max so far
        // (every later one is no larger either), and at the first it reaches whole.
        let mut order: Vec<Ranked> = (top.iter().enumerate())
            .filter(|(_, &t)| t > 0.0)
            .map(|(b, &t)| Ranked {
                top: t,
                column: (b % self.size[0]) as u32,
                row: (b / self.size[0]) as u32,
                bucket: b as u32,
            })
            .collect();
        order.sort_unstable_by(|a, b| b.top.total_cmp(&a.top));
        let exotic = !(r2.is_finite())
            || self
                .poses
                .iter()
                .any(|p| !(p[0].is_finite() && p[1].is_finite()));
        let direct = |target: [f64; 2]| {
            (self.poses.iter().zip(contour))
                .filter(|(q, _)| within(q, target))
                .map(|(_, &c)| c)
                .fold(0.0f64, f64::max)
        };
        if exotic {
            // Not finite anywhere: the direct scan.
            return (self.poses.iter())
                .map(|p| direct([p[0] - shift[0], p[1] - shift[1]]))
                .collect();
        }
        let r = reach.abs();
        // One bucket beyond the disc's box on each side absorbs any rounding of the bucket
        // indices; `lo` and `hi` bound the targets' coordinates along axis `d`.
        let span = |d: usize, lo: f64, hi: f64| {
            let (a, b) = (self.index(d, lo - r), self.index(d, hi + r));
            (a.saturating_sub(1), (b + 1).min(self.size[d] - 1))
        };
        let walk = Walk {
            buckets: self,
            values: &values,
            r2,
        };
        let mut out = vec![0.0; self.poses.len()];
        let mut near: Vec<Ranked> = Vec::with_capacity(order.len());
        for (b, bounds) in self.boxes.iter().enumerate() {
            let range = self.start[b]..self.start[b + 1];
            if range.is_empty() {
                continue;
            }
            // The buckets any member's disc can overlap, in the walk's order: its targets lie
            // within the members' box moved by the shift, and a bucket index only grows with
            // the coordinate, so each member's own span lies within this one.
            let ((i0, i1), (j0, j1)) = (
                span(0, bounds[0] - shift[0], bounds[1] - shift[0]),
                span(1, bounds[2] - shift[1], bounds[3] - shift[1]),
            );
            near.clear();
            near.extend(order.iter().filter(|o| {
                let (i, j) = (o.column as usize, o.row as usize);
                (i0..=i1).contains(&i) && (j0..=j1).contains(&j)
            }));
            for k in range {
                let target = [self.xs[k] - shift[0], self.ys[k] - shift[1]];
                out[self.members[k] as usize] = if !(target[0].is_finite() && target[1].is_finite())
                {
                    direct(target)
                } else {
                    let ((i0, i1), (j0, j1)) =
                        (span(0, target[0], target[0]), span(1, target[1], target[1]));
                    walk.max(&near, target, [i0, i1, j0, j1])
                };
            }
        }
        out
    }
}

/// One frame's walk over the buckets for a pose's max.
struct Walk<'a> {
    buckets: &'a PoseBuckets,
    /// The contour in bucket order.
    values: &'a [f64],
    r2: f64,
}

impl Walk<'_> {
    /// The largest value within the disc around `target` over the buckets `ranked` (largest
    /// value first; every bucket of the disc's span `[i0, i1, j0, j1]` among them).
    fn max(&self, ranked: &[Ranked], target: [f64; 2], span: [usize; 4]) -> f64 {
        let [i0, i1, j0, j1] = span;
        let b = self.buckets;
        let mut best = 0.0f64;
        for ranked in ranked {
            // This bucket and every later one are no larger: none can change the max.
            if ranked.top <= best {
                break;
            }
            let (i, j) = (ranked.column as usize, ranked.row as usize);
            if i < i0 || i > i1 || j < j0 || j > j1 {
                continue;
            }
            let bucket = ranked.bucket as usize;
            match reached(&b.boxes[bucket], target, self.r2) {
                Reached::All => {
                    best = ranked.top;
                    break;
                }
                Reached::None => {}
                Reached::Some => {
                    for k in b.start[bucket]..b.start[bucket + 1] {
                        let d = (b.xs[k] - target[0]).powi(2) + (b.ys[k] - target[1]).powi(2);
                        if d <= self.r2 {
                            best = best.max(self.values[k]);
                        }
                    }
                }
            }
        }
        best
    }
}

/// A bucket in the dilation's walk: its largest value and place on the grid.
#[derive(Clone, Copy, Debug)]
struct Ranked {
    top: f64,
    column: u32,
    row: u32,
    bucket: u32,
}

/// How many of a bucket's members lie within the disc.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Reached {
    All,
    None,
    Some,
}

/// Which members of a bucket with box `b` = [x0, x1, y0, y1] the disc of squared radius `r2`
/// around `t` holds, as the direct scan's test would find them: a difference, its square and a
/// sum are rounded monotonically, so a member's computed squared distance lies between those of
/// the box's nearest and farthest corners, computed the same way.
fn reached(b: &[f64; 4], t: [f64; 2], r2: f64) -> Reached {
    let (far_x, far_y) = (
        (b[0] - t[0]).powi(2).max((b[1] - t[0]).powi(2)),
        (b[2] - t[1]).powi(2).max((b[3] - t[1]).powi(2)),
    );
    if far_x + far_y <= r2 {
        return Reached::All;
    }
    let near = |lo: f64, hi: f64, x: f64| {
        if x < lo {
            (lo - x).powi(2)
        } else if x > hi {
            (hi - x).powi(2)
        } else {
            0.0
        }
    };
    if near(b[0], b[1], t[0]) + near(b[2], b[3], t[1]) <= r2 {
        Reached::Some
    } else {
        Reached::None
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// The definition: every pair.
    fn direct(poses: &[[f64; 2]], contour: &[f64], reach: f64, shift: [f64; 2]) -> Vec<f64> {
        if reach <= 0.0 && shift == [0.0; 2] {
            return contour.to_vec();
        }
        let r2 = reach * reach;
        poses
            .iter()
            .map(|p| {
                let t = [p[0] - shift[0], p[1] - shift[1]];
                (poses.iter().zip(contour))
                    .filter(|(q, _)| (q[0] - t[0]).powi(2) + (q[1] - t[1]).powi(2) <= r2)
                    .map(|(_, &c)| c)
                    .fold(0.0f64, f64::max)
            })
            .collect()
    }

    #[test]
    fn dilation_spreads_each_value_over_its_reach() {
        let poses = [[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [3.5, 0.0]];
        let contour = [0.0, 1.0, 0.2, 0.0];
        let still = [0.0; 2];
        let dilate = |_: &[[f64; 2]], c: &[f64], r: f64, s: [f64; 2]| {
            PoseBuckets::new(&poses).dilate(c, r, s)
        };
        assert_eq!(dilate(&poses, &contour, 0.0, still), contour.to_vec());
        assert_eq!(
            dilate(&poses, &contour, 1.5, still),
            vec![1.0, 1.0, 1.0, 0.2]
        );
        assert_eq!(
            dilate(&poses, &contour, 1.4, still),
            vec![1.0, 1.0, 1.0, 0.0]
        );
        assert_eq!(dilate(&poses, &contour, 10.0, still), vec![1.0; 4]);
        // Moved by +1 first: pose 1's value lands on pose 2, pose 2's at 3 (reach 0.5 of 3.5).
        assert_eq!(
            dilate(&poses, &contour, 0.6, [1.0, 0.0]),
            vec![0.0, 0.0, 1.0, 0.2]
        );
    }

    #[test]
    fn a_box_reached_whole_or_not_at_all_says_so_of_every_member() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let mut seen = [0usize; 3];
        for _ in 0..20_000 {
            // Members on a coarse lattice, so that distances often equal the radius exactly.
            let mut at = || 0.25 * rng.random_range(-8i32..8) as f64;
            let members: Vec<[f64; 2]> = (0..3).map(|_| [at(), at()]).collect();
            let target = [at(), at()];
            let r2 = [0.0, 0.0625, 0.5, 1.0, 2.25, 4.0][rng.random_range(0..6)];
            let mut bounds = [
                f64::INFINITY,
                f64::NEG_INFINITY,
                f64::INFINITY,
                f64::NEG_INFINITY,
            ];
            for m in &members {
                bounds = [
                    bounds[0].min(m[0]),
                    bounds[1].max(m[0]),
                    bounds[2].min(m[1]),
                    bounds[3].max(m[1]),
                ];
            }
            let inside = members
                .iter()
                .filter(|q| (q[0] - target[0]).powi(2) + (q[1] - target[1]).powi(2) <= r2)
                .count();
            let reach = reached(&bounds, target, r2);
            match reach {
                Reached::All => assert_eq!(inside, members.len()),
                Reached::None => assert_eq!(inside, 0),
                Reached::Some => {}
            }
            seen[reach as usize] += 1;
        }
        // Each answer was exercised.
        assert!(seen.iter().all(|&n| n > 100), "{seen:?}");
    }

    #[test]
    fn buckets_give_the_direct_scan_bit_for_bit() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let mesh: Vec<[f64; 2]> = (0..20)
            .flat_map(|j| (0..20).map(move |i| [i as f64 - 9.5, 40.0 + j as f64]))
            .collect();
        let scattered: Vec<[f64; 2]> = (0..300)
            .map(|_| [rng.random_range(-10.0..10.0), rng.random_range(35.0..60.0)])
            .collect();
        // A clump far from a few isolated poses, and one pose alone.
        let mut clumped: Vec<[f64; 2]> = (0..50).map(|k| [1e-3 * k as f64, 0.0]).collect();
        clumped.extend([[30.0, 30.0], [-30.0, 5.0]]);
        for poses in [mesh, scattered, clumped, vec![[1.0, 2.0]]] {
            let buckets = PoseBuckets::new(&poses);
            for round in 0..60 {
                // Spread values; a peak that falls to 0 far away (as a carried contour does);
                // few distinct values (ties), with a negative value and a NaN now and then.
                let centre = [rng.random_range(-10.0..10.0), rng.random_range(35.0..60.0)];
                let contour: Vec<f64> = (poses.iter())
                    .map(|p| match round % 3 {
                        0 => rng.random::<f64>().powi(4),
                        1 => (-((p[0] - centre[0]).powi(2) + (p[1] - centre[1]).powi(2)) * 20.0)
                            .exp(),
                        _ => [0.0, 0.5, 1.0, -0.5, f64::NAN][rng.random_range(0..5)],
                    })
                    .collect();
                // Reaches from none to beyond the poses' extent, exactly on mesh distances too.
                let reach = [0.0, 1.0, 2.0, 0.37, 4.0, 100.0, -1.5][rng.random_range(0..7)];
                let shift = [
                    rng.random_range(-3.0..3.0),
                    [0.0, 1.0][rng.random_range(0..2)],
                ];
                let bits = |v: Vec<f64>| v.into_iter().map(f64::to_bits).collect::<Vec<_>>();
                assert_eq!(
                    bits(buckets.dilate(&contour, reach, shift)),
                    bits(direct(&poses, &contour, reach, shift)),
                    "reach {reach}, shift {shift:?}"
                );
            }
        }
    }
}
