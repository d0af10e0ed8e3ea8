//! An exact k-nearest-neighbour index over the standardised sample rows: a k-d tree (kiddo's)
//! on at most [`TREE_DIMS`] coordinates — the features themselves when there are that few, else
//! their leading principal components — whose distances bound the full distances from below (an
//! orthonormal projection never lengthens a vector). A query takes k neighbours in the tree,
//! measures their full distances, and gathers every sample the tree puts within the k-th of
//! them (widened for rounding): a superset of the k nearest, which the caller ranks with the
//! brute-force distance itself, so the answer is the brute force's to the bit.
//!
//! Whether the tree pays is measured when it is built, not assumed from the dimension: on
//! features that follow a two-dimensional pose the leading components hold nearly all the
//! spread and a query gathers a few dozen samples even from 64 features; on features without
//! such structure it gathers most of them, and the brute force is kept.

use std::num::NonZero;
use std::sync::Arc;

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::{DMatrix, SymmetricEigen};

/// Coordinates the tree splits on.
pub(super) const TREE_DIMS: usize = 4;
/// Fewer samples than this are searched by brute force (a scan of 256 rows takes a few µs).
pub(super) const MIN_SAMPLES: usize = 256;
/// The tree is kept when a probe query gathers at most this share of the samples on average.
const MAX_GATHERED_SHARE: f64 = 0.125;
/// Probe queries when the index is built.
const PROBES: usize = 32;
/// Widening of the gathering radius: relative, and absolute per unit of coordinate size.
const RELATIVE_SLACK: f64 = 1e-9;
const ABSOLUTE_SLACK: f64 = 1e-10;

/// The tree, the projection that feeds it and the size of the samples' coordinates.
#[derive(Clone)]
pub(super) struct Index {
    /// Shared by clones: the tree is read only.
    tree: Arc<ImmutableKdTree<f64, TREE_DIMS>>,
    /// Rows of the projection (`TREE_DIMS` × dim, row-major) when there are more features than
    /// tree coordinates; without it, the features are the coordinates (padded with zeros).
    projection: Option<Vec<f64>>,
    dim: usize,
    /// The largest Euclidean norm of a standardised sample row.
    reach: f64,
}

impl std::fmt::Debug for Index {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Index")
            .field("dim", &self.dim)
            .field("projected", &self.projection.is_some())
            .finish_non_exhaustive()
    }
}

impl Index {
    /// The index of `inputs` (row-major, `dim` per sample), or `None` where a tree would not
    /// pay (few samples, or probes that gather too many) or cannot hold the coordinates.
    /// `distance(query, i)` is the brute force's squared distance to sample `i`.
    pub(super) fn build(
        inputs: &[f64],
        dim: usize,
        k: usize,
        distance: impl Fn(&[f64], usize) -> f64,
    ) -> Option<Self> {
        let n = inputs.len() / dim.max(1);
        if n < MIN_SAMPLES || dim == 0 || n > u32::MAX as usize {
            return None;
        }
        let projection = (dim > TREE_DIMS).then(|| principal_axes(inputs, dim));
        let mut points = Vec::with_capacity(n);
        let mut reach = 0.0f64;
        for row in inputs.chunks_exact(dim) {
            let p = project(projection.as_deref(), row);
            // kiddo reserves the largest value; our coordinates are standardised.
            if !p.iter().all(|x| x.abs() < 1e300) {
                return None;
            }
            points.push(p);
            reach = reach.max(norm(row));
        }
        let tree = Arc::new(ImmutableKdTree::new_from_slice(&points).ok()?);
        let index = Self {
            tree,
            projection,
            dim,
            reach,
        };
        // Probes: midpoints of samples n/PROBES apart along the trajectory and their next.
        let mut gathered = 0;
        for t in 0..PROBES {
            let i = t * n / PROBES;
            let j = (i + 1) % n;
            let query: Vec<f64> = (inputs[i * dim..(i + 1) * dim].iter())
                .zip(&inputs[j * dim..(j + 1) * dim])
                .map(|(a, b)| 0.5 * (a + b))
                .collect();
            gathered += index.nearest(&query, k, |s| distance(&query, s))?.1;
        }
        (gathered as f64 <= MAX_GATHERED_SHARE * (PROBES * n) as f64).then_some(index)
    }

