//! Analysis of feature values on a regular mesh of poses: does the feature vector tell each node
//! apart from its 4-neighbours, and how smooth is each feature between neighbours (the paper's
//! condition 2 of §3.1)?

use serde::{Deserialize, Serialize};

use super::FeatureError;

/// How the `nx × ny` nodes are laid out in the value list.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MeshOrder {
    /// Node `(ix, iy)` is entry `iy · nx + ix` (x fastest).
    #[default]
    RowMajor,
    /// Boustrophedon, as a robot sweeps the mesh: rows of constant `iy` in turn, even rows with
    /// `ix` increasing, odd rows with `ix` decreasing. Node `(ix, iy)` is entry
    /// `iy · nx + ix` on even rows and `iy · nx + (nx − 1 − ix)` on odd rows.
    Serpentine,
}

impl MeshOrder {
    /// The entry index of node `(ix, iy)` on an `nx`-wide mesh.
    pub fn index(self, ix: usize, iy: usize, nx: usize) -> usize {
        match self {
            MeshOrder::RowMajor => iy * nx + ix,
            MeshOrder::Serpentine if iy % 2 == 1 => iy * nx + (nx - 1 - ix),
            MeshOrder::Serpentine => iy * nx + ix,
        }
    }
}

/// Smoothness of one feature between mesh neighbours, relative to its range.
#[derive(Debug, Clone, PartialEq)]
pub struct FeatureSmoothness {
    /// `max − min` of the feature's present values over the mesh (0 when constant or all missing).
    pub range: f64,
    /// Largest `|Δ| / range` between 4-neighbours where both values are present (0 if the range
    /// is 0 or no such pair exists).
    pub max_step: f64,
    /// Mean `|Δ| / range` over those neighbour pairs.
    pub mean_step: f64,
    /// Number of nodes where the feature is missing.
    pub missing: usize,
}

/// The result of [`analyse_mesh`].
#[derive(Debug, Clone, PartialEq)]
pub struct MeshAnalysis {
    /// Number of nodes, `nx · ny`.
    pub nodes: usize,
    /// Nodes that the feature vector tells apart from every one of their 4-neighbours.
    pub distinguished: usize,
    /// The nodes `(ix, iy)` that are not told apart from at least one 4-neighbour.
    pub confused: Vec<(usize, usize)>,
    /// Per feature, in the order of the values.
    pub features: Vec<FeatureSmoothness>,
}

