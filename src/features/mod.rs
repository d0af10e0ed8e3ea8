//! Image → scalar features. This room sees grey images only, never ground truth.
//!
//! A [`Feature`] is a named extractor giving one or more scalar values per image, each of which
//! may be missing (`None`, e.g. an empty silhouette). A [`FeatureSet`] is an ordered list of
//! extractors built from a [`FeatureConfig`] (or from your own [`Feature`]s), so a new feature is
//! added without touching the tracker.
//!
//! The paper's features (§6.1): the silhouette's outer contour ([`silhouette`]) measured by the
//! unsigned distance from each of `k` lines through the silhouette centroid, each turned into a
//! size function whose table mean over a fixed window is one scalar ([`size`]); optionally the
//! intensity barycentre ([`mod@barycentre`]). [`mesh`] checks the paper's condition 2 on a mesh of
//! poses; [`synthetic`] draws test frames.
//!
//! Conventions: pixel coordinates, `x` = column, `y` = row (downwards), pixel centres at integers.
//! Line `i` of `k` has direction angle `i · 180° / k` from +x toward +y.

pub mod barycentre;
pub mod external;
pub mod mesh;
pub mod silhouette;
pub mod size;
pub mod synthetic;
pub mod tiles;

use std::fmt;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;

use image::GrayImage;
use serde::{Deserialize, Serialize};

pub use barycentre::{barycentre, Background};
pub use external::{ExternalFeatureConfig, MissingValues};
pub use mesh::{analyse_mesh, FeatureSmoothness, MeshAnalysis, MeshOrder};
pub use silhouette::{
    extract_silhouette, silhouette_and_stray, silhouette_pixels, Polarity, Silhouette,
    SilhouetteConfig, Threshold,
};
pub use size::{distance_from_line, PersistenceDiagram, SizeTable, Window};
pub use tiles::{TileConfig, TileFeature, MAX_TILES};

/// Feature values of a dataset's frames: one row per frame, one value per feature (`None` when
/// missing).
pub type FeatureRows = Vec<Vec<Option<f64>>>;

/// What went wrong in feature configuration or computation.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum FeatureError {
    /// An external feature program's settings are wrong.
    #[error("feature program `{program}`: {reason}")]
    BadProgram {
        /// Its command line.
        program: String,
        /// What is wrong and how to fix it.
        reason: String,
    },
    /// The size-function window is empty, reversed or not finite.
    #[error(
        "size-function window [{a}, {b}] is invalid: give finite a < b in pixels, e.g. [0, 128]"
    )]
    BadWindow {
        /// Lower end given.
        a: f64,
        /// Upper end given.
        b: f64,
    },
    /// The size-function table grid is out of range.
    #[error("size-function table grid {grid} is out of range: use 2 to 4096 (e.g. 64)")]
    BadGrid {
        /// Grid given.
        grid: usize,
    },
    /// The number of sheaf lines is out of range.
    #[error("number of sheaf lines {lines} is out of range: use 1 to 360 (the paper uses 6)")]
    BadLines {
        /// Lines given.
        lines: usize,
    },
    /// The silhouette contrast guard is not a finite, non-negative number.
    #[error(
        "silhouette min_contrast {min_contrast} is invalid: use a finite value ≥ 0 (grey levels)"
    )]
    BadContrast {
        /// Value given.
        min_contrast: f64,
    },
    /// The tile features' settings are wrong.
    #[error("[features.tiles]: {reason}")]
    BadTiles {
        /// What is wrong and how to fix it.
        reason: String,
    },
    /// No feature is enabled.
    #[error("the feature set is empty: enable size_functions, barycentre and/or tiles")]
    NoFeatures,
    /// Two values share a name.
    #[error("feature name {name:?} appears twice: names must be unique")]
    DuplicateName {
        /// The repeated name.
        name: String,
    },
    /// A NaN or infinite number where a finite one is needed.
    #[error("{what} at index {index} is not finite: remove NaN/inf values first")]
    NonFinite {
        /// What the number was.
        what: &'static str,
        /// Where it was.
        index: usize,
    },
    /// The mesh does not have `nx · ny` nodes.
    #[error("mesh of {nx} × {ny} needs {} feature vectors, got {got}", nx.saturating_mul(*ny))]
    MeshSize {
        /// Nodes along x.
        nx: usize,
        /// Nodes along y.
        ny: usize,
        /// Vectors given.
        got: usize,
    },
    /// Feature vectors of unequal length.
    #[error(
        "feature vector {index} has {got} values, the first has {expected}: give equal lengths"
    )]
    RaggedValues {
        /// Which vector.
        index: usize,
        /// Length of the first vector.
        expected: usize,
        /// Its length.
        got: usize,
    },
    /// A negative or non-finite tolerance.
    #[error("tolerance {tolerance} is invalid: use a finite value ≥ 0 (fraction of the range)")]
    BadTolerance {
        /// Value given.
        tolerance: f64,
    },
    /// A negative or non-finite noise level.
    #[error("noise sigma {sigma} is invalid: use a finite value ≥ 0 (grey levels)")]
    BadNoise {
        /// Value given.
        sigma: f64,
    },
    /// The synthetic rig cannot reach a position.
    #[error(
        "the synthetic rig cannot reach {pose_mm:?} mm: stay inside x ∈ [−9.5, 9.5], y ∈ [38, 57]"
    )]
    Unreachable {
        /// The position asked for.
        pose_mm: [f64; 2],
    },
}

