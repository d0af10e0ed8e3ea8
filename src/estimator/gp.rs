//! The Gaussian-process baseline: regression of the pose on the standardised features with one
//! ARD squared-exponential kernel shared by both coordinates,
//! k(x, x′) = σf² exp(−½ Σ_d (x_d − x′_d)²/ℓ_d²) + σn² δ, hyperparameters fitted by maximising
//! the two coordinates' summed log marginal likelihood (analytic gradients, projected L-BFGS in
//! log space, deterministic starts) on at most `max_fit_samples` evenly spaced samples, then the
//! kernel matrix factored once on every sample.
//!
//! Behaviour worth knowing: sample rows with a missing or non-finite value are dropped (an error
//! when none remains); the GP needs every feature, so a frame with any missing feature has no
//! estimate (flagged in `flags.missing`). `uncertainty_radius` is the radius of the 90 % disc of
//! an isotropic 2-D Gaussian whose per-axis standard deviation is the RMS over x and y of the
//! predictive standard deviation (latent variance plus noise), in mm. `detection_score` is how
//! far the frame's standardised features lie from those the samples show at the estimate (every
//! feature alike, see `local_surface.rs`), so a corrupted feature the kernel ignores still
//! raises it. Fitting costs O(m³) per optimiser step (m ≤ `max_fit_samples`) and O(n³) once; a
//! frame costs O(n·D) for the mean and the score and O(n²) for the variance.

use crate::range::within;
use std::path::Path;

use nalgebra::DMatrix;
use serde::{Deserialize, Serialize};

use super::inputs::{check_header_features, check_training, frame_values, training_header};
use super::local_surface::{nearest_by_scan, surface_distance};
use super::samples::{check_exact_gp_count, check_samples, kept_samples};
use super::{EstimateFlags, EstimatorError, PoseEstimate, PoseEstimator, TrainingSet};
use crate::features::FeatureConfig;
use crate::gaussian_process::{cholesky, dot, minimise, Objective, LOG_LENGTH};
use crate::model::ModelError;
use crate::model_file::{self, check_finite, corrupted, Header, Provenance};
use crate::standardisation::Standardisation;

/// Jitter tried, relative to σf², when the final factorisation fails.
const JITTERS: [f64; 9] = [1e-10, 1e-9, 1e-8, 1e-7, 1e-6, 1e-5, 1e-4, 1e-3, 1e-2];
/// The 90 % disc of an isotropic 2-D Gaussian has radius σ·√(−2 ln 0.1).
const DISC_90: f64 = 2.145_966_026_289_347;

/// How the Gaussian-process baseline is fitted.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct GpSettings {
    /// At most this many samples (evenly spaced along the trajectory) fit the hyperparameters.
    pub max_fit_samples: usize,
    /// Most optimiser iterations per start (0: keep the initial hyperparameters).
    pub iterations: usize,
    /// Optimiser starts (at least 1): start s multiplies the initial length scale by 4^±⌈s/2⌉
    /// (1, ¼, 4, 1/16 …); the best log marginal likelihood wins.
    pub starts: usize,
    /// Initial length scale of every standardised feature.
    pub initial_length_scale: f64,
    /// Initial noise standard deviation, relative to the standardised outputs (σf starts at 1).
    pub initial_noise: f64,
}

impl Default for GpSettings {
    fn default() -> Self {
        Self {
            max_fit_samples: 400,
            iterations: 200,
            starts: 2,
            initial_length_scale: 1.0,
            initial_noise: 0.1,
        }
    }
}

