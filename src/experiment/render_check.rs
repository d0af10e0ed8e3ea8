//! The render check (`[confidence] render_check`): analysis by synthesis in the harness.
//!
//! The robot's silhouette at a method's estimate is compared with the frame's as the features
//! see it ([`crate::features::silhouette_pixels`]: the same threshold and largest component):
//! the mismatch is the number of pixels where the two differ. A method abstains where the
//! mismatch lies above the ⌈(n+1)(1 − a)⌉-th smallest of its own mismatches on the n clean
//! calibration frames (`a` = `confidence.render_share`, half the detection score's share by
//! default).
//!
//! The silhouette at the estimate comes from one of two places (`confidence.render_from`):
//! - `samples` (the default): predicted from the sample frames a run trains on
//!   ([`SampleSilhouettes`]), so the check needs no model of the camera or the robot, only
//!   sample frames dense enough (the 1 mm mesh; docs/results.md);
//! - `simulator`: rendered noise-free from the kinematics alone ([`FiveBar::inverse`] and
//!   [`FiveBar::elbows`]: capsules pivot → elbow → end-effector and the end-effector's disc, with
//!   the geometry's radii) through the simulator's own [`Camera`], one sample per pixel (a pixel
//!   is in where its centre is). It needs the exact image-formation model: half a pixel of camera
//!   error already spoils it (docs/results.md).
//!
//! **Stray pixels.** Pixels on the body's side of the threshold outside the silhouette (impulse
//! noise, a bright object, glare over the threshold, a piece an occluder cuts off the robot) fit
//! no pose and move global features such as the barycentre. Every method but the centre abstains,
//! flagged `stray_pixels`, on a frame with more than any clean calibration frame shows (the n-th
//! smallest of n: if exchangeable, at most 1/(n+1) of clean frames exceed it; 0 when simulated).
//!
//! The limits learned with silhouettes from the samples are kept in each method's model file
//! (`calibration.render_limit_px`, `stray_limit_px`): `track --samples` applies them to recorded
//! frames, and `train` learns them on its validation frames. The renderer's limits stay the run's.
//!
//! **Undefined cases abstain.** An estimate that is not finite (or, rendered, that the arms
//! cannot reach), no estimate, a frame without a silhouette (black, no contrast) or of another
//! size than the camera's: the mismatch is infinite, above any limit. A *dropped* frame is different: it has no image, which
//! is missing data rather than evidence against the estimate, so the check leaves a temporal
//! method's prediction there alone.

use std::sync::Arc;

use image::GrayImage;

use super::sample_silhouettes::{on_threads, SampleSilhouettes};
use super::{ExperimentError, Workbench};
use crate::dataset::{Dataset, Polarity};
use crate::estimator::{
    conformal_quantile, Calibrated, Calibration, Centre, EstimatorError, Method, PoseEstimate,
    PoseEstimator, RenderSource,
};
use crate::faults::FrameFaults;
use crate::features::{silhouette_and_stray, SilhouetteConfig};
use crate::scenario::CheckedScenario;
use crate::seed::{self, ScenarioPart};
use crate::sim::{Camera, FiveBar, Part, Primitive, Scene, SimError, SimSettings};

/// A frame as the check sees it.
#[derive(Debug, Clone, PartialEq)]
pub struct Observed(Seen);

#[derive(Debug, Clone, PartialEq)]
enum Seen {
    /// Dropped: there is no image to judge by.
    NoImage,
    /// An image showing no silhouette (or of another size than the camera's).
    NoSilhouette,
    /// The silhouette as the features see it, 64 pixels a word, row-major, with the count of
    /// stray pixels beside it.
    Silhouette { words: Vec<u64>, stray: usize },
}

impl Observed {
    /// A dropped frame: no image.
    pub fn dropped() -> Self {
        Self(Seen::NoImage)
    }

