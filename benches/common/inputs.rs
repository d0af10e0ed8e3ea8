//! The seeded inputs of the benches, one copy included by each (`#[path]`): the C400 mass
//! functions of `evidence`, the EM features of `hmm`, the samples and frames of `baselines`, and
//! the peer comparison (`peers`), which must time exactly what the benches time.

// Each bench uses its own part.
#![allow(dead_code)]

use evitrack::estimator::{Labelled, TrainingSet};
use evitrack::evidence::{MassFunction, Subset};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

/// 8 mass functions of 3 focal sets of `k` of `n` elements.
pub fn mass_functions(k: usize, n: usize, seed: u64, lowest_mass: f64) -> Vec<MassFunction> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..8)
        .map(|_| {
            let raw: Vec<f64> = (0..3).map(|_| rng.random_range(lowest_mass..1.0)).collect();
            let total: f64 = raw.iter().sum();
            let focal = raw
                .iter()
                .map(|m| {
                    let idx = rand::seq::index::sample(&mut rng, n, k);
                    let s = Subset::from_indices(n, idx.iter()).expect("indices below n");
                    (s, m / total)
                })
                .collect();
            MassFunction::new(n, focal).expect("valid mass function")
        })
        .collect()
}

/// 8 smooth features along a serpentine sweep of `n` nodes.
pub fn em_features(n: usize) -> Vec<Vec<f64>> {
    let side = (n as f64).sqrt().ceil() as usize;
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let noise = Normal::new(0.0, 0.02).expect("valid");
    (0..8)
        .map(|f| {
            let a = 0.5 + f as f64 * 0.37;
            (0..n)
                .map(|i| {
                    let (r, c) = (i / side, i % side);
                    let c = if r % 2 == 0 { c } else { side - 1 - c };
                    let (x, y) = (c as f64 / side as f64, r as f64 / side as f64);
                    (a * x + (1.0 - a) * y * y).sin()
                        + (3.0 * a * x * y).cos()
                        + noise.sample(&mut rng)
                })
                .collect()
        })
        .collect()
}

/// `dim` smooth features of the pose, each with noise of standard deviation 0.01.
pub fn features_of(p: [f64; 2], dim: usize, rng: &mut ChaCha8Rng) -> Vec<Option<f64>> {
    let noise = Normal::new(0.0, 0.01).expect("valid");
    let (x, y) = (p[0] / 9.5, (p[1] - 47.5) / 9.5);
    (0..dim)
        .map(|f| {
            // Past the 8th, slopes fold back into the same range: distinct but alike features.
            let a = 0.5 + (f % 8) as f64 * 0.37 + (f / 8) as f64 * 0.05;
            let v = (a * x + (1.0 - a) * y).sin() + (0.7 * a * x * y).cos() + 0.3 * a * y;
            Some(v + noise.sample(rng))
        })
        .collect()
}

/// A `side` × `side` mesh over [−9.5, 9.5] × [38, 57] mm in serpentine order, and `dim`
/// features of each pose.
pub fn mesh(side: usize, dim: usize) -> (Vec<[f64; 2]>, Vec<Vec<Option<f64>>>) {
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let step = 19.0 / (side - 1) as f64;
    let poses: Vec<[f64; 2]> = (0..side * side)
        .map(|i| {
            let (r, c) = (i / side, i % side);
            let c = if r % 2 == 0 { c } else { side - 1 - c };
            [-9.5 + c as f64 * step, 38.0 + r as f64 * step]
        })
        .collect();
    let rows = poses
        .iter()
        .map(|&p| features_of(p, dim, &mut rng))
        .collect();
    (poses, rows)
}

/// `n` random poses inside the mesh and their `dim` features (the peers' test error needs the
/// poses).
pub fn frames(n: usize, dim: usize) -> (Vec<[f64; 2]>, Vec<Vec<Option<f64>>>) {
    let mut rng = ChaCha8Rng::seed_from_u64(12);
    (0..n)
        .map(|_| {
            let p = [rng.random_range(-9.0..9.0), rng.random_range(38.5..56.5)];
            let row = features_of(p, dim, &mut rng);
            (p, row)
        })
        .unzip()
}

/// A `side` × `side` mesh in serpentine order and its features, as a training set.
pub struct Samples {
    pub names: Vec<String>,
    pub poses: Vec<[f64; 2]>,
    pub rows: Vec<Vec<Option<f64>>>,
}

impl Samples {
    /// [`mesh`] with 8 features.
    pub fn mesh(side: usize) -> Self {
        Self::mesh_of(side, 8)
    }

    /// [`mesh`] with `dim` features per sample.
    pub fn mesh_of(side: usize, dim: usize) -> Self {
        let (poses, rows) = mesh(side, dim);
        Self {
            names: (0..dim).map(|i| format!("f{i}")).collect(),
            poses,
            rows,
        }
    }

    pub fn training(&self) -> TrainingSet<'_> {
        TrainingSet::new(
            &self.names,
            Labelled {
                poses: &self.poses,
                rows: &self.rows,
            },
        )
    }
}