/// A named extractor: image → one or more named scalar values, each possibly missing.
///
/// Implementations must append exactly `names().len()` values to `out`, in the order of
/// `names()`; [`FeatureSet`] pads or truncates a misbehaving extractor to that length and turns
/// non-finite values into `None`.
pub trait Feature: fmt::Debug + Send + Sync {
    /// Stable, unique names of the values, in output order.
    fn names(&self) -> Vec<String>;
    /// Append this extractor's values for `image` to `out`.
    fn extract(&self, image: &GrayImage, out: &mut Vec<Option<f64>>);
}

/// How a size-function table is reduced to one number.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MeanMethod {
    /// Exact mean over the triangle `a ≤ x < y ≤ b`: `Σ sᵢ² / (b − a)²` (default, fast).
    #[default]
    ClosedForm,
    /// Mean of the `G × G` table over its cells with `x < y` (the paper's table, O(1/G) from the
    /// closed form).
    Table,
}

/// Settings of the size-function features.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SizeFunctionConfig {
    /// Whether these features are computed (default true).
    pub enabled: bool,
    /// Number of sheaf lines `k` (default 6, as in the paper); one feature per line.
    pub lines: usize,
    /// Fixed window `[a, b]` in pixels (default `[0, 128]`). Never normalised per image.
    pub window: [f64; 2],
    /// Closed form (default) or table mean.
    pub mean: MeanMethod,
    /// Table grid `G` for [`MeanMethod::Table`] (default 64, 2 to 4096).
    pub table_grid: usize,
    /// Signed distance from the line instead of the unsigned one (default false). With signed
    /// distances use a window around 0, e.g. `[-128, 128]`.
    pub signed: bool,
}

impl Default for SizeFunctionConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            lines: 6,
            window: [0.0, 128.0],
            mean: MeanMethod::ClosedForm,
            table_grid: 64,
            signed: false,
        }
    }
}

/// Settings of the barycentre features.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct BarycentreConfig {
    /// Whether `barycentre_x`, `barycentre_y` are computed (default false: the paper's 6).
    pub enabled: bool,
    /// Background subtraction (default: median plus four robust noise deviations).
    pub background: Background,
}

impl Default for BarycentreConfig {
    fn default() -> Self {
        Self {
            enabled: false,
            background: Background::MedianPlusNoise,
        }
    }
}

/// Which features to compute and how. `Default` is the paper's 6 size functions;
/// [`FeatureConfig::with_barycentre`] adds the barycentre (8 features).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FeatureConfig {
    /// Body brightness relative to the background (default bright on dark).
    pub polarity: Polarity,
    /// Silhouette extraction.
    pub silhouette: SilhouetteConfig,
    /// Size functions on the sheaf of lines.
    pub size_functions: SizeFunctionConfig,
    /// Intensity barycentre.
    pub barycentre: BarycentreConfig,
    /// Local features: body share per tile (`[features.tiles]`, after the barycentre); left out
    /// of the written form when off, so older files keep their bytes.
    #[serde(skip_serializing_if = "tiles::is_off")]
    pub tiles: TileConfig,
    /// Programs in any language whose values follow the built-in ones (`[[features.external]]`);
    /// left out of the written form when there is none, so older files keep their bytes.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub external: Vec<ExternalFeatureConfig>,
}

impl FeatureConfig {
    /// The 8-feature preset: 6 size functions, then `barycentre_x`, `barycentre_y`.
    pub fn with_barycentre() -> Self {
        let mut c = Self::default();
        c.barycentre.enabled = true;
        c
    }