    /// Whether the frame was dropped (the check then judges nothing).
    pub fn is_dropped(&self) -> bool {
        self.0 == Seen::NoImage
    }

    /// Its silhouette's pixels, if it shows one.
    pub fn pixels(&self) -> Option<usize> {
        match &self.0 {
            Seen::Silhouette { words, .. } => {
                Some(words.iter().map(|w| w.count_ones() as usize).sum())
            }
            Seen::NoImage | Seen::NoSilhouette => None,
        }
    }

    /// Its stray pixels (module notes), if it shows a silhouette.
    pub fn stray(&self) -> Option<usize> {
        match &self.0 {
            Seen::Silhouette { stray, .. } => Some(*stray),
            Seen::NoImage | Seen::NoSilhouette => None,
        }
    }
}

/// Renders the robot at an estimate (or predicts its silhouette from the sample frames) and
/// compares it with a frame.
#[derive(Debug, Clone)]
pub struct RenderCheck {
    frames: FrameView,
    source: Source,
    /// Frames with more stray pixels than this abstain (`None`: not checked).
    stray_limit: Option<f64>,
}

/// How the features see a frame: its size, the body's polarity, the silhouette's settings.
#[derive(Debug, Clone)]
struct FrameView {
    width: u32,
    height: u32,
    polarity: Polarity,
    silhouette: SilhouetteConfig,
}

impl FrameView {
    fn pixel_count(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// The silhouette of `image` (row-major pixel flags); `None` for another size or no body.
    fn silhouette(&self, image: &GrayImage) -> Option<Vec<bool>> {
        self.silhouette_and_stray(image).map(|(pixels, _)| pixels)
    }

    /// [`FrameView::silhouette`] with its count of stray pixels.
    fn silhouette_and_stray(&self, image: &GrayImage) -> Option<(Vec<bool>, usize)> {
        (image.dimensions() == (self.width, self.height))
            .then(|| silhouette_and_stray(image, self.polarity, &self.silhouette))
            .flatten()
    }
}

/// Where the silhouette at an estimate comes from.
#[derive(Debug, Clone)]
enum Source {
    /// Rendered with the simulator's camera and robot.
    Renderer { camera: Camera, five_bar: FiveBar },
    /// Predicted from the sample frames.
    Samples(SampleSilhouettes),
}

/// Packs row-major pixel flags into words.
fn pack(pixels: impl Iterator<Item = bool>, count: usize) -> Vec<u64> {
    let mut words = vec![0u64; count.div_ceil(64)];
    for (i, on) in pixels.enumerate().take(count) {
        if on {
            words[i / 64] |= 1 << (i % 64);
        }
    }
    words
}

impl RenderCheck {
    /// The check of frames simulated with `sim`, whose silhouette the features take with
    /// `silhouette` (the body's polarity is the camera's).
    ///
    /// # Errors
    /// `sim`'s own when it is not valid.
    pub fn new(sim: &SimSettings, silhouette: &SilhouetteConfig) -> Result<Self, SimError> {
        let rig = sim.check()?;
        let mut camera = rig.camera;
        // A pixel is in where its centre is: one sample is enough for a count of pixels.
        camera.supersampling = 1;
        let g = &camera.geometry;
        let frames = FrameView {
            width: g.width,
            height: g.height,
            polarity: g.polarity,
            silhouette: silhouette.clone(),
        };
        let five_bar = rig.five_bar;
        Ok(Self {
            frames,
            source: Source::Renderer { camera, five_bar },
            stray_limit: None,
        })
    }

    /// The check of recorded frames of `width × height` px with the body's `polarity`, whose
    /// silhouette the features take with `silhouette`, predicted from `sample`'s frames (`track
    /// --samples`), learned on up to two of `threads`; `None` when fewer than 3 of those frames
    /// have a pose and a silhouette.
    pub fn from_samples(
        (width, height): (u32, u32),
        polarity: Polarity,
        silhouette: &SilhouetteConfig,
        sample: &Dataset,
        threads: usize,
    ) -> Option<Self> {
        let frames = FrameView {
            width,
            height,
            polarity,
            silhouette: silhouette.clone(),
        };
        Self::predicting(frames, sample, threads)
    }

