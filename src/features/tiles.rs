//! Local features: a region of the frame cut into a grid of tiles, one value per tile, the share
//! of the tile covered by the body (`tile_r{row}_c{column}`).
//!
//! Each value depends on its tile's pixels and on the frame's median grey level only, so an
//! occluder moves the tiles it overlaps and leaves the others (the global size functions and
//! barycentre all move at once). A pixel's weight ramps linearly from 0 at `median + floor` to 1
//! at `median + floor + contrast` (body intensities): anti-aliased edge pixels count by their
//! coverage, so a value moves smoothly with sub-pixel motion. The median is the background's
//! while the body and any occluder cover under half the frame; a 15 × 15 box (1 % of a
//! 170 × 120 frame) moves it by a fraction of a grey level. Otsu's level would not do: a
//! bright box shifts it and so every tile (see [`super::Threshold`]).

use image::GrayImage;
use serde::{Deserialize, Serialize};

use super::silhouette::{histogram, Polarity};
use super::{Feature, FeatureError};

/// Most tiles of one family: the trackers take at most 64 features in all.
pub const MAX_TILES: usize = 64;

/// Settings of the tile features (`[features.tiles]`), off by default.
///
/// `columns × rows` tiles (at most [`MAX_TILES`]) over `region` (default the whole frame); tile
/// `(r, c)` spans columns `x + ⌊c·w/columns⌋ .. x + ⌊(c+1)·w/columns⌋` and likewise rows.
/// Values are in `[0, 1]`; missing (`None`) only where the region leaves the frame.
/// On the simulator's default rig and workspace every tile of the whole-frame 4 × 4 and 6 × 4
/// grids sees the arm somewhere (test `every_tile_varies_over_the_workspace_and_a_box_moves_few_of_them`);
/// from 8 × 4 on, the two top corner tiles never do. A constant tile is harmless, not an error:
/// its HMM gets one state, which no frame can contradict, and k-NN, the GP and the continuous
/// trackers give the same errors with it as without (measured on the 8 features plus one constant
/// tile); it only spends one of the 64 features the trackers take.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TileConfig {
    /// Whether the tile values are computed (default false).
    pub enabled: bool,
    /// Tiles across (default 4).
    pub columns: usize,
    /// Tiles down (default 4).
    pub rows: usize,
    /// `[x, y, width, height]` in pixels, `(x, y)` the top-left corner; default the whole frame.
    pub region: Option<[u32; 4]>,
    /// Grey levels above the median where a pixel starts to count (default 10: five noise σ of
    /// the default camera).
    pub floor: f64,
    /// Grey levels over which a pixel's weight ramps from 0 to 1 (default 150; the default
    /// camera's body is 190 above its background).
    pub contrast: f64,
}

impl Default for TileConfig {
    fn default() -> Self {
        Self {
            enabled: false,
            columns: 4,
            rows: 4,
            region: None,
            floor: 10.0,
            contrast: 150.0,
        }
    }
}

impl TileConfig {
    /// Validate the settings and build the extractor.
    pub fn check(&self, polarity: Polarity) -> Result<TileFeature, FeatureError> {
        let bad = |reason: String| Err(FeatureError::BadTiles { reason });
        let tiles = self.columns.saturating_mul(self.rows);
        if self.columns == 0 || self.rows == 0 || tiles > MAX_TILES {
            return bad(format!(
                "{} × {} tiles: give columns and rows ≥ 1 with at most {MAX_TILES} tiles, e.g. 4 × 4",
                self.columns, self.rows
            ));
        }
        if !(self.floor.is_finite() && (0.0..=255.0).contains(&self.floor)) {
            return bad(format!(
                "floor {} must be a grey level in [0, 255]",
                self.floor
            ));
        }
        if !(self.contrast.is_finite() && self.contrast >= 1.0 && self.contrast <= 255.0) {
            return bad(format!(
                "contrast {} must be in [1, 255] grey levels",
                self.contrast
            ));
        }
        if let Some([x, y, w, h]) = self.region {
            if w < self.columns as u32 || h < self.rows as u32 {
                return bad(format!(
                    "region {w} × {h} px is smaller than one pixel per tile ({} × {})",
                    self.columns, self.rows
                ));
            }
            if x.checked_add(w).is_none() || y.checked_add(h).is_none() {
                return bad(format!("region [{x}, {y}, {w}, {h}] overflows"));
            }
        }
        Ok(TileFeature {
            polarity,
            columns: self.columns,
            rows: self.rows,
            region: self.region,
            floor: self.floor,
            contrast: self.contrast,
        })
    }
}