impl GpSettings {
    /// Checks the settings.
    ///
    /// # Errors
    /// [`ModelError::Settings`] naming the field (`gp.…`) that is out of range.
    pub fn check(&self) -> Result<(), EstimatorError> {
        let bad = |field, reason: &str| {
            Err(ModelError::Settings {
                field,
                reason: reason.into(),
            }
            .into())
        };
        for (field, value, range) in [
            ("gp.max_fit_samples", self.max_fit_samples, 1..=5000),
            ("gp.iterations", self.iterations, 0..=10_000),
            ("gp.starts", self.starts, 1..=20),
        ] {
            within(value, range).map_err(|reason| ModelError::Settings { field, reason })?;
        }
        let (lo, hi) = (LOG_LENGTH.0.exp(), LOG_LENGTH.1.exp());
        if !(self.initial_length_scale >= lo && self.initial_length_scale <= hi) {
            return bad("gp.initial_length_scale", "must be in 0.01..=1000");
        }
        if !(self.initial_noise >= 1e-6 && self.initial_noise <= 10.0) {
            return bad("gp.initial_noise", "must be in 1e-6..=10");
        }
        Ok(())
    }
}

/// Fitted kernel hyperparameters, in standardised units (features and pose coordinates scaled
/// to unit standard deviation on the samples).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GpHyperparameters {
    /// Length scale ℓ_d of each feature.
    pub length_scales: Vec<f64>,
    /// Signal standard deviation σf.
    pub signal_std: f64,
    /// Noise standard deviation σn.
    pub noise_std: f64,
}

/// The Gaussian-process baseline, fitted (see the module documentation).
#[derive(Debug, Clone)]
pub struct Gp {
    file: GpFile,
    factor: Factor,
}

/// What prediction needs, recomputed from the stored state by the same operations.
#[derive(Debug, Clone)]
struct Factor {
    /// Standardised sample features divided by the length scales, row-major.
    inputs: Vec<f64>,
    /// Lower Cholesky factor of the kernel matrix, row-major n×n.
    lower: Vec<f64>,
    /// K⁻¹y for each scaled output, per sample.
    alpha: Vec<[f64; 2]>,
    /// σn² plus any jitter the factorisation needed.
    noise_var: f64,
    /// Standardised sample features (every feature weighs the same), row-major.
    standard: Vec<f64>,
}

/// The model file, and the fitted state.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct GpFile {
    #[serde(flatten)]
    header: Header,
    settings: GpSettings,
    standardisation: Standardisation,
    /// Centring and scaling of the pose coordinates (x, y).
    output: Standardisation,
    hyperparameters: GpHyperparameters,
    /// On the fit samples, summed over the two coordinates (standardised units).
    log_marginal_likelihood: f64,
    /// The kept samples' poses (mm) and raw feature values.
    sample_poses: Vec<[f64; 2]>,
    sample_features: Vec<Vec<f64>>,
}

impl Gp {
    /// Version of the model file format this build writes and reads. 2: the detection score is
    /// the local plane's (issue 27); a version-1 file's calibrated abstention limit was set on
    /// the nearest sample's ARD-scaled distance, so it is refused rather than compared with the new score.
    /// 3: the local surface is quadratic, through 16 samples; a version-2 file's limit was set
    /// on the plane's score.
    pub const FORMAT_VERSION: u32 = 3;
    /// The `method` of its model files.
    pub const METHOD: &'static str = "gp";