    /// The check that predicts the silhouette at an estimate from `sample`'s frames (those with
    /// a pose and a silhouette) instead of rendering it, learned on up to two of `threads`;
    /// `None` when fewer than 3 have both.
    pub fn with_samples(self, sample: &Dataset, threads: usize) -> Option<Self> {
        Self::predicting(self.frames, sample, threads)
    }

    fn predicting(frames: FrameView, sample: &Dataset, threads: usize) -> Option<Self> {
        let posed: Vec<([f64; 2], &GrayImage)> = (sample.frames.iter())
            .filter_map(|frame| frame.truth.map(|t| ([t.x, t.y], &frame.image)))
            .collect();
        let (width, height) = (frames.width as usize, frames.height as usize);
        let samples = SampleSilhouettes::new(
            width,
            height,
            &posed,
            |&(pose, image)| Some((pose, frames.silhouette(image)?)),
            threads,
        )?;
        Some(Self {
            frames,
            source: Source::Samples(samples),
            stray_limit: None,
        })
    }

    /// Where the silhouette at an estimate comes from.
    pub fn source(&self) -> RenderSource {
        match self.source {
            Source::Renderer { .. } => RenderSource::Simulator,
            Source::Samples(_) => RenderSource::Samples,
        }
    }

    /// The silhouette of `image` as the features see it.
    pub fn observe(&self, image: &GrayImage) -> Observed {
        match self.frames.silhouette_and_stray(image) {
            Some((pixels, stray)) => Observed(Seen::Silhouette {
                words: pack(pixels.into_iter(), self.frames.pixel_count()),
                stray,
            }),
            None => Observed(Seen::NoSilhouette),
        }
    }

    /// The stray-pixel limit learned on clean calibration frames `observed`: the most stray
    /// pixels any of them shows (`None` when none shows a silhouette).
    pub fn learn_stray_limit(observed: &[Observed]) -> Option<f64> {
        (observed.iter())
            .filter_map(Observed::stray)
            .max()
            .map(|n| n as f64)
    }

    /// The check with frames beyond `limit` stray pixels abstaining (`None`: not checked).
    pub fn with_stray_limit(self, limit: Option<f64>) -> Self {
        Self {
            stray_limit: limit,
            ..self
        }
    }

    /// The robot's shapes with its end-effector at `at`, from the kinematics alone; `None` where
    /// the arms cannot reach it.
    fn scene(five_bar: &FiveBar, at: [f64; 2]) -> Option<Scene> {
        let theta = five_bar.inverse(at[0], at[1]).ok()?;
        let g = five_bar.geometry();
        let radius = g.link_radius;
        let pivots = five_bar.pivots();
        let elbows = five_bar.elbows(theta);
        let mut parts = Vec::with_capacity(5);
        for (pivot, elbow) in pivots.into_iter().zip(elbows) {
            let (a, b) = (pivot, elbow);
            parts.push((Part::Proximal, Primitive::Capsule { a, b, radius }));
        }
        for elbow in elbows {
            let (a, b) = (elbow, at);
            parts.push((Part::Distal, Primitive::Capsule { a, b, radius }));
        }
        let disc = Primitive::Disc {
            centre: at,
            radius: g.end_effector_radius,
        };
        parts.push((Part::EndEffector, disc));
        Some(Scene { parts })
    }

    /// The robot's silhouette at `at` (rendered, or predicted from the samples), packed as
    /// [`Observed`]'s.
    pub fn rendered(&self, at: [f64; 2]) -> Option<Vec<u64>> {
        let count = self.frames.pixel_count();
        match &self.source {
            Source::Samples(samples) => samples.predict_packed(at),
            Source::Renderer { camera, five_bar } => {
                let coverage = camera.coverage(&Self::scene(five_bar, at)?);
                Some(pack(coverage.iter().map(|&c| c >= 0.5), count))
            }
        }
    }