/// Whether the settings are the default ones, left out of written configurations.
pub(crate) fn is_off(config: &TileConfig) -> bool {
    *config == TileConfig::default()
}

/// The tile extractor built by [`TileConfig::check`].
#[derive(Debug, Clone)]
pub struct TileFeature {
    polarity: Polarity,
    columns: usize,
    rows: usize,
    region: Option<[u32; 4]>,
    floor: f64,
    contrast: f64,
}

/// The first pixel of each of `n` tiles over `len` pixels from `start`, and the end.
fn edges(start: usize, len: usize, n: usize) -> Vec<usize> {
    (0..=n).map(|i| start + i * len / n).collect()
}

impl TileFeature {
    /// The weight of each grey level, from the frame's median.
    fn weights(&self, image: &GrayImage) -> [f64; 256] {
        let hist = histogram(image.as_raw());
        let total: u64 = hist.iter().sum();
        let mut seen = 0;
        let mut median = 0usize;
        for (v, &c) in hist.iter().enumerate() {
            seen += c;
            if 2 * seen >= total {
                median = v;
                break;
            }
        }
        let flip = self.polarity == Polarity::DarkOnBright;
        let body = |v: usize| if flip { 255 - v } else { v } as f64;
        let start = body(median) + self.floor;
        let mut lut = [0.0; 256];
        for (v, w) in lut.iter_mut().enumerate() {
            *w = ((body(v) - start) / self.contrast).clamp(0.0, 1.0);
        }
        lut
    }
}

impl Feature for TileFeature {
    fn names(&self) -> Vec<String> {
        (0..self.rows)
            .flat_map(|r| (0..self.columns).map(move |c| format!("tile_r{r}_c{c}")))
            .collect()
    }

    fn extract(&self, image: &GrayImage, out: &mut Vec<Option<f64>>) {
        let (width, height) = (image.width() as usize, image.height() as usize);
        let [x, y, w, h] = self
            .region
            .map_or([0, 0, width, height], |r| r.map(|v| v as usize));
        if width == 0 || height == 0 || x + w > width || y + h > height {
            out.extend(std::iter::repeat_n(None, self.rows * self.columns));
            return;
        }
        let lut = self.weights(image);
        let xs = edges(x, w, self.columns);
        let ys = edges(y, h, self.rows);
        // Column → tile column, so the inner loop is one lookup and one add per pixel.
        let mut tile_of = vec![0usize; w];
        for c in 0..self.columns {
            tile_of[xs[c] - x..xs[c + 1] - x].fill(c);
        }
        let raw = image.as_raw();
        let mut sums = vec![0.0; self.columns];
        for r in 0..self.rows {
            sums.fill(0.0);
            for row in ys[r]..ys[r + 1] {
                let pixels = &raw[row * width + x..row * width + x + w];
                for (&p, &c) in pixels.iter().zip(&tile_of) {
                    sums[c] += lut[p as usize];
                }
            }
            for c in 0..self.columns {
                let area = (xs[c + 1] - xs[c]) * (ys[r + 1] - ys[r]);
                out.push((area > 0).then(|| sums[c] / area as f64));
            }
        }
    }
}

#[cfg(test)]
#[path = "tiles_tests.rs"]
mod tests;