    /// The k nearest samples to `query` (every feature present) as (squared distance, sample)
    /// by increasing distance, ties to the lower sample, with `distance(i)` the brute force's
    /// squared distance; and how many samples were gathered. `None` when a distance is not
    /// finite (the caller's brute force handles those).
    pub(super) fn nearest(
        &self,
        query: &[f64],
        k: usize,
        distance: impl Fn(usize) -> f64,
    ) -> Option<(Vec<(f64, usize)>, usize)> {
        let p = project(self.projection.as_deref(), query);
        if !p.iter().all(|x| x.is_finite()) {
            return None;
        }
        let first = (self.tree.query(&p))
            .nearest_n::<SquaredEuclidean<f64>>(NonZero::new(k)?)
            .execute();
        let mut kth = 0.0f64;
        for item in &first {
            let d2 = distance(item.item as usize);
            if !d2.is_finite() {
                return None;
            }
            kth = kth.max(d2);
        }
        // Every sample whose full squared distance is at most `kth` lies within this radius in
        // the tree (the projection shortens; the slack covers rounding in both sums).
        let widened =
            kth.sqrt() * (1.0 + RELATIVE_SLACK) + ABSOLUTE_SLACK * (1.0 + self.reach + norm(query));
        let radius = widened * widened;
        if !radius.is_finite() {
            return None;
        }
        let within = (self.tree.query(&p))
            .within::<SquaredEuclidean<f64>>(radius)
            .unsorted()
            .execute();
        let gathered = within.len();
        let mut found: Vec<(f64, usize)> = within
            .iter()
            .map(|item| (distance(item.item as usize), item.item as usize))
            .collect();
        found.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        found.truncate(k);
        (found.len() == k).then_some((found, gathered))
    }
}

/// The tree coordinates of a row: its leading principal components, or the row itself padded.
fn project(projection: Option<&[f64]>, row: &[f64]) -> [f64; TREE_DIMS] {
    match projection {
        Some(axes) => std::array::from_fn(|c| {
            (axes[c * row.len()..(c + 1) * row.len()].iter().zip(row))
                .map(|(a, x)| a * x)
                .sum()
        }),
        None => std::array::from_fn(|c| row.get(c).copied().unwrap_or(0.0)),
    }
}

/// The `TREE_DIMS` unit eigenvectors of the rows' second-moment matrix with the largest
/// eigenvalues (ties to the lower index), row-major.
fn principal_axes(inputs: &[f64], dim: usize) -> Vec<f64> {
    let mut moments = DMatrix::<f64>::zeros(dim, dim);
    for row in inputs.chunks_exact(dim) {
        for a in 0..dim {
            for b in 0..=a {
                moments[(a, b)] += row[a] * row[b];
            }
        }
    }
    for a in 0..dim {
        for b in 0..a {
            moments[(b, a)] = moments[(a, b)];
        }
    }
    let eigen = SymmetricEigen::new(moments);
    let mut order: Vec<usize> = (0..dim).collect();
    order.sort_by(|&a, &b| (eigen.eigenvalues[b].total_cmp(&eigen.eigenvalues[a])).then(a.cmp(&b)));
    let mut axes = Vec::with_capacity(TREE_DIMS * dim);
    for &c in &order[..TREE_DIMS] {
        axes.extend(eigen.eigenvectors.column(c).iter());
    }
    axes
}

fn norm(row: &[f64]) -> f64 {
    row.iter().map(|x| x * x).sum::<f64>().sqrt()
}
