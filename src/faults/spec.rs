//! The `[[faults]]` tables of a scenario, as written, and their checking.

use serde::{Deserialize, Serialize};

use super::{Change, Effect, Fault, FaultError};

/// What a fault does.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FaultKind {
    /// A rectangle of constant intensity over the image (`rect`, `intensity`, `velocity`).
    Occluder,
    /// A bright Gaussian blob added to the image (`centre`, `radius`, `peak`).
    Glare,
    /// Pixels set to black or white (`density`).
    SaltPepper,
    /// The frame is black.
    Black,
    /// The frame is lost: every feature missing.
    Dropped,
    /// Named features read `value`.
    Stuck,
    /// Named features read `value` more.
    Offset,
    /// Named features are multiplied by `factor`.
    Gain,
    /// Named features are missing.
    Dropout,
    /// Named features get Gaussian noise of standard deviation `sigma`.
    Noise,
}

impl FaultKind {
    pub(super) fn is_feature_fault(self) -> bool {
        matches!(
            self,
            FaultKind::Stuck
                | FaultKind::Offset
                | FaultKind::Gain
                | FaultKind::Dropout
                | FaultKind::Noise
        )
    }

    fn name(self) -> &'static str {
        match self {
            FaultKind::Occluder => "occluder",
            FaultKind::Glare => "glare",
            FaultKind::SaltPepper => "salt_pepper",
            FaultKind::Black => "black",
            FaultKind::Dropped => "dropped",
            FaultKind::Stuck => "stuck",
            FaultKind::Offset => "offset",
            FaultKind::Gain => "gain",
            FaultKind::Dropout => "dropout",
            FaultKind::Noise => "noise",
        }
    }
}

/// Units of a feature fault's `value` and `sigma`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FaultUnits {
    /// The feature's own units.
    #[default]
    Raw,
    /// Standard deviations of the feature over the sample trajectory; a stuck `value` is counted
    /// from the feature's sample mean.
    Sd,
}

/// One `[[faults]]` table. Which fields apply depends on `kind`; a field another kind uses is an
/// error, so a typo cannot pass unnoticed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FaultSpec {
    /// What the fault does.
    pub kind: FaultKind,
    /// Label in `frames.csv` (default: the kind).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub name: Option<String>,
    /// Share of the frames inside the window it strikes, in [0, 1] (default 1).
    #[serde(default = "one")]
    pub share: f64,
    /// First and last frame (inclusive) it may strike (default: every frame).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub window: Option<[usize; 2]>,
    /// Frames struck in a row once it strikes (default 1).
    #[serde(default = "one_usize")]
    pub burst: usize,
    /// Feature faults: the features it changes, by name.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub features: Vec<String>,
    /// `stuck`: the value read; `offset`: the amount added.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub value: Option<f64>,
    /// `gain`: the factor.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub factor: Option<f64>,
    /// `noise`: the standard deviation.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sigma: Option<f64>,
    /// Units of `value` and `sigma` (default `raw`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub units: Option<FaultUnits>,
    /// `occluder`: `[x, y, width, height]` in pixels, (x, y) its top-left corner at the window's
    /// first frame.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rect: Option<[f64; 4]>,
    /// `occluder`: grey level 0 (dark) to 255 (bright).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub intensity: Option<f64>,
    /// `occluder`: pixels per frame it moves by (default still).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub velocity: Option<[f64; 2]>,
    /// `glare`: its centre `[x, y]` in pixels.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub centre: Option<[f64; 2]>,
    /// `glare`: its standard deviation in pixels.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub radius: Option<f64>,
    /// `glare`: grey levels added at its centre (default 200).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub peak: Option<f64>,
    /// `salt_pepper`: share of the pixels set to 0 or 255, in (0, 1].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub density: Option<f64>,
}

fn one() -> f64 {
    1.0
}

fn one_usize() -> usize {
    1
}

