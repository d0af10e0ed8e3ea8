//! The k-nearest-neighbours baseline: standardise the features on the sample trajectory, find
//! the k sample poses whose features are nearest to the frame's, and average them.
//!
//! Behaviour worth knowing: sample rows with a missing or non-finite value are dropped (an error
//! when none remains); a frame's missing features are left out of the distances (the search runs
//! on the features present, flagged in `flags.missing`); a frame with no feature present has no
//! estimate. Ties in distance go to the lower sample index. A frame with every feature present
//! is searched through a k-d tree when one pays (`index.rs`: exact, the brute force's answer to
//! the bit); otherwise, and whenever a distance overflows, by brute force: O(n·D) per frame.
//! `detection_score` is how far the frame's standardised features (those present) lie from a
//! quadratic surface through the samples nearest its answer (`local_surface.rs`, as the GP's):
//! the nearest sample's distance barely rose when a few of many features were corrupted
//! (salt-and-pepper), since the neighbours moved to poses that absorbed them. Its nearest
//! samples come from the sample poses' buckets (`PoseBuckets`, the temporal tracker's): a few
//! buckets and O(D) more per frame.

mod index;
#[cfg(test)]
mod tests;

use crate::range::within;
use std::path::Path;

use serde::{Deserialize, Serialize};

use super::inputs::{
    check_header_features, check_training, frame_values, scaled_norm, training_header,
};
use super::local_surface::{surface_distance, LOCAL_SAMPLES};
use super::motion::{cell_variance, PoseBuckets};
use super::samples::{check_samples, kept_samples};
use super::{EstimateFlags, EstimatorError, PoseEstimate, PoseEstimator, TrainingSet};
use crate::features::FeatureConfig;
use crate::model::ModelError;
use crate::model_file::{self, corrupted, Header};
use crate::standardisation::Standardisation;

/// How the neighbours' poses are averaged.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum KnnWeights {
    /// Every neighbour counts the same.
    Uniform,
    /// Each neighbour weighs 1/d (d its feature distance); when some neighbours are at distance
    /// 0, only those count, equally.
    #[default]
    Distance,
}

/// How the k-nearest-neighbours baseline is fitted and run.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct KnnSettings {
    /// Neighbours averaged per frame (at least 1, at most the usable samples).
    pub k: usize,
    /// How they are weighted.
    pub weights: KnnWeights,
}

impl Default for KnnSettings {
    fn default() -> Self {
        Self {
            k: 6,
            weights: KnnWeights::Distance,
        }
    }
}

impl KnnSettings {
    /// Checks the settings on their own (`k` against the samples is checked when fitting).
    ///
    /// # Errors
    /// [`ModelError::Settings`] naming `knn.k` when it is 0.
    pub fn check(&self) -> Result<(), EstimatorError> {
        within(self.k, 1..=10_000).map_err(|reason| ModelError::Settings {
            field: "knn.k",
            reason,
        })?;
        Ok(())
    }
}

/// The k-nearest-neighbours baseline, fitted.
///
/// Estimate: the weighted mean of the k nearest sample poses in standardised feature space
/// (Euclidean, over the frame's present features). `uncertainty_radius`: the weighted RMS
/// distance of those poses from the estimate (with the estimate's weights; 0 when every weight
/// sits on one pose). Covariance: their weighted second moments plus the variance of the poses
/// each sample pose stands for, s²/12 per axis for a typical spacing s (so a frame whose weight
/// sits on one sample still states that sample's cell). Detection score: see the module
/// documentation. No group, no conflict level.
#[derive(Debug, Clone)]
pub struct Knn {
    file: KnnFile,
    /// Standardised sample features, row-major.
    inputs: Vec<f64>,
    /// The tree over them, where one pays.
    index: Option<index::Index>,
    /// The sample poses in cells, for the detection score's nearest samples.
    grid: PoseBuckets,
    /// The variance per axis of the poses a sample pose stands for (mm²,
    /// [`super::motion::cell_variance`]).
    cell_variance: f64,
}

/// The model file, and the fitted state.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct KnnFile {
    #[serde(flatten)]
    header: Header,
    settings: KnnSettings,
    standardisation: Standardisation,
    /// The kept samples' poses (mm).
    sample_poses: Vec<[f64; 2]>,
    /// Their raw feature values, one row per pose.
    sample_features: Vec<Vec<f64>>,
}

impl Knn {
    /// Version of the model file format this build writes and reads. 2: the detection score is
    /// the local plane's (issue 27); a version-1 file's calibrated abstention limit was set on
    /// the nearest distance, so it is refused rather than compared with the new score. 3: the
    /// covariance adds the sample poses' cells, which a version-2 file's radius was learned
    /// without. 4: the local surface is quadratic, through 16 samples; a version-3 file's
    /// limit was set on the plane's score.
    pub const FORMAT_VERSION: u32 = 4;
    /// The `method` of its model files.
    pub const METHOD: &'static str = "knn";