    /// Validate the settings and build the feature set.
    pub fn check(&self) -> Result<FeatureSet, FeatureError> {
        let mut features: Vec<Arc<dyn Feature>> = Vec::new();
        let mc = self.silhouette.min_contrast;
        if !(mc.is_finite() && mc >= 0.0) {
            return Err(FeatureError::BadContrast { min_contrast: mc });
        }
        let sf = &self.size_functions;
        if sf.enabled {
            if !(1..=360).contains(&sf.lines) {
                return Err(FeatureError::BadLines { lines: sf.lines });
            }
            let window = Window::new(sf.window[0], sf.window[1])?;
            if sf.mean == MeanMethod::Table && !(2..=4096).contains(&sf.table_grid) {
                return Err(FeatureError::BadGrid {
                    grid: sf.table_grid,
                });
            }
            features.push(Arc::new(SizeFunctionFeature {
                polarity: self.polarity,
                silhouette: self.silhouette.clone(),
                lines: sf.lines,
                window,
                mean: sf.mean,
                table_grid: sf.table_grid,
                signed: sf.signed,
            }));
        }
        if self.barycentre.enabled {
            features.push(Arc::new(BarycentreFeature {
                polarity: self.polarity,
                background: self.barycentre.background,
            }));
        }
        if self.tiles.enabled {
            features.push(Arc::new(self.tiles.check(self.polarity)?));
        }
        let mut set = FeatureSet::new(features)?;
        for program in &self.external {
            program.check()?;
            set.names.extend(program.values.iter().cloned());
        }
        set.external = self.external.clone();
        set.check_unique()?;
        Ok(FeatureSet {
            polarity: Some(self.polarity),
            ..set
        })
    }
}

/// The size functions of the silhouette contour under "distance from a line" for a sheaf of
/// lines through the silhouette centroid: values `size_line0 … size_line{k−1}`.
///
/// Unsigned distance is the default: it is the "distance from a line" of the paper, symmetric
/// under a half turn of the line, so `k` lines over 180° are the whole sheaf, and its diagram
/// sees both sides of the line (two zero crossings are born at ~0; the finite pairs die at the
/// side extents, which move with the links' pose while the essential class stays put). On the
/// rig-like mesh the six unsigned features tell far more nodes apart from their neighbours than
/// signed ones (test `unsigned_distance_tells_more_nodes_apart_than_signed`).
#[derive(Debug, Clone)]
pub struct SizeFunctionFeature {
    polarity: Polarity,
    silhouette: SilhouetteConfig,
    lines: usize,
    window: Window,
    mean: MeanMethod,
    table_grid: usize,
    signed: bool,
}

impl SizeFunctionFeature {
    /// The size-function means of a contour around `centre`, one per line, appended to `out`.
    pub fn values_of_contour(
        &self,
        contour: &[[f64; 2]],
        centre: [f64; 2],
        out: &mut Vec<Option<f64>>,
    ) {
        let mut phi = Vec::with_capacity(contour.len());
        let mut scratch = size::CycleScratch::default();
        let mut diagram = PersistenceDiagram::default();
        for i in 0..self.lines {
            let angle = i as f64 * std::f64::consts::PI / self.lines as f64;
            distance_from_line(contour, centre, angle, self.signed, &mut phi);
            let value = match diagram.compute_into(&phi, &mut scratch) {
                Err(_) => None,
                Ok(()) => match self.mean {
                    MeanMethod::ClosedForm => Some(diagram.mean_closed_form(self.window)),
                    MeanMethod::Table => diagram.mean_table(self.window, self.table_grid).ok(),
                },
            };
            out.push(value);
        }
    }
}

impl Feature for SizeFunctionFeature {
    fn names(&self) -> Vec<String> {
        (0..self.lines).map(|i| format!("size_line{i}")).collect()
    }

    fn extract(&self, image: &GrayImage, out: &mut Vec<Option<f64>>) {
        match extract_silhouette(image, self.polarity, &self.silhouette) {
            Some(s) => self.values_of_contour(&s.contour, s.centroid, out),
            None => out.extend(std::iter::repeat_n(None, self.lines)),
        }
    }
}

/// The intensity barycentre: values `barycentre_x`, `barycentre_y` (pixels).
#[derive(Debug, Clone)]
pub struct BarycentreFeature {
    polarity: Polarity,
    background: Background,
}

impl Feature for BarycentreFeature {
    fn names(&self) -> Vec<String> {
        vec!["barycentre_x".into(), "barycentre_y".into()]
    }

    fn extract(&self, image: &GrayImage, out: &mut Vec<Option<f64>>) {
        match barycentre(image, self.polarity, self.background) {
            Some([x, y]) => out.extend([Some(x), Some(y)]),
            None => out.extend([None, None]),
        }
    }
}

/// A validated, ordered list of extractors; its values are named by [`FeatureSet::names`].
#[derive(Debug, Clone)]
pub struct FeatureSet {
    features: Vec<Arc<dyn Feature>>,
    counts: Vec<usize>,
    names: Vec<String>,
    /// How the set reads frames, when it comes from a [`FeatureConfig`].
    polarity: Option<Polarity>,
    /// Programs whose values follow the extractors' (see [`FeatureSet::external`]).
    external: Vec<ExternalFeatureConfig>,
}

