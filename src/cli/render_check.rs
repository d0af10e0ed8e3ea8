//! The render check for model files: `train` learns its limit (on by default, given a validation
//! dataset of 199 frames or more), `track --samples` applies the limit a model file carries, with
//! the silhouette at each estimate predicted from the sample frames the model was trained on.

use std::path::Path;

use anyhow::{bail, Context, Result};
use evitrack::dataset::Dataset;
use evitrack::estimator::{
    Calibrated, Calibration, ConfidenceSettings, PoseEstimate, PoseEstimator, RenderSource,
};
use evitrack::experiment::{estimates_on, RenderCheck};
use evitrack::features::FeatureConfig;
use image::GrayImage;

/// The check as `track` applies it.
pub(super) struct TrackCheck {
    check: RenderCheck,
    limit_px: f64,
    calibration: Calibration,
}

impl TrackCheck {
    /// The check for `estimator` (read from `model`) on `dataset`'s frames, with the sample
    /// frames at `samples`; `None` without `--samples` (with a note when the model carries a
    /// limit).
    ///
    /// # Errors
    /// `--samples` for a model without a limit, an unreadable sample dataset, or one with fewer
    /// than 3 frames that have a pose and a silhouette.
    pub(super) fn new(
        estimator: &dyn PoseEstimator,
        model: &Path,
        samples: Option<&Path>,
        config: &FeatureConfig,
        dataset: &Dataset,
    ) -> Result<Option<Self>> {
        let calibration = (estimator as &dyn std::any::Any)
            .downcast_ref::<Calibrated>()
            .map(Calibrated::calibration);
        let limit = calibration.and_then(|c| c.render_limit_px);
        let (path, limit_px, calibration) = match (samples, limit, calibration) {
            (Some(path), Some(limit), Some(calibration)) => (path, limit, calibration),
            (None, None, _) => return Ok(None),
            (None, Some(_), _) => {
                eprintln!(
                    "note: {} carries the render check's limit from its run; pass --samples with \
                     the sample frames it was trained on to apply it (a run's: `evitrack \
                     simulate --scenario RUN_FOLDER/scenario.toml --part sample --out SAMPLES`)",
                    model.display()
                );
                return Ok(None);
            }
            (Some(_), _, _) => bail!(
                "{} has no render-check limit to apply (its run or `train` learned none: the \
                 check off, `render_from = \"simulator\"`, too few calibration frames for its \
                 share, or tracker options left its calibration out): leave --samples out",
                model.display()
            ),
        };
        let sample = super::read_dataset(path)?;
        super::check_polarity(config, &sample, &path.display().to_string())?;
        let what = path.display().to_string();
        let check = check_from_samples(config, &sample, dataset, &what)?
            .with_stray_limit(calibration.stray_limit_px);
        Ok(Some(Self {
            check,
            limit_px,
            calibration: calibration.clone(),
        }))
    }

    /// Makes `estimate` abstain (flag `render_mismatch`) where the silhouette predicted at it
    /// misses `image`'s by more than the limit, or (flag `stray_pixels`) where `image` shows more
    /// stray pixels than the model's validation frames did.
    pub(super) fn judge(&self, estimate: &mut PoseEstimate, image: &GrayImage) {
        let observed = self.check.observe(image);
        (self.check).judge(estimate, &observed, self.limit_px, &self.calibration);
    }
}

/// The check of frames of `frames`' size with silhouettes predicted from `sample` (named `what`).
fn check_from_samples(
    config: &FeatureConfig,
    sample: &Dataset,
    frames: &Dataset,
    what: &str,
) -> Result<RenderCheck> {
    let camera = &frames.manifest.camera;
    let size = (camera.width, camera.height);
    let threads = super::cores();
    RenderCheck::from_samples(size, config.polarity, &config.silhouette, sample, threads)
        .with_context(|| {
            format!(
            "{what}: fewer than 3 frames have a pose and a silhouette of {} × {} px, too few to \
             predict the robot's silhouette",
            size.0, size.1
        )
        })
}

/// A validation dataset with its feature rows and times.
pub(super) type Validation<'a> = (&'a Dataset, &'a [Vec<Option<f64>>], &'a [f64]);

/// `train`'s part: where `confidence` asks for the check (or leaves it to its default) and the
/// model is calibrated on `validation`'s frames, learns the limit on them against the model's
/// estimates there and keeps it in `estimator`'s calibration (so its model file carries it).
/// Returns the limit, `None` when there is none to learn or too few frames for the share.
///
/// # Errors
/// The simulator source (a model file cannot render); asked for (`confidence.render_check =
/// true`), fewer than 3 sample frames with a pose and a silhouette (left to its default, the
/// check is left out then, with a note).
pub(super) fn learn_limit(
    estimator: &mut dyn PoseEstimator,
    confidence: &ConfidenceSettings,
    config: &FeatureConfig,
    sample: &Dataset,
    validation: Option<Validation<'_>>,
) -> Result<Option<f64>> {
    let required = confidence.render_check_required();
    if !confidence.render_check_on(validation.map(|(data, _, _)| data.frames.len())) {
        return Ok(None);
    }
    if confidence.render_from == RenderSource::Simulator {
        bail!(
            "`confidence.render_from = \"simulator\"` renders the simulator's robot, which `train` \
             does not have: use \"samples\" (the default) or set `confidence.render_check=false`"
        );
    }
    let Some((validation, rows, times)) = validation else {
        eprintln!(
            "note: `confidence.render_check` learns its limit on the validation frames: give \
             --validation, or the model carries none"
        );
        return Ok(None);
    };
    // The centre, not calibrated, has no estimate of its own to check.
    if !(&*estimator as &dyn std::any::Any).is::<Calibrated>() {
        return Ok(None);
    }
    let check = match check_from_samples(config, sample, validation, "the sample frames") {
        Ok(check) => check,
        Err(e) if !required => {
            eprintln!("note: no render check: {e:#}");
            return Ok(None);
        }
        Err(e) => return Err(e),
    };
    let poses = estimates_on(estimator, rows, times)?;
    let observed: Vec<_> = validation
        .images()
        .map(|image| check.observe(image))
        .collect();
    let limit = check.limit(&poses, &observed, confidence.render_share);
    let any = estimator as &mut dyn std::any::Any;
    let Some(calibrated) = any.downcast_mut::<Calibrated>() else {
        return Ok(None);
    };
    calibrated.set_render_limits((limit, RenderCheck::learn_stray_limit(&observed)));
    Ok(limit)
}
