//! Synthetic feature maps with a known answer, for tests and benches of the estimators: smooth,
//! non-linear functions of the pose over the rig's workspace, measured with seeded Gaussian noise.

use rand::Rng;
use rand_distr::{Distribution, Normal};

/// Feature `i` of pose `q` (mm, x ∈ [−9.5, 9.5], y ∈ [38, 57]): a plane wave of its own
/// direction and frequency plus a gentle bowl, so that every pair of features crosses at an
/// angle and no feature is linear.
pub fn feature_value(i: usize, q: [f64; 2]) -> f64 {
    let angle = 0.7 + 1.3 * i as f64;
    let (u, v) = (q[0] / 19.0, (q[1] - 47.5) / 19.0);
    let along = angle.cos() * u + angle.sin() * v;
    let frequency = 1.5 + 0.25 * (i % 4) as f64;
    (frequency * along * std::f64::consts::PI).sin() + 0.3 * (u * u + v * v) + 0.1 * i as f64
}

/// The gradient (∂/∂x, ∂/∂y, per mm) of [`feature_value`] `i` at `q`: the slopes the
/// information limit's closed form needs.
pub fn feature_gradient(i: usize, q: [f64; 2]) -> [f64; 2] {
    let angle = 0.7 + 1.3 * i as f64;
    let (u, v) = (q[0] / 19.0, (q[1] - 47.5) / 19.0);
    let along = angle.cos() * u + angle.sin() * v;
    let frequency = 1.5 + 0.25 * (i % 4) as f64;
    let wave = (frequency * along * std::f64::consts::PI).cos() * frequency * std::f64::consts::PI;
    [
        (wave * angle.cos() + 0.6 * u) / 19.0,
        (wave * angle.sin() + 0.6 * v) / 19.0,
    ]
}

/// Every one of `features` feature values of pose `q`, each with Gaussian noise of standard
/// deviation `noise` drawn from `rng`.
pub fn feature_row(
    features: usize,
    q: [f64; 2],
    noise: f64,
    rng: &mut impl Rng,
) -> Vec<Option<f64>> {
    let normal = Normal::new(0.0, noise.max(0.0)).unwrap_or(Normal::new(0.0, 0.0).expect("σ = 0"));
    (0..features)
        .map(|i| Some(feature_value(i, q) + normal.sample(rng)))
        .collect()
}

/// The mesh of the workspace with `per_side` × `per_side` nodes (20: the 1 mm mesh).
pub fn workspace_mesh(per_side: usize) -> Vec<[f64; 2]> {
    let step = if per_side > 1 {
        19.0 / (per_side - 1) as f64
    } else {
        0.0
    };
    (0..per_side)
        .flat_map(|r| (0..per_side).map(move |c| [-9.5 + c as f64 * step, 38.0 + r as f64 * step]))
        .collect()
}

/// A sample trajectory of these maps: a mesh of the workspace, each pose's feature row measured
/// with noise, and the features' names (`f0`, `f1`, …).
pub struct MeshSamples {
    /// The features' names.
    pub names: Vec<String>,
    /// The mesh's poses (mm).
    pub poses: Vec<[f64; 2]>,
    /// One feature row per pose.
    pub rows: Vec<Vec<Option<f64>>>,
}

impl MeshSamples {
    /// The `per_side`² mesh with `features` features each, measured with `noise` drawn from
    /// `rng` pose by pose.
    pub fn new(per_side: usize, features: usize, noise: f64, rng: &mut impl Rng) -> Self {
        let poses = workspace_mesh(per_side);
        let rows = (poses.iter())
            .map(|&q| feature_row(features, q, noise, rng))
            .collect();
        Self {
            names: (0..features).map(|i| format!("f{i}")).collect(),
            poses,
            rows,
        }
    }

    /// The training set of these samples alone.
    pub fn training(&self) -> super::TrainingSet<'_> {
        super::TrainingSet::new(
            &self.names,
            super::Labelled {
                poses: &self.poses,
                rows: &self.rows,
            },
        )
    }
}

/// `count` poses drawn uniformly from the workspace.
pub fn workspace_points(count: usize, rng: &mut impl Rng) -> Vec<[f64; 2]> {
    (0..count)
        .map(|_| [rng.random_range(-9.5..=9.5), rng.random_range(38.0..=57.0)])
        .collect()
}

/// The continuous tracker fitted on `features` test maps over a `per_side`² mesh, with a
/// validation set of `validation` random poses (threshold learned from it when
/// `learn_threshold`), every value measured with `noise`, all drawn from `seed`.
pub fn fitted_continuous(
    features: usize,
    per_side: usize,
    validation: usize,
    noise: f64,
    learn_threshold: bool,
    seed: u64,
) -> super::Continuous {
    use rand::SeedableRng;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let poses = workspace_mesh(per_side);
    let rows: Vec<_> = (poses.iter())
        .map(|&q| feature_row(features, q, noise, &mut rng))
        .collect();
    let valid_poses = workspace_points(validation, &mut rng);
    let valid_rows: Vec<_> = (valid_poses.iter())
        .map(|&q| feature_row(features, q, noise, &mut rng))
        .collect();
    let names: Vec<String> = (0..features).map(|i| format!("f{i}")).collect();
    let mut data = super::TrainingSet::new(
        &names,
        super::Labelled {
            poses: &poses,
            rows: &rows,
        },
    );
    data.validation = Some(super::Labelled {
        poses: &valid_poses,
        rows: &valid_rows,
    });
    let settings = super::ContinuousSettings {
        learn_threshold,
        ..super::ContinuousSettings::default()
    };
    super::Continuous::fit(&settings, &data).expect("the test maps fit")
}