    /// Fits on the sample trajectory of `data` (samples with a missing value are dropped).
    ///
    /// # Errors
    /// Invalid settings, an inconsistent training set, no complete sample, or a kernel matrix
    /// that stays singular even with jitter.
    pub fn fit(settings: &GpSettings, data: &TrainingSet) -> Result<Self, EstimatorError> {
        settings.check()?;
        check_training(data)?;
        let (poses, rows) = kept_samples(data, "the Gaussian process")?;
        check_exact_gp_count(poses.len(), "gp")?;
        let dim = data.feature_names.len();
        let standardisation = Standardisation::fit(&rows, dim);
        let output = Standardisation::fit(&pose_rows(&poses), 2);
        let (n, m) = (poses.len(), poses.len().min(settings.max_fit_samples));
        let subset: Vec<usize> = (0..m).map(|i| i * n / m).collect();
        let inputs = standardisation.apply_rows(&rows);
        let outputs = output.apply_rows(&pose_rows(&poses));
        let objective = Objective::new(&inputs, &outputs, dim, &subset);
        // One thread per start; the best value wins, ties to the earlier start.
        let found: Vec<Option<(Vec<f64>, f64)>> = std::thread::scope(|scope| {
            let handles: Vec<_> = (0..settings.starts)
                .map(|s| {
                    let power = s.div_ceil(2) as f64 * if s % 2 == 1 { -1.0 } else { 1.0 };
                    let length = (settings.initial_length_scale * 4f64.powf(power)).ln();
                    let mut start = vec![length; dim];
                    start.extend([0.0, settings.initial_noise.ln()]);
                    let objective = &objective;
                    scope.spawn(move || minimise(objective, start, settings.iterations))
                })
                .collect();
            let joined = handles.into_iter().map(|h| h.join().ok().flatten());
            joined.collect()
        });
        let mut best: Option<(Vec<f64>, f64)> = None;
        for candidate in found.into_iter().flatten() {
            if best.as_ref().is_none_or(|b| candidate.1 < b.1) {
                best = Some(candidate);
            }
        }
        let (theta, value) = best.ok_or_else(|| {
            EstimatorError::Training(
                "the Gaussian process's kernel matrix is singular at every start: \
                 raise gp.initial_noise"
                    .into(),
            )
        })?;
        let file = GpFile {
            header: training_header(Self::METHOD, Self::FORMAT_VERSION, data),
            settings: settings.clone(),
            standardisation,
            output,
            hyperparameters: GpHyperparameters {
                length_scales: theta[..dim].iter().map(|t| t.exp()).collect(),
                signal_std: theta[dim].exp(),
                noise_std: (theta[dim] + theta[dim + 1]).exp(),
            },
            log_marginal_likelihood: -value * m as f64,
            sample_poses: poses,
            sample_features: rows,
        };
        Self::factor(file).map_err(EstimatorError::Training)
    }

    /// The estimator of a fitted state: the same operations whether fitted or loaded.
    fn factor(file: GpFile) -> Result<Self, String> {
        let factor = Factor::new(
            &file.standardisation.apply_rows(&file.sample_features),
            &file.output.apply_rows(&pose_rows(&file.sample_poses)),
            &file.hyperparameters,
        )?;
        Ok(Self { file, factor })
    }

    /// The settings it was fitted with.
    pub fn settings(&self) -> &GpSettings {
        &self.file.settings
    }

    /// The fitted hyperparameters (standardised units).
    pub fn hyperparameters(&self) -> &GpHyperparameters {
        &self.file.hyperparameters
    }

    /// The log marginal likelihood the hyperparameters reached on the fit samples (summed over
    /// x and y, standardised units).
    pub fn log_marginal_likelihood(&self) -> f64 {
        self.file.log_marginal_likelihood
    }

    /// The samples it regresses on (the complete samples of the training trajectory).
    pub fn sample_poses(&self) -> &[[f64; 2]] {
        &self.file.sample_poses
    }

    /// Reads a model file's text, checking the header, settings, standardisations,
    /// hyperparameters and samples, then factors the kernel matrix as fitting did.
    ///
    /// # Errors
    /// [`EstimatorError::Model`] naming what is wrong.
    pub fn from_json(text: &str) -> Result<Self, EstimatorError> {
        let file: GpFile = model_file::parse(text, Self::METHOD, Self::FORMAT_VERSION)?;
        let dim = file.header.feature_names.len();
        check_header_features(&file.header)?;
        file.settings
            .check()
            .map_err(|e| corrupted(format!("`settings`: {e}")))?;
        file.standardisation
            .check(dim, "standardisation")
            .map_err(corrupted)?;
        file.output.check(2, "output").map_err(corrupted)?;
        file.header
            .provenance
            .check_poses("sample_poses", &file.sample_poses)?;
        let h = &file.hyperparameters;
        if h.length_scales.len() != dim {
            return Err(corrupted(format!(
                "`hyperparameters.length_scales` has {} values for {dim} features",
                h.length_scales.len()
            ))
            .into());
        }
        let named = (h.length_scales.iter().enumerate())
            .map(|(d, &v)| (format!("hyperparameters.length_scales[{d}]"), v))
            .chain([
                ("hyperparameters.signal_std".to_string(), h.signal_std),
                ("hyperparameters.noise_std".to_string(), h.noise_std),
            ]);
        for (field, v) in named {
            if !(v.is_finite() && v > 0.0) {
                return Err(corrupted(format!("`{field}` is {v}, not a positive number")).into());
            }
        }
        check_finite("log_marginal_likelihood", &[file.log_marginal_likelihood])?;
        check_samples(&file.sample_poses, &file.sample_features, dim)?;
        (file.standardisation)
            .check_rows(&file.sample_features, "sample_features", "standardisation")
            .and_then(|()| (file.output).check_rows(&file.sample_poses, "sample_poses", "output"))
            .map_err(corrupted)?;
        Ok(Self::factor(file).map_err(corrupted)?)
    }