/// Analyse feature vectors on an `nx × ny` mesh laid out in `order`.
///
/// Two neighbouring nodes are told apart when, for at least one feature, their values differ by
/// more than `tolerance · range` of that feature, or the feature is missing at exactly one of
/// them. A feature of zero range never tells nodes apart. A single node (no neighbours) counts as
/// distinguished.
///
/// Errors: `values.len() != nx · ny`, vectors of unequal length, a non-finite value, or a
/// negative / non-finite tolerance.
pub fn analyse_mesh(
    values: &[Vec<Option<f64>>],
    nx: usize,
    ny: usize,
    order: MeshOrder,
    tolerance: f64,
) -> Result<MeshAnalysis, FeatureError> {
    if values.len() != nx.saturating_mul(ny) {
        return Err(FeatureError::MeshSize {
            nx,
            ny,
            got: values.len(),
        });
    }
    if !(tolerance.is_finite() && tolerance >= 0.0) {
        return Err(FeatureError::BadTolerance { tolerance });
    }
    let nf = values.first().map_or(0, Vec::len);
    for (i, v) in values.iter().enumerate() {
        if v.len() != nf {
            return Err(FeatureError::RaggedValues {
                index: i,
                expected: nf,
                got: v.len(),
            });
        }
        if v.iter().flatten().any(|x| !x.is_finite()) {
            return Err(FeatureError::NonFinite {
                what: "mesh feature value",
                index: i,
            });
        }
    }
    let at = |ix: usize, iy: usize| &values[order.index(ix, iy, nx)];
    let ranges: Vec<f64> = (0..nf)
        .map(|f| {
            let (lo, hi) = values
                .iter()
                .filter_map(|v| v[f])
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), x| {
                    (lo.min(x), hi.max(x))
                });
            if hi > lo {
                hi - lo
            } else {
                0.0
            }
        })
        .collect();
    // Right and down neighbour pairs cover every 4-neighbour edge once.
    let mut edges = Vec::with_capacity(2 * nx * ny);
    for iy in 0..ny {
        for ix in 0..nx {
            if ix + 1 < nx {
                edges.push(((ix, iy), (ix + 1, iy)));
            }
            if iy + 1 < ny {
                edges.push(((ix, iy), (ix, iy + 1)));
            }
        }
    }
    let mut confused = vec![false; nx * ny];
    let mut max_step = vec![0.0f64; nf];
    let mut sum_step = vec![0.0f64; nf];
    let mut count_step = vec![0usize; nf];
    for &((ax, ay), (bx, by)) in &edges {
        let (u, v) = (at(ax, ay), at(bx, by));
        let mut apart = false;
        for f in 0..nf {
            match (u[f], v[f]) {
                (Some(p), Some(q)) => {
                    let rel = if ranges[f] > 0.0 {
                        (p - q).abs() / ranges[f]
                    } else {
                        0.0
                    };
                    apart |= rel > tolerance;
                    max_step[f] = max_step[f].max(rel);
                    sum_step[f] += rel;
                    count_step[f] += 1;
                }
                (None, None) => {}
                _ => apart = true,
            }
        }
        if !apart {
            confused[ay * nx + ax] = true;
            confused[by * nx + bx] = true;
        }
    }
    let features = (0..nf)
        .map(|f| FeatureSmoothness {
            range: ranges[f],
            max_step: max_step[f],
            mean_step: if count_step[f] > 0 {
                sum_step[f] / count_step[f] as f64
            } else {
                0.0
            },
            missing: values.iter().filter(|v| v[f].is_none()).count(),
        })
        .collect();
    let confused: Vec<(usize, usize)> = (0..ny)
        .flat_map(|iy| (0..nx).map(move |ix| (ix, iy)))
        .filter(|&(ix, iy)| confused[iy * nx + ix])
        .collect();
    Ok(MeshAnalysis {
        nodes: nx * ny,
        distinguished: nx * ny - confused.len(),
        confused,
        features,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(
        nx: usize,
        ny: usize,
        order: MeshOrder,
        f: impl Fn(usize, usize) -> Vec<Option<f64>>,
    ) -> Vec<Vec<Option<f64>>> {
        let mut v = vec![Vec::new(); nx * ny];
        for iy in 0..ny {
            for ix in 0..nx {
                v[order.index(ix, iy, nx)] = f(ix, iy);
            }
        }
        v
    }

    #[test]
    fn linear_ramps_tell_every_node_apart() {
        for order in [MeshOrder::RowMajor, MeshOrder::Serpentine] {
            let v = grid(5, 4, order, |ix, iy| {
                vec![Some(ix as f64), Some(2.0 * iy as f64)]
            });
            let a = analyse_mesh(&v, 5, 4, order, 0.1).unwrap();
            assert_eq!((a.nodes, a.distinguished), (20, 20));
            assert!(a.confused.is_empty());
            assert_eq!(a.features[0].range, 4.0);
            assert_eq!(a.features[0].max_step, 0.25);
            // 16 x-edges of step 1/4, 15 y-edges of step 0.
            assert!((a.features[0].mean_step - 16.0 * 0.25 / 31.0).abs() < 1e-12);
            assert!((a.features[1].max_step - 1.0 / 3.0).abs() < 1e-12);
        }
    }

    #[test]
    fn one_ramp_cannot_separate_along_the_other_axis() {
        let v = grid(4, 3, MeshOrder::RowMajor, |ix, _| vec![Some(ix as f64)]);
        let a = analyse_mesh(&v, 4, 3, MeshOrder::RowMajor, 0.01).unwrap();
        assert_eq!(a.distinguished, 0);
        let c = grid(4, 3, MeshOrder::RowMajor, |_, _| vec![Some(7.0)]);
        let a = analyse_mesh(&c, 4, 3, MeshOrder::RowMajor, 0.0).unwrap();
        assert_eq!(
            (a.distinguished, a.features[0].range, a.features[0].max_step),
            (0, 0.0, 0.0)
        );
    }

    #[test]
    fn serpentine_layout_is_read_correctly() {
        // Values laid out serpentine but read as row-major would scramble odd rows.
        let v = grid(3, 2, MeshOrder::Serpentine, |ix, iy| {
            vec![Some((ix + 10 * iy) as f64)]
        });
        assert_eq!(v[3][0], Some(12.0));
        let a = analyse_mesh(&v, 3, 2, MeshOrder::Serpentine, 0.0).unwrap();
        assert!((a.features[0].max_step - 10.0 / 12.0).abs() < 1e-12);
        let b = analyse_mesh(&v, 3, 2, MeshOrder::RowMajor, 0.0).unwrap();
        assert!(b.features[0].max_step != a.features[0].max_step);
    }

    #[test]
    fn a_jump_shows_in_max_step_and_missing_values_separate() {
        let v = grid(6, 1, MeshOrder::RowMajor, |ix, _| {
            vec![
                Some(if ix < 3 { 0.0 } else { 10.0 }),
                (ix != 0).then_some(1.0),
            ]
        });
        let a = analyse_mesh(&v, 6, 1, MeshOrder::RowMajor, 0.05).unwrap();
        assert_eq!(a.features[0].max_step, 1.0);
        assert_eq!(a.features[1].missing, 1);
        // Nodes 0|1 differ by missingness, 2|3 by the jump; 1–2 and 3–4–5 are confused.
        assert_eq!(a.confused, vec![(1, 0), (2, 0), (3, 0), (4, 0), (5, 0)]);
        assert_eq!(a.distinguished, 1);
    }

    #[test]
    fn bad_meshes_are_errors() {
        let v = vec![vec![Some(1.0)]; 5];
        assert!(matches!(
            analyse_mesh(&v, 2, 3, MeshOrder::RowMajor, 0.1),
            Err(FeatureError::MeshSize { got: 5, .. })
        ));
        assert!(analyse_mesh(&v, 5, 1, MeshOrder::RowMajor, f64::NAN).is_err());
        let mut r = v.clone();
        r[2].push(None);
        assert!(analyse_mesh(&r, 5, 1, MeshOrder::RowMajor, 0.1).is_err());
        let mut n = v;
        n[1][0] = Some(f64::INFINITY);
        assert!(analyse_mesh(&n, 5, 1, MeshOrder::RowMajor, 0.1).is_err());
        let single = analyse_mesh(&[vec![Some(1.0)]], 1, 1, MeshOrder::RowMajor, 0.1).unwrap();
        assert_eq!(single.distinguished, 1);
    }
}