    /// Fits on the sample trajectory of `data` (samples with a missing value are dropped).
    ///
    /// # Errors
    /// Invalid settings, an inconsistent training set, no complete sample, or `k` above the
    /// number of complete samples.
    pub fn fit(settings: &KnnSettings, data: &TrainingSet) -> Result<Self, EstimatorError> {
        settings.check()?;
        check_training(data)?;
        let (poses, rows) = kept_samples(data, "k-NN")?;
        if settings.k > poses.len() {
            return Err(ModelError::Settings {
                field: "knn.k",
                reason: format!(
                    "{} neighbours but only {} samples have every feature value",
                    settings.k,
                    poses.len()
                ),
            }
            .into());
        }
        Ok(Self::new(KnnFile {
            header: training_header(Self::METHOD, Self::FORMAT_VERSION, data),
            settings: settings.clone(),
            standardisation: Standardisation::fit(&rows, data.feature_names.len()),
            sample_poses: poses,
            sample_features: rows,
        }))
    }

    /// The estimator of a fitted state: the same operations whether fitted or loaded.
    fn new(file: KnnFile) -> Self {
        let inputs = file.standardisation.apply_rows(&file.sample_features);
        let dim = file.header.feature_names.len();
        let mask = vec![1.0; dim];
        let index = index::Index::build(&inputs, dim, file.settings.k, |query, i| {
            squared_distance(&inputs[i * dim..(i + 1) * dim], query, &mask)
        });
        Self {
            grid: PoseBuckets::new(&file.sample_poses),
            cell_variance: cell_variance(&file.sample_poses),
            file,
            inputs,
            index,
        }
    }

    /// The settings it was fitted with.
    pub fn settings(&self) -> &KnnSettings {
        &self.file.settings
    }

    /// The sample poses it searches (the complete samples of the training trajectory).
    pub fn sample_poses(&self) -> &[[f64; 2]] {
        &self.file.sample_poses
    }

    /// The k nearest samples to a frame: `(sample index, distance)` by increasing distance,
    /// ties to the lower index; empty when no feature is present.
    ///
    /// # Errors
    /// [`EstimatorError::FeatureCount`] when `features` does not have one value per feature.
    pub fn neighbours(
        &self,
        features: &[Option<f64>],
    ) -> Result<Vec<(usize, f64)>, EstimatorError> {
        Ok(match self.query(features)? {
            Some((query, mask, complete)) => self.nearest(&query, &mask, complete),
            None => Vec::new(),
        })
    }

    /// The k nearest samples to a standardised query (see [`Knn::neighbours`]).
    fn nearest(&self, query: &[f64], mask: &[f64], complete: bool) -> Vec<(usize, f64)> {
        let dim = self.file.header.feature_names.len();
        let k = self.file.settings.k;
        if let (true, Some(index)) = (complete, &self.index) {
            let row = |i: usize| &self.inputs[i * dim..(i + 1) * dim];
            let found = index.nearest(query, k, |i| squared_distance(row(i), query, mask));
            if let Some((best, _)) = found {
                return best.into_iter().map(|(d2, i)| (i, d2.sqrt())).collect();
            }
        }
        self.brute_force(query, mask)
    }

    /// A frame's standardised values, the mask of its present features (1, or 0 for missing)
    /// and whether every feature is present; `None` when none is.
    #[allow(clippy::type_complexity)]
    fn query(
        &self,
        features: &[Option<f64>],
    ) -> Result<Option<(Vec<f64>, Vec<f64>, bool)>, EstimatorError> {
        let dim = self.file.header.feature_names.len();
        let (values, missing) = frame_values(features, dim)?;
        if missing.len() == dim {
            return Ok(None);
        }
        // A missing feature gets weight 0: same sum, one branch-free loop.
        let mut query = vec![0.0; dim];
        let mut mask = vec![0.0; dim];
        for (d, v) in values.iter().enumerate() {
            if let Some(x) = v {
                query[d] = self.file.standardisation.apply(d, *x);
                mask[d] = 1.0;
            }
        }
        Ok(Some((query, mask, missing.is_empty())))
    }

    /// The k nearest samples by scanning them all (see [`Knn::neighbours`]); a missing
    /// feature has weight 0 in `mask`.
    fn brute_force(&self, query: &[f64], mask: &[f64]) -> Vec<(usize, f64)> {
        let (k, dim) = (self.file.settings.k, query.len());
        // (squared distance, distance when the square overflowed, sample index).
        let mut best: Vec<(f64, f64, usize)> = Vec::with_capacity(k + 1);
        for (i, row) in self.inputs.chunks_exact(dim).enumerate() {
            let d2 = squared_distance(row, query, mask);
            // A frame far beyond the samples (a fault of 1e200) overflows the square: rank by
            // the distance itself, after every finite square.
            let key = if d2.is_finite() {
                (d2, 0.0)
            } else {
                let terms =
                    (row.iter().zip(query).zip(mask))
                        .map(|((r, q), m)| if *m > 0.0 { q - r } else { 0.0 });
                (f64::INFINITY, scaled_norm(terms))
            };
            // Samples come in index order, so a tie never displaces an earlier sample.
            if best.len() == k && key >= (best[k - 1].0, best[k - 1].1) {
                continue;
            }
            let at = best.partition_point(|b| (b.0, b.1) <= key);
            best.insert(at, (key.0, key.1, i));
            best.truncate(k);
        }
        best.into_iter()
            .map(|(d2, far, i)| (i, if d2.is_finite() { d2.sqrt() } else { far }))
            .collect()
    }

