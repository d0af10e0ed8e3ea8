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
mod spec;

pub use schedule::active_frames;
use spec::check_one;
pub use spec::{FaultKind, FaultSpec, FaultUnits};

use ::image::GrayImage;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use serde::{Deserialize, Serialize};

use crate::features::{FeatureRows, FeatureSet};

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

    /// Whether any fault struck the frame, whether or not it changed a feature beyond the
    /// tolerance: such a frame is not clean, though it may not count as corrupted.
    pub fn struck(&self) -> bool {
        self.dropped || !self.faults.is_empty()
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
        let mut extract = |_: &[usize], edited: &[GrayImage]| {
            Ok::<_, std::convert::Infallible>(set.extract_batch(edited))
        };
        self.apply_with(seed, images, clean, scales, &mut extract)
            .unwrap_or_else(|never| match never {})
    }

    /// [`FaultPlan::apply`] with the features of the changed images from
    /// `extract(frame indices, images)`, called once with every changed image of the motion (so
    /// that a feature program runs once).
    ///
    /// # Errors
    /// `extract`'s.
    pub fn apply_with<'a, E>(
        &self,
        seed: u64,
        images: impl Iterator<Item = &'a GrayImage>,
        clean: &[Vec<Option<f64>>],
        scales: &[FeatureScale],
        extract: &mut ExtractChanged<'_, E>,
    ) -> Result<Corrupted, E> {
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
        // Images first (each fault's stream is drawn by one kind of effect only, so painting
        // every frame before changing any feature keeps every stream's order).
        let mut struck_by = Vec::with_capacity(n_frames);
        let mut labels = Vec::with_capacity(n_frames);
        let (mut edited_at, mut edited) = (Vec::new(), Vec::new());
        for (i, image) in images.take(n_frames).enumerate() {
            let struck: Vec<usize> = (0..self.faults.len()).filter(|&k| strikes[k][i]).collect();
            let mut label = FrameFaults {
                faults: struck
                    .iter()
                    .map(|&k| self.faults[k].name.clone())
                    .collect(),
                ..FrameFaults::default()
            };
            let mut painted: Option<GrayImage> = None;
            for &k in &struck {
                let fault = &self.faults[k];
                let rng = &mut rngs[k];
                let offset = i.saturating_sub(fault.window.map_or(0, |w| w[0])) as f64;
                match &fault.effect {
                    Effect::Dropped => label.dropped = true,
                    Effect::Features { .. } => {}
                    effect => {
                        let img = painted.get_or_insert_with(|| image.clone());
                        image_faults::paint(img, effect, offset, rng);
                    }
                }
            }
            if let (false, Some(img)) = (label.dropped, painted) {
                edited_at.push(i);
                edited.push(img);
            }
            struck_by.push(struck);
            labels.push(label);
        }
        let mut extracted = edited_at.iter().copied().zip(extract(&edited_at, &edited)?);
        let mut next = extracted.next();
        let mut rows = Vec::with_capacity(n_frames);
        for (i, (label, struck)) in labels.iter_mut().zip(&struck_by).enumerate() {
            let mut row = if label.dropped {
                vec![None; clean[i].len()]
            } else if next.as_ref().is_some_and(|(k, _)| *k == i) {
                let (_, row) = next.take().unwrap_or_default();
                next = extracted.next();
                row
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
        }
        Ok(Corrupted { rows, labels })
    }
}

/// Features of changed images: `(frame indices, images) → rows`, for [`FaultPlan::apply_with`].
pub type ExtractChanged<'a, E> = dyn FnMut(&[usize], &[GrayImage]) -> Result<FeatureRows, E> + 'a;

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

#[cfg(test)]
#[path = "faults_tests.rs"]
mod tests;