    /// Reads a model file written from [`PoseEstimator::to_json`].
    ///
    /// # Errors
    /// [`EstimatorError::Io`] when it cannot be read; [`EstimatorError::Model`] naming the path
    /// and what is wrong otherwise.
    pub fn load(path: &Path) -> Result<Self, EstimatorError> {
        Ok(model_file::load(path, Self::from_json)?)
    }

    /// Predictive mean (mm), the RMS over x and y of the predictive standard deviation (mm) and
    /// the detection score ([`surface_distance`]), for a complete row of feature values.
    fn predict(&self, values: &[f64]) -> ([f64; 2], f64, f64) {
        let (f, h, file) = (&self.factor, &self.file.hyperparameters, &self.file);
        let standard: Vec<f64> = (values.iter().enumerate())
            .map(|(d, &x)| file.standardisation.apply(d, x))
            .collect();
        let query: Vec<f64> = (standard.iter().zip(&h.length_scales))
            .map(|(z, l)| z / l)
            .collect();
        let sf2 = h.signal_std * h.signal_std;
        let kstar: Vec<f64> = (f.inputs.chunks_exact(values.len()))
            .map(|row| sf2 * (-0.5 * squared_distance(row, &query)).exp())
            .collect();
        let mut mean = [0.0; 2];
        for (k, a) in kstar.iter().zip(&f.alpha) {
            mean[0] += k * a[0];
            mean[1] += k * a[1];
        }
        // v = L⁻¹k*, by forward substitution on the row-major factor.
        let n = kstar.len();
        let mut v = vec![0.0; n];
        for i in 0..n {
            let dot = fast_dot(&f.lower[i * n..i * n + i], &v[..i]);
            v[i] = (kstar[i] - dot) / f.lower[i * n + i];
        }
        let latent = (sf2 - fast_dot(&v, &v)).max(0.0);
        let std = (latent + f.noise_var).sqrt();
        let (means, scales) = (&file.output.means, &file.output.scales);
        let pose = [
            means[0] + scales[0] * mean[0],
            means[1] + scales[1] * mean[1],
        ];
        (
            pose,
            std * (0.5 * (scales[0].powi(2) + scales[1].powi(2))).sqrt(),
            {
                let near = nearest_by_scan(pose, &file.sample_poses);
                surface_distance(
                    &standard,
                    None,
                    pose,
                    &file.sample_poses,
                    &f.standard,
                    &near,
                )
            },
        )
    }
}

