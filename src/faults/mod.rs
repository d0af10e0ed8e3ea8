//! Faults: things going wrong with a measurement, injected into the test motions of a scenario so
//! that the claim "conflict rejects incorrect measurements" can be measured.
//!
//! Two families, listed in a scenario's `[[faults]]` tables and applied in that order:
//!
//! - *image faults* change the rendered frame before features are extracted: an occluding
//!   rectangle (static or moving, dark or bright), a glare blob, salt-and-pepper pixels, a black
//!   frame, a dropped frame (no image at all: every feature missing);
//! - *feature faults* change named features after extraction: stuck at a value, offset, gain,
//!   dropout, a noise burst.
//!
//! Each fault strikes a share of the frames inside its window, in bursts of a given length, drawn
//! from its own seeded stream. Every frame records its ground truth: the faults that struck and
//! the features whose value they changed (compared with the clean extraction of the same image).

mod image_faults;
mod schedule;

pub use schedule::active_frames;

use ::image::GrayImage;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use serde::{Deserialize, Serialize};

use crate::features::FeatureSet;

/// A feature counts as changed by a fault when its value moved by more than this share of its
/// range over the sample trajectory (or appeared or vanished): smaller moves are below what the
/// clean noise does anyway.
pub const CHANGE_TOLERANCE: f64 = 0.01;

/// Failures while checking fault settings.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum FaultError {
    /// A fault's settings are inconsistent or out of range.
    #[error("fault {index} (`{name}`): {message}")]
    Invalid {
        /// Position in the `[[faults]]` list.
        index: usize,
        /// Its name.
        name: String,
        /// What is wrong and how to fix it.
        message: String,
    },
}

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
    fn is_feature_fault(self) -> bool {
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

/// A checked fault: what it does, to which features, on which frames.
#[derive(Debug, Clone, PartialEq)]
struct Fault {
    name: String,
    kind: FaultKind,
    effect: Effect,
    share: f64,
    window: Option<[usize; 2]>,
    burst: usize,
}

/// What a checked fault does to a frame.
#[derive(Debug, Clone, PartialEq)]
enum Effect {
    Occluder {
        rect: [f64; 4],
        intensity: u8,
        velocity: [f64; 2],
    },
    Glare {
        centre: [f64; 2],
        radius: f64,
        peak: f64,
    },
    SaltPepper {
        density: f64,
    },
    Black,
    Dropped,
    /// A feature fault on these feature indices.
    Features {
        indices: Vec<usize>,
        change: Change,
        units: FaultUnits,
    },
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Change {
    Stuck(f64),
    Offset(f64),
    Gain(f64),
    Dropout,
    Noise(f64),
}

/// The checked `[[faults]]` of a scenario, in order.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FaultPlan {
    faults: Vec<Fault>,
}

/// How a feature varies over the sample trajectory: the scale of `units = "sd"` and of
/// [`CHANGE_TOLERANCE`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FeatureScale {
    /// Mean.
    pub mean: f64,
    /// Standard deviation.
    pub sd: f64,
    /// Largest minus smallest value.
    pub range: f64,
}

impl FeatureScale {
    /// The scales of every feature (column) of `rows`, missing values skipped; a feature never
    /// present gets mean 0, sd 0, range 0.
    pub fn of_rows(rows: &[Vec<Option<f64>>], n_features: usize) -> Vec<FeatureScale> {
        (0..n_features)
            .map(|j| {
                let values: Vec<f64> = rows
                    .iter()
                    .filter_map(|r| r.get(j).copied().flatten())
                    .collect();
                if values.is_empty() {
                    return FeatureScale {
                        mean: 0.0,
                        sd: 0.0,
                        range: 0.0,
                    };
                }
                let n = values.len() as f64;
                let mean = values.iter().sum::<f64>() / n;
                let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n;
                let (lo, hi) = values
                    .iter()
                    .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| {
                        (a.min(v), b.max(v))
                    });
                FeatureScale {
                    mean,
                    sd: var.sqrt(),
                    range: hi - lo,
                }
            })
            .collect()
    }
}

/// The ground truth of one frame's faults.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct FrameFaults {
    /// Names of the faults that struck (in the plan's order).
    pub faults: Vec<String>,
    /// Features whose value the faults changed (ascending), present or not afterwards.
    pub changed: Vec<usize>,
    /// The frame was lost.
    pub dropped: bool,
}

impl FrameFaults {
    /// Whether the faults changed what the frame measures.
    pub fn corrupted(&self) -> bool {
        self.dropped || !self.changed.is_empty()
    }
}

/// A motion's feature rows after the faults, with each frame's ground truth.
#[derive(Debug, Clone, PartialEq)]
pub struct Corrupted {
    /// Feature rows as the estimators see them.
    pub rows: Vec<Vec<Option<f64>>>,
    /// Per frame, what struck it.
    pub labels: Vec<FrameFaults>,
}