    /// Reads a model file's text, checking the header, the settings, the standardisation and
    /// the samples.
    ///
    /// # Errors
    /// [`EstimatorError::Model`] naming what is wrong.
    pub fn from_json(text: &str) -> Result<Self, EstimatorError> {
        let file: KnnFile = model_file::parse(text, Self::METHOD, Self::FORMAT_VERSION)?;
        let dim = file.header.feature_names.len();
        check_header_features(&file.header)?;
        file.settings
            .check()
            .map_err(|e| corrupted(format!("`settings`: {e}")))?;
        file.standardisation
            .check(dim, "standardisation")
            .map_err(corrupted)?;
        check_samples(&file.sample_poses, &file.sample_features, dim)?;
        (file.standardisation)
            .check_rows(&file.sample_features, "sample_features", "standardisation")
            .map_err(corrupted)?;
        file.header
            .provenance
            .check_poses("sample_poses", &file.sample_poses)?;
        if file.settings.k > file.sample_poses.len() {
            return Err(corrupted(format!(
                "`settings.k` is {} but there are {} samples",
                file.settings.k,
                file.sample_poses.len()
            ))
            .into());
        }
        Ok(Self::new(file))
    }

    /// Reads a model file written from [`PoseEstimator::to_json`].
    ///
    /// # Errors
    /// [`EstimatorError::Io`] when it cannot be read; [`EstimatorError::Model`] naming the path
    /// and what is wrong otherwise.
    pub fn load(path: &Path) -> Result<Self, EstimatorError> {
        Ok(model_file::load(path, Self::from_json)?)
    }
}

impl PoseEstimator for Knn {
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
        let (_, missing) = frame_values(features, self.file.header.feature_names.len())?;
        let query = self.query(features)?;
        let neighbours = match &query {
            Some((query, mask, complete)) => self.nearest(query, mask, *complete),
            None => Vec::new(),
        };
        let weights: Vec<f64> = match self.file.settings.weights {
            KnnWeights::Uniform => vec![1.0; neighbours.len()],
            KnnWeights::Distance if neighbours.iter().any(|n| n.1 == 0.0) => neighbours
                .iter()
                .map(|n| if n.1 == 0.0 { 1.0 } else { 0.0 })
                .collect(),
            KnnWeights::Distance => neighbours.iter().map(|n| 1.0 / n.1).collect(),
        };
        let total: f64 = weights.iter().sum();
        let (pose, radius, covariance) =
            if neighbours.is_empty() || !(total > 0.0 && total.is_finite()) {
                (None, None, None)
            } else {
                let mut mean = [0.0; 2];
                for (&(i, _), w) in neighbours.iter().zip(&weights) {
                    for (m, p) in mean.iter_mut().zip(self.file.sample_poses[i]) {
                        *m += w * p;
                    }
                }
                let mean = mean.map(|m| m / total);
                let mut moments = [[0.0; 2]; 2];
                for (&(i, _), w) in neighbours.iter().zip(&weights) {
                    let p = self.file.sample_poses[i];
                    let d = [p[0] - mean[0], p[1] - mean[1]];
                    for (row, a) in moments.iter_mut().zip(d) {
                        for (m, b) in row.iter_mut().zip(d) {
                            *m += w * a * b / total;
                        }
                    }
                }
                let spread = (moments[0][0] + moments[1][1]).sqrt();
                moments[0][0] += self.cell_variance;
                moments[1][1] += self.cell_variance;
                (Some(mean), Some(spread), Some(moments))
            };
        // How far the frame lies from the samples at its answer, over its present features.
        let score = pose.zip(query).map(|(pose, (query, mask, _))| {
            surface_distance(
                &query,
                Some(&mask),
                pose,
                &self.file.sample_poses,
                &self.inputs,
                &self.grid.nearest(pose, LOCAL_SAMPLES),
            )
        });
        Ok(PoseEstimate {
            detection_score: score,
            pose,
            uncertainty_radius: radius,
            group: None,
            conflict_level: None,
            region: None,
            covariance,
            flags: EstimateFlags {
                missing,
                ..EstimateFlags::default()
            },
        })
    }

    fn to_json(&self) -> Result<String, EstimatorError> {
        Ok(model_file::to_text(&self.file)?)
    }
}

/// The squared distance of a sample row from a query over the features `mask` weighs 1: the
/// one formula both searches rank by, so they agree to the bit.
fn squared_distance(row: &[f64], query: &[f64], mask: &[f64]) -> f64 {
    row.iter()
        .zip(query)
        .zip(mask)
        .map(|((r, q), m)| m * (q - r) * (q - r))
        .sum()
}

/// The scenario checks of k-NN: its `[knn]` section.
pub(crate) fn check_settings(
    settings: &super::EstimatorSettings,
    _context: &super::SettingsContext,
) -> Result<(), String> {
    settings.knn.check().map_err(|e| format!("[knn]: {e}"))
}