impl FeatureSet {
    /// A set from your own extractors, in order. Errors if it is empty or names repeat.
    pub fn new(features: Vec<Arc<dyn Feature>>) -> Result<Self, FeatureError> {
        let mut names = Vec::new();
        let mut counts = Vec::new();
        for f in &features {
            let n = f.names();
            counts.push(n.len());
            names.extend(n);
        }
        let set = Self {
            features,
            counts,
            names,
            polarity: None,
            external: Vec::new(),
        };
        set.check_unique()?;
        Ok(set)
    }

    /// At least one name, and no name twice.
    fn check_unique(&self) -> Result<(), FeatureError> {
        if self.names.is_empty() {
            return Err(FeatureError::NoFeatures);
        }
        let mut seen = std::collections::HashSet::new();
        for n in &self.names {
            if !seen.insert(n.as_str()) {
                return Err(FeatureError::DuplicateName { name: n.clone() });
            }
        }
        Ok(())
    }

    /// The external programs, in order; their values are the last of [`FeatureSet::names`].
    /// The per-image methods below leave them missing (`None`): `crate::external::extract`
    /// runs the programs on a dataset folder and fills them in.
    pub fn external(&self) -> &[ExternalFeatureConfig] {
        &self.external
    }

    /// How many values come from the image extractors (the first ones of every row).
    pub fn image_values(&self) -> usize {
        self.counts.iter().sum()
    }

    /// The polarity the set reads frames with: a [`FeatureConfig`]'s, `None` for your own
    /// extractors.
    pub fn polarity(&self) -> Option<Polarity> {
        self.polarity
    }

    /// Names of the values, in output order (e.g. `size_line0` … `size_line5`, `barycentre_x`,
    /// `barycentre_y`).
    pub fn names(&self) -> Vec<String> {
        self.names.clone()
    }

    /// Number of values per image.
    pub fn len(&self) -> usize {
        self.names.len()
    }

    /// Always false: a checked set has at least one value.
    pub fn is_empty(&self) -> bool {
        self.names.is_empty()
    }

    /// The values for one image, in the order of [`FeatureSet::names`]; `None` = missing (always
    /// for the external programs' values). Never NaN or infinite.
    pub fn extract(&self, image: &GrayImage) -> Vec<Option<f64>> {
        let mut out = Vec::with_capacity(self.len());
        for (f, &count) in self.features.iter().zip(&self.counts) {
            let start = out.len();
            f.extract(image, &mut out);
            out.resize(start + count, None);
        }
        for v in &mut out {
            if v.is_some_and(|x| !x.is_finite()) {
                *v = None;
            }
        }
        out.resize(self.len(), None);
        out
    }

    /// The values for many images, one vector per image, in order.
    pub fn extract_batch<'a, I>(&self, images: I) -> Vec<Vec<Option<f64>>>
    where
        I: IntoIterator<Item = &'a GrayImage>,
    {
        images.into_iter().map(|im| self.extract(im)).collect()
    }

    /// [`FeatureSet::extract_batch`] on up to `threads` threads, each taking a contiguous run of
    /// images. `progress(done, total)` is called on the calling thread, which extracts the first
    /// run, and once more at the end. Each image's values depend on that image only, so the rows
    /// are the same whatever `threads`.
    pub fn extract_on(
        &self,
        images: &[&GrayImage],
        threads: usize,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Vec<Vec<Option<f64>>> {
        let total = images.len();
        let size = total.div_ceil(threads.clamp(1, total.max(1))).max(1);
        let done = AtomicUsize::new(0);
        let extract = |image: &&GrayImage| {
            let row = self.extract(image);
            done.fetch_add(1, Ordering::Relaxed);
            row
        };
        let mut chunks = images.chunks(size);
        let first = chunks.next().unwrap_or_default();
        std::thread::scope(|scope| {
            let handles: Vec<_> = chunks
                .map(|chunk| {
                    let extract = &extract;
                    scope.spawn(move || chunk.iter().map(extract).collect::<Vec<_>>())
                })
                .collect();
            let mut rows = Vec::with_capacity(total);
            let mut reported = 0;
            for image in first {
                rows.push(extract(image));
                reported = done.load(Ordering::Relaxed);
                progress(reported, total);
            }
            for handle in handles {
                // An extractor's panic goes on in the caller, as without threads.
                let chunk = handle
                    .join()
                    .unwrap_or_else(|panic| std::panic::resume_unwind(panic));
                rows.extend(chunk);
            }
            if reported < total {
                progress(total, total);
            }
            rows
        })
    }
}

#[cfg(test)]
mod tests;