impl FaultPlan {
    /// Checks `specs` against the scenario's feature names and image size.
    ///
    /// # Errors
    /// [`FaultError::Invalid`] naming the fault and the field.
    pub fn check(
        specs: &[FaultSpec],
        feature_names: &[String],
        image_size: [u32; 2],
    ) -> Result<Self, FaultError> {
        let faults = specs
            .iter()
            .enumerate()
            .map(|(index, spec)| check_one(index, spec, feature_names, image_size))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Self { faults })
    }

    /// Whether there is no fault.
    pub fn is_empty(&self) -> bool {
        self.faults.is_empty()
    }

    /// Whether any fault changes images (so features are extracted again).
    pub fn touches_images(&self) -> bool {
        self.faults.iter().any(|f| !f.kind.is_feature_fault())
    }

    /// Applies the plan to one motion: `images` and their `clean` feature rows (one per image),
    /// `set` to extract features again from changed images, `scales` of the features over the
    /// sample trajectory. Every draw comes from `seed`; the same arguments give the same output,
    /// bit for bit.
    pub fn apply<'a>(
        &self,
        seed: u64,
        images: impl Iterator<Item = &'a GrayImage>,
        clean: &[Vec<Option<f64>>],
        set: &FeatureSet,
        scales: &[FeatureScale],
    ) -> Corrupted {
        let n_frames = clean.len();
        let mut rngs: Vec<ChaCha8Rng> = (0..self.faults.len())
            .map(|k| ChaCha8Rng::seed_from_u64(crate::seed::derive(seed, &format!("fault{k}"))))
            .collect();
        // Which frames each fault strikes: drawn first, whole, so effects cannot shift them.
        let strikes: Vec<Vec<bool>> = self
            .faults
            .iter()
            .zip(&mut rngs)
            .map(|(f, rng)| active_frames(n_frames, f.share, f.window, f.burst, rng))
            .collect();
        let mut rows = Vec::with_capacity(n_frames);
        let mut labels = Vec::with_capacity(n_frames);
        for (i, image) in images.take(n_frames).enumerate() {
            let struck: Vec<usize> = (0..self.faults.len()).filter(|&k| strikes[k][i]).collect();
            let mut label = FrameFaults {
                faults: struck
                    .iter()
                    .map(|&k| self.faults[k].name.clone())
                    .collect(),
                ..FrameFaults::default()
            };
            let mut edited: Option<GrayImage> = None;
            for &k in &struck {
                let fault = &self.faults[k];
                let rng = &mut rngs[k];
                let offset = i.saturating_sub(fault.window.map_or(0, |w| w[0])) as f64;
                match &fault.effect {
                    Effect::Dropped => label.dropped = true,
                    Effect::Features { .. } => {}
                    effect => {
                        let img = edited.get_or_insert_with(|| image.clone());
                        image_faults::paint(img, effect, offset, rng);
                    }
                }
            }
            let mut row = if label.dropped {
                vec![None; set.len()]
            } else if let Some(img) = &edited {
                set.extract(img)
            } else {
                clean[i].clone()
            };
            // A lost frame has nothing for a feature fault to change.
            for &k in struck.iter().filter(|_| !label.dropped) {
                if let Effect::Features {
                    indices,
                    change,
                    units,
                } = &self.faults[k].effect
                {
                    for &j in indices {
                        row[j] = change_value(row[j], *change, *units, scales[j], &mut rngs[k]);
                    }
                }
            }
            label.changed = (0..row.len())
                .filter(|&j| changed(clean[i][j], row[j], scales[j].range))
                .collect();
            rows.push(row);
            labels.push(label);
        }
        Corrupted { rows, labels }
    }
}

/// Whether a feature value counts as changed (see [`CHANGE_TOLERANCE`]).
fn changed(clean: Option<f64>, now: Option<f64>, range: f64) -> bool {
    match (clean, now) {
        (Some(a), Some(b)) => (a - b).abs() > CHANGE_TOLERANCE * range,
        (None, None) => false,
        _ => true,
    }
}

fn change_value(
    value: Option<f64>,
    change: Change,
    units: FaultUnits,
    scale: FeatureScale,
    rng: &mut ChaCha8Rng,
) -> Option<f64> {
    let unit = match units {
        FaultUnits::Raw => 1.0,
        FaultUnits::Sd => scale.sd,
    };
    match change {
        Change::Stuck(v) => Some(match units {
            FaultUnits::Raw => v,
            FaultUnits::Sd => scale.mean + v * scale.sd,
        }),
        Change::Dropout => None,
        // A noise draw is made whether or not the value is present, so later frames do not
        // depend on which earlier ones were missing.
        Change::Noise(sigma) => {
            let z: f64 = rng.sample(StandardNormal);
            value.map(|x| x + z * sigma * unit)
        }
        Change::Offset(by) => value.map(|x| x + by * unit),
        Change::Gain(factor) => value.map(|x| x * factor),
    }
}

fn check_one(
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

#[cfg(test)]
#[path = "faults_tests.rs"]
mod tests;
