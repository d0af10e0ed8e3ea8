//! The `[confidence]` section's settings: the levels every method's regions and abstentions are
//! held to, and where the render check runs.

use serde::{Deserialize, Serialize};

use super::{cells, conformal_rank};
use crate::range::within;

/// The `[confidence]` section: the levels every method's regions and abstentions are held to.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ConfidenceSettings {
    /// Share of clean frames the regions should hold (split-conformal, on the validation motion).
    pub coverage: f64,
    /// Share of clean calibration frames the method may abstain on, by its detection score and
    /// the render check together: where the check runs it takes `render_share` of it and the
    /// detection score the rest ([`ConfidenceSettings::detection_share`]).
    pub abstain_share: f64,
    /// The detection limit lies this many times its distance from the median calibration score
    /// beyond the split-conformal quantile (0: the quantile itself). The quantile holds its
    /// share on frames exchangeable with the calibration motion's; a test motion that visits
    /// poses the calibration passes less (the paper's Lissajous) shows clean scores a little
    /// above every calibration score, while a fault's lie far beyond it (docs/results.md, "A
    /// stretched detection limit").
    pub detection_stretch: f64,
    /// A region larger than this share of the workspace's area makes the method abstain.
    pub max_region_share: f64,
    /// The render check: each method but the centre also abstains where the robot's silhouette
    /// at its estimate differs from the frame's by more pixels than on `render_share` of its
    /// clean calibration frames (`crate::experiment::RenderCheck`). The harness (or `train`)
    /// learns its limit after the fit; from the samples, model files carry it for
    /// `track --samples`. `None` (the default): on wherever the calibration motion has frames
    /// enough for its limit ([`ConfidenceSettings::render_check_on`]; the run leaves it out, its
    /// share unused, where fewer than 3 sample frames show a silhouette); `Some(true)` asks for
    /// it (an error where it cannot be learned), `Some(false)` turns it off.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub render_check: Option<bool>,
    /// Where the render check takes the silhouette at an estimate from.
    #[serde(default, skip_serializing_if = "RenderSource::is_samples")]
    pub render_from: RenderSource,
    /// Share of clean calibration frames the render check may make abstain, taken from
    /// `abstain_share` (half of its default), so that with the check the two together still
    /// abstain on about 1 % of frames like the calibration motion's.
    #[serde(skip_serializing_if = "is_default_render_share")]
    pub render_share: f64,
    /// A region quantile per cell of an nx × ny grid over the workspace, by where the estimate
    /// fell (Mondrian conformal, `calibration_cells.rs`), so that the coverage holds part by part
    /// where each cell has calibration frames enough; `None` (the default): one quantile.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cells: Option<[usize; 2]>,
}

const DEFAULT_RENDER_SHARE: f64 = 0.005;
const DEFAULT_DETECTION_STRETCH: f64 = 0.5;

fn is_default_render_share(share: &f64) -> bool {
    *share == DEFAULT_RENDER_SHARE
}

/// Where the render check takes the robot's silhouette at an estimate from.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum RenderSource {
    /// Predicted from the sample frames the run trains on: no model of the camera or the robot.
    #[default]
    Samples,
    /// Rendered from the simulator's camera and robot: needs the exact image-formation model.
    Simulator,
}

impl RenderSource {
    fn is_samples(&self) -> bool {
        *self == Self::Samples
    }
}

impl Default for ConfidenceSettings {
    fn default() -> Self {
        Self {
            coverage: 0.9,
            abstain_share: 0.01,
            detection_stretch: DEFAULT_DETECTION_STRETCH,
            max_region_share: 0.5,
            render_check: None,
            render_from: RenderSource::Samples,
            render_share: DEFAULT_RENDER_SHARE,
            cells: None,
        }
    }
}

impl ConfidenceSettings {
    /// Whether the render check runs with `calibration_frames` frames to learn its limit on
    /// (`None`: no calibration motion): as asked, else wherever those frames are enough for a
    /// limit at `render_share` (199 at the default 0.005).
    pub fn render_check_on(&self, calibration_frames: Option<usize>) -> bool {
        let learnable = |n: usize| conformal_rank(n, 1.0 - self.render_share) <= n;
        self.render_check
            .unwrap_or_else(|| calibration_frames.is_some_and(learnable))
    }

    /// The share of `calibration_frames` clean calibration frames the detection score may make
    /// abstain: `abstain_share`, less `render_share` where the render check runs (at least 0).
    pub fn detection_share(&self, calibration_frames: usize) -> f64 {
        match self.render_check_on(Some(calibration_frames)) {
            true => (self.abstain_share - self.render_share).max(0.0),
            false => self.abstain_share,
        }
    }

    /// Whether the render check was asked for in so many words (then it must run).
    pub fn render_check_required(&self) -> bool {
        self.render_check == Some(true)
    }

    /// Checks the ranges: a sentence naming the field otherwise.
    ///
    /// # Errors
    /// The field and its range.
    pub fn check(&self) -> Result<(), String> {
        within(self.coverage, 0.5..=0.999).map_err(|e| format!("`confidence.coverage`: {e}"))?;
        within(self.abstain_share, 0.0..=0.5)
            .map_err(|e| format!("`confidence.abstain_share`: {e}"))?;
        within(self.detection_stretch, 0.0..=10.0)
            .map_err(|e| format!("`confidence.detection_stretch`: {e}"))?;
        within(self.render_share, 0.0..=0.5)
            .map_err(|e| format!("`confidence.render_share`: {e}"))?;
        within(self.max_region_share, 0.01..=1.0)
            .map_err(|e| format!("`confidence.max_region_share`: {e}"))?;
        if let Some(cells) = self.cells {
            cells::check_cells(cells)?;
        }
        Ok(())
    }
}