pub(super) fn check_one(
    index: usize,
    spec: &FaultSpec,
    feature_names: &[String],
    image_size: [u32; 2],
) -> Result<Fault, FaultError> {
    let name = spec
        .name
        .clone()
        .unwrap_or_else(|| spec.kind.name().to_string());
    let invalid = |message: String| FaultError::Invalid {
        index,
        name: name.clone(),
        message,
    };
    if name.is_empty() || name.contains(['+', ',', '"']) {
        return Err(invalid(
            "`name` must be non-empty and free of `+`, `,` and `\"` (it is written to frames.csv)"
                .into(),
        ));
    }
    if !(0.0..=1.0).contains(&spec.share) {
        return Err(invalid(format!(
            "`share` must lie in [0, 1], not {}",
            spec.share
        )));
    }
    if spec.burst == 0 {
        return Err(invalid("`burst` must be at least 1".into()));
    }
    if let Some([first, last]) = spec.window {
        if first > last {
            return Err(invalid(format!(
                "`window` [{first}, {last}] ends before it starts: give [first, last] frames"
            )));
        }
    }
    // Every field a kind does not use must be absent.
    let used: &[&str] = match spec.kind {
        FaultKind::Occluder => &["rect", "intensity", "velocity"],
        FaultKind::Glare => &["centre", "radius", "peak"],
        FaultKind::SaltPepper => &["density"],
        FaultKind::Black | FaultKind::Dropped => &[],
        FaultKind::Stuck | FaultKind::Offset => &["features", "value", "units"],
        FaultKind::Gain => &["features", "factor"],
        FaultKind::Dropout => &["features"],
        FaultKind::Noise => &["features", "sigma", "units"],
    };
    let present = [
        ("features", !spec.features.is_empty()),
        ("value", spec.value.is_some()),
        ("factor", spec.factor.is_some()),
        ("sigma", spec.sigma.is_some()),
        ("units", spec.units.is_some()),
        ("rect", spec.rect.is_some()),
        ("intensity", spec.intensity.is_some()),
        ("velocity", spec.velocity.is_some()),
        ("centre", spec.centre.is_some()),
        ("radius", spec.radius.is_some()),
        ("peak", spec.peak.is_some()),
        ("density", spec.density.is_some()),
    ];
    if let Some((field, _)) = present.iter().find(|(f, p)| *p && !used.contains(f)) {
        return Err(invalid(format!(
            "`{field}` does not apply to kind `{}` (it takes {})",
            spec.kind.name(),
            if used.is_empty() {
                "no settings".to_string()
            } else {
                used.iter()
                    .map(|u| format!("`{u}`"))
                    .collect::<Vec<_>>()
                    .join(", ")
            }
        )));
    }
    let need = |v: Option<f64>, field: &str| {
        v.filter(|x| x.is_finite()).ok_or_else(|| {
            invalid(format!(
                "kind `{}` needs a finite `{field}`",
                spec.kind.name()
            ))
        })
    };
    let [width, height] = image_size.map(f64::from);
    let effect = match spec.kind {
        FaultKind::Occluder => {
            let rect = spec.rect.ok_or_else(|| {
                invalid("kind `occluder` needs `rect = [x, y, width, height]` in pixels".into())
            })?;
            if rect.iter().any(|v| !v.is_finite()) || rect[2] <= 0.0 || rect[3] <= 0.0 {
                return Err(invalid(format!(
                    "`rect` {rect:?} needs finite values and a positive width and height"
                )));
            }
            let intensity = spec.intensity.unwrap_or(0.0);
            if !(0.0..=255.0).contains(&intensity) {
                return Err(invalid(format!(
                    "`intensity` must lie in [0, 255], not {intensity}"
                )));
            }
            let velocity = spec.velocity.unwrap_or([0.0, 0.0]);
            if velocity.iter().any(|v| !v.is_finite()) {
                return Err(invalid("`velocity` must be finite".into()));
            }
            let outside = rect[0] >= width
                || rect[1] >= height
                || rect[0] + rect[2] <= 0.0
                || rect[1] + rect[3] <= 0.0;
            if outside && velocity == [0.0, 0.0] {
                return Err(invalid(format!(
                    "`rect` {rect:?} lies outside the {width}×{height} image and does not move"
                )));
            }
            Effect::Occluder {
                rect,
                intensity: intensity.round() as u8,
                velocity,
            }
        }
        FaultKind::Glare => {
            let centre = spec
                .centre
                .filter(|c| c.iter().all(|v| v.is_finite()))
                .ok_or_else(|| {
                    invalid("kind `glare` needs a finite `centre = [x, y]` in pixels".into())
                })?;
            let radius = need(spec.radius, "radius")?;
            let peak = spec.peak.unwrap_or(200.0);
            if radius <= 0.0 || !(peak > 0.0 && peak <= 255.0) {
                return Err(invalid(format!(
                    "`radius` must be positive and `peak` in (0, 255]; got {radius} and {peak}"
                )));
            }
            Effect::Glare {
                centre,
                radius,
                peak,
            }
        }
        FaultKind::SaltPepper => {
            let density = need(spec.density, "density")?;
            if !(density > 0.0 && density <= 1.0) {
                return Err(invalid(format!(
                    "`density` must lie in (0, 1], not {density}"
                )));
            }
            Effect::SaltPepper { density }
        }
        FaultKind::Black => Effect::Black,
        FaultKind::Dropped => Effect::Dropped,
        kind => {
            if spec.features.is_empty() {
                return Err(invalid(format!(
                    "kind `{}` needs `features`, names among {}",
                    kind.name(),
                    feature_names.join(", ")
                )));
            }
            let mut indices = Vec::with_capacity(spec.features.len());
            for f in &spec.features {
                let j = feature_names.iter().position(|n| n == f).ok_or_else(|| {
                    invalid(format!(
                        "no feature `{f}` in this scenario; its features are {}",
                        feature_names.join(", ")
                    ))
                })?;
                if indices.contains(&j) {
                    return Err(invalid(format!("`features` names `{f}` twice")));
                }
                indices.push(j);
            }
            let change = match kind {
                FaultKind::Stuck => Change::Stuck(need(spec.value, "value")?),
                FaultKind::Offset => Change::Offset(need(spec.value, "value")?),
                FaultKind::Gain => Change::Gain(need(spec.factor, "factor")?),
                FaultKind::Dropout => Change::Dropout,
                _ => {
                    let sigma = need(spec.sigma, "sigma")?;
                    if sigma <= 0.0 {
                        return Err(invalid(format!("`sigma` must be positive, not {sigma}")));
                    }
                    Change::Noise(sigma)
                }
            };
            Effect::Features {
                indices,
                change,
                units: spec.units.unwrap_or_default(),
            }
        }
    };
    Ok(Fault {
        name,
        kind: spec.kind,
        effect,
        share: spec.share,
        window: spec.window,
        burst: spec.burst,
    })
}