impl PoseEstimator for Gp {
    fn method(&self) -> &'static str {
        Self::METHOD
    }

    fn feature_names(&self) -> &[String] {
        &self.file.header.feature_names
    }

    fn feature_config(&self) -> Option<&FeatureConfig> {
        self.file.header.feature_config.as_ref()
    }

    fn estimate(&self, features: &[Option<f64>]) -> Result<PoseEstimate, EstimatorError> {
        let (values, missing) = frame_values(features, self.file.header.feature_names.len())?;
        let (pose, std, score) = if missing.is_empty() {
            let values: Vec<f64> = values.iter().map(|v| v.unwrap_or(0.0)).collect();
            let (pose, std, score) = self.predict(&values);
            (Some(pose), Some(std), Some(score))
        } else {
            (None, None, None)
        };
        Ok(PoseEstimate {
            detection_score: score,
            pose,
            uncertainty_radius: std.map(|s| s * DISC_90),
            group: None,
            conflict_level: None,
            region: None,
            // The same predictive variance for both coordinates (one kernel).
            covariance: std.map(|s| [[s * s, 0.0], [0.0, s * s]]),
            flags: EstimateFlags {
                missing,
                ..EstimateFlags::default()
            },
        })
    }

    fn to_json(&self) -> Result<String, EstimatorError> {
        Ok(model_file::to_text(&self.file)?)
    }

    fn with_provenance(&self, provenance: &Provenance) -> Option<Box<dyn PoseEstimator>> {
        let mut copy = self.clone();
        copy.file.header.provenance = provenance.clone();
        Some(Box::new(copy))
    }
}

fn pose_rows(poses: &[[f64; 2]]) -> Vec<Vec<f64>> {
    poses.iter().map(|p| p.to_vec()).collect()
}

/// A dot product with four running sums (one sum would be a chain of dependent additions).
fn fast_dot(a: &[f64], b: &[f64]) -> f64 {
    let mut sums = [0.0; 4];
    let (a4, b4) = (a.chunks_exact(4), b.chunks_exact(4));
    let tail: f64 = dot(a4.remainder(), b4.remainder());
    for (x, y) in a4.zip(b4) {
        for k in 0..4 {
            sums[k] += x[k] * y[k];
        }
    }
    (sums[0] + sums[1]) + (sums[2] + sums[3]) + tail
}

fn squared_distance(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum()
}

impl Factor {
    /// Factors the kernel matrix of standardised `inputs` (row-major) and solves for the two
    /// scaled `outputs` (row-major, 2 per sample), adding jitter if the factorisation fails.
    fn new(inputs: &[f64], outputs: &[f64], hyper: &GpHyperparameters) -> Result<Self, String> {
        let dim = hyper.length_scales.len();
        let standard = inputs.to_vec();
        let inputs: Vec<f64> = inputs
            .chunks_exact(dim)
            .flat_map(|row| row.iter().zip(&hyper.length_scales).map(|(z, l)| z / l))
            .collect();
        let n = inputs.len() / dim;
        let sf2 = hyper.signal_std * hyper.signal_std;
        let mut kernel = DMatrix::zeros(n, n);
        for j in 0..n {
            let b = &inputs[j * dim..(j + 1) * dim];
            for i in 0..j {
                let k = sf2 * (-0.5 * squared_distance(&inputs[i * dim..(i + 1) * dim], b)).exp();
                kernel[(i, j)] = k;
                kernel[(j, i)] = k;
            }
        }
        let y = DMatrix::from_row_slice(n, 2, outputs);
        let base = hyper.noise_std * hyper.noise_std;
        for noise_var in std::iter::once(base).chain(JITTERS.iter().map(|j| base + j * sf2)) {
            let mut k = kernel.clone();
            for i in 0..n {
                k[(i, i)] = sf2 + noise_var;
            }
            if let Some(chol) = cholesky(k) {
                let alpha = chol.solve(&y);
                let l = chol.l_dirty();
                let mut lower = vec![0.0; n * n];
                for i in 0..n {
                    for j in 0..=i {
                        lower[i * n + j] = l[(i, j)];
                    }
                }
                return Ok(Self {
                    inputs,
                    lower,
                    alpha: (0..n).map(|i| [alpha[(i, 0)], alpha[(i, 1)]]).collect(),
                    noise_var,
                    standard,
                });
            }
        }
        Err("the kernel matrix is not positive definite, even with jitter of 1e-2 σf²".into())
    }
}

/// The scenario checks of the Gaussian process: its `[gp]` section.
pub(crate) fn check_settings(
    settings: &super::EstimatorSettings,
    _context: &super::SettingsContext,
) -> Result<(), String> {
    settings.gp.check().map_err(|e| format!("[gp]: {e}"))
}

#[cfg(test)]
#[path = "gp_tests.rs"]
mod tests;