    /// The limit learned on the calibration frames `observed` against a method's `poses` there:
    /// the ⌈(n+1)(1 − `share`)⌉-th smallest mismatch ([`render_limit`]).
    pub fn limit(
        &self,
        poses: &[Option<[f64; 2]>],
        observed: &[Observed],
        share: f64,
    ) -> Option<f64> {
        let mismatches: Vec<f64> = (poses.iter().zip(observed))
            .map(|(&pose, observed)| self.mismatch(observed, pose))
            .collect();
        render_limit(&mismatches, share)
    }

    /// Makes `estimate` abstain by `calibration`'s rule, flagged `render_mismatch`, where its
    /// mismatch with `observed` is above `limit_px`, and flagged `stray_pixels` where the frame
    /// has more stray pixels than the check's limit; a frame without a pose, already abstained,
    /// or dropped is left alone.
    pub fn judge(
        &self,
        estimate: &mut PoseEstimate,
        observed: &Observed,
        limit_px: f64,
        calibration: &Calibration,
    ) {
        if estimate.pose.is_none() || estimate.flags.abstained || observed.is_dropped() {
            return;
        }
        let stray = (observed.stray().zip(self.stray_limit)).is_some_and(|(n, l)| n as f64 > l);
        let mismatch = self.mismatch(observed, estimate.pose) > limit_px;
        if stray || mismatch {
            calibration.abstain(estimate);
            estimate.flags.stray_pixels = stray;
            estimate.flags.render_mismatch = mismatch;
        }
    }

    /// Pixels where the robot rendered at `estimate` and the `observed` silhouette differ;
    /// infinite where either is undefined (module notes).
    pub fn mismatch(&self, observed: &Observed, estimate: Option<[f64; 2]>) -> f64 {
        let (Seen::Silhouette { words: seen, .. }, Some(at)) = (&observed.0, estimate) else {
            return f64::INFINITY;
        };
        let Some(rendered) = self.rendered(at) else {
            return f64::INFINITY;
        };
        let differ: u32 = seen
            .iter()
            .zip(&rendered)
            .map(|(a, b)| (a ^ b).count_ones())
            .sum();
        f64::from(differ)
    }
}

/// The limit of a method's mismatches: the ⌈(n+1)(1 − `share`)⌉-th smallest of its `n`
/// clean calibration frames' (infinite ones rank last); `None` when that rank is past the end
/// or infinite, and then the check makes no frame abstain.
pub fn render_limit(calibration: &[f64], share: f64) -> Option<f64> {
    conformal_quantile(calibration, 1.0 - share)
}

/// `estimator`'s poses on the calibration frames `rows` (at `times`): those its calibration saw,
/// else (a method fitted elsewhere) tracked again.
///
/// # Errors
/// The estimator's, while tracking.
pub fn estimates_on(
    estimator: &dyn PoseEstimator,
    rows: &[Vec<Option<f64>>],
    times: &[f64],
) -> Result<Vec<Option<[f64; 2]>>, EstimatorError> {
    let calibrated = (estimator as &dyn std::any::Any).downcast_ref::<Calibrated>();
    match calibrated.map(Calibrated::calibration_poses) {
        Some(poses) if poses.len() == rows.len() => Ok(poses.to_vec()),
        _ => {
            let mut motion = estimator.start_motion();
            (rows.iter().zip(times))
                .map(|(row, &time)| Ok(motion.next(time, row)?.pose))
                .collect()
        }
    }
}

/// The check as a run uses it: the calibration motion's silhouettes, the limits learned on them,
/// the test frames judged against them.
#[derive(Debug)]
pub(super) struct Harness {
    learned: Arc<Learned>,
    /// Share of clean calibration frames the check may make abstain.
    share: f64,
}

/// What the check learns before any method: the silhouette source (from the samples, a
/// distance field per sample frame) and the calibration motion's silhouettes. A pure function of
/// the settings and seeds in [`Harness::new`]'s key, so the variants of a sweep share it.
#[derive(Debug)]
pub(super) struct Learned {
    check: RenderCheck,
    /// The calibration motion's frames (`[calibration]`, else the validation motion).
    calibration: Vec<Observed>,
}

/// A method's limit with the calibration its abstentions follow.
#[derive(Debug)]
pub(super) struct MethodLimit {
    /// Mismatches above it abstain (`None`: none does).
    pub limit: Option<f64>,
    calibration: Option<Calibration>,
}

impl Harness {
    /// The check of `scenario`'s frames, its calibration motion's silhouettes taken; `sample`
    /// is the sample trajectory the run trains on. `None` when the check is off: turned off, or
    /// left to its default where it cannot be learned (no calibration motion, or from the
    /// samples fewer than 3 sample frames with a silhouette).
    ///
    /// # Errors
    /// The camera or robot cannot be built, the calibration motion cannot be simulated, or the
    /// check was asked for (`render_check = true`) and the samples cannot predict a silhouette.
    pub(super) fn new(
        scenario: &CheckedScenario,
        bench: &Workbench,
        sample: &Dataset,
    ) -> Result<Option<Self>, ExperimentError> {
        let s = scenario.get();
        let (motion, part) = match (&s.calibration, &s.validation) {
            (Some(motion), _) => (motion, ScenarioPart::Calibration),
            (None, Some(motion)) => (motion, ScenarioPart::Validation),
            // Asked for without one, the scenario's check refuses it.
            (None, None) => return Ok(None),
        };
        let data = bench.dataset(&s.sim, motion, seed::for_part(s.seed, part), &mut |_, _| {})?;
        if !s.confidence.render_check_on(Some(data.frames.len())) {
            return Ok(None);
        }
        let check = RenderCheck::new(&s.sim, &s.features.silhouette).map_err(|e| {
            ExperimentError::Simulate {
                what: "the render check's camera and robot".into(),
                source: Arc::new(e),
            }
        })?;
        let from_samples = s.confidence.render_from == RenderSource::Samples;
        // The sample frames depend on the features only through the adaptive trajectory.
        let key = serde_json::json!({
            "sim": s.sim,
            "silhouette": s.features.silhouette,
            "from_samples": from_samples,
            "sample": from_samples.then_some(&s.sample),
            "sample_seed": seed::for_part(s.seed, ScenarioPart::Sample),
            "features": (from_samples && s.sample.adaptive.is_some()).then_some(&s.features),
            "calibration": motion,
            "calibration_seed": seed::for_part(s.seed, part),
        })
        .to_string();
        let learned = bench.render_check(key, || {
            let check = match from_samples {
                true => check.with_samples(sample, bench.threads())?,
                false => check,
            };
            let images: Vec<&GrayImage> = data.images().collect();
            let calibration = on_threads(bench.threads(), &images, |image| check.observe(image));
            Some(Learned {
                check: check.with_stray_limit(RenderCheck::learn_stray_limit(&calibration)),
                calibration,
            })
        });
        let Some(learned) = learned else {
            if !s.confidence.render_check_required() {
                return Ok(None);
            }
            let samples = sample.frames.len();
            return Err(ExperimentError::RenderCheck(format!(
                "fewer than 3 of the {samples} sample frames show a silhouette, too few to \
                 predict one at an estimate; set `confidence.render_from = \"simulator\"` or \
                 turn `confidence.render_check` off"
            )));
        };
        Ok(Some(Self {
            learned,
            share: s.confidence.render_share,
        }))
    }

    /// Where the silhouette at an estimate comes from.
    pub(super) fn source(&self) -> RenderSource {
        self.learned.check.source()
    }

    /// The calibration motion's frames the limits are learned on.
    pub(super) fn calibration_frames(&self) -> usize {
        self.learned.calibration.len()
    }

    /// The silhouettes of painted frames `at`.
    pub(super) fn observe_painted(
        &self,
        at: &[usize],
        images: &[GrayImage],
    ) -> Vec<(usize, Observed)> {
        let observed = images.iter().map(|image| self.learned.check.observe(image));
        at.iter().copied().zip(observed).collect()
    }

    /// The silhouettes of a test motion's frames: `painted` ones as painted, dropped ones none,
    /// the others as simulated.
    pub(super) fn observe_motion(
        &self,
        data: &Dataset,
        mut painted: Vec<(usize, Observed)>,
        labels: Option<&[FrameFaults]>,
    ) -> Vec<Observed> {
        painted.sort_by_key(|p| p.0);
        (data.images().enumerate())
            .map(|(i, image)| {
                if labels.is_some_and(|l| l.get(i).is_some_and(|f| f.dropped)) {
                    return Observed::dropped();
                }
                match painted.binary_search_by_key(&i, |p| p.0) {
                    Ok(k) => painted[k].1.clone(),
                    Err(_) => self.learned.check.observe(image),
                }
            })
            .collect()
    }

    /// The limit of `method` (`estimator`), learned on the calibration motion's `(truth, times,
    /// rows)`; `None` for the centre, which has no estimate of its own to check.
    pub(super) fn method_limit(
        &self,
        method: Method,
        estimator: &dyn PoseEstimator,
        calibrating: Option<&super::LabelledMotion>,
    ) -> Result<Option<MethodLimit>, ExperimentError> {
        let Some((_, times, rows)) = calibrating.filter(|_| method.name() != Centre::METHOD) else {
            return Ok(None);
        };
        self.limit(estimator, rows, times)
            .map(Some)
            .map_err(|source| ExperimentError::Estimator {
                stage: format!("the render check of {method} on its calibration motion"),
                source,
            })
    }

    /// `estimator`'s limit, learned on its estimates of the calibration motion's `rows` (at
    /// `times`).
    fn limit(
        &self,
        estimator: &dyn PoseEstimator,
        rows: &[Vec<Option<f64>>],
        times: &[f64],
    ) -> Result<MethodLimit, EstimatorError> {
        let calibrated = (estimator as &dyn std::any::Any).downcast_ref::<Calibrated>();
        let calibration = calibrated.map(|c| c.calibration().clone());
        let poses = estimates_on(estimator, rows, times)?;
        Ok(MethodLimit {
            limit: self
                .learned
                .check
                .limit(&poses, &self.learned.calibration, self.share),
            calibration,
        })
    }

    /// Makes `estimate` abstain where its mismatch with `observed` is above `limit` or the frame
    /// has too many stray pixels ([`RenderCheck::judge`]).
    pub(super) fn judge(
        &self,
        estimate: &mut PoseEstimate,
        observed: &Observed,
        limit: &MethodLimit,
    ) {
        if let Some(calibration) = &limit.calibration {
            let limit_px = limit.limit.unwrap_or(f64::INFINITY);
            (self.learned.check).judge(estimate, observed, limit_px, calibration);
        }
    }

    /// The limits a model file keeps (mismatch, stray pixels): those learned with silhouettes
    /// from the samples (`track --samples` can apply them), not the renderer's.
    pub(super) fn limits_to_keep(&self, limit: &MethodLimit) -> (Option<f64>, Option<f64>) {
        match self.source() {
            RenderSource::Samples => (limit.limit, self.stray_limit()),
            RenderSource::Simulator => (None, None),
        }
    }

    /// The stray-pixel limit learned on the calibration frames.
    pub(super) fn stray_limit(&self) -> Option<f64> {
        self.learned.check.stray_limit
    }
}

#[cfg(test)]
#[path = "render_check_tests.rs"]
mod tests;
