//! Running a scenario: simulate, extract features, train, track, measure.
//!
//! A [`Workbench`] memoises simulated datasets and feature matrices by their settings, so the
//! variants of a sweep that share a sample trajectory or a test motion simulate it once; results do
//! not depend on which variant asked first, since every dataset is a pure function of its settings
//! and seed.

use std::collections::HashMap;
use std::sync::{Arc, Mutex, OnceLock};
use std::time::Instant;

use serde::{Deserialize, Serialize};

use crate::dataset::Dataset;
use crate::evidence::ConflictLevel;
use crate::features::FeatureConfig;
use crate::model::EvidentialModel;
use crate::report::{distance, ErrorStats};
use crate::scenario::{Expectations, Scenario};
use crate::sim::{Motion, SimSettings};
use crate::track::{self, FrameEstimate, TrackSettings, Tracker};

/// Failures while running a scenario.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ExperimentError {
    /// The simulator failed (bad settings or motion, or the physics).
    #[error("simulating {what}: {message}")]
    Simulate {
        /// Which trajectory.
        what: String,
        /// The simulator's message.
        message: String,
    },
    /// The feature configuration is invalid.
    #[error("feature configuration: {0}")]
    Features(String),
    /// Training the evidential model failed.
    #[error("training the model: {0}")]
    Train(String),
    /// The tracker settings are invalid.
    #[error("tracker settings: {0}")]
    Track(String),
    /// The scenario is invalid.
    #[error("{0}")]
    Scenario(String),
    /// Writing results failed.
    #[error("writing {path}: {message}")]
    Write {
        /// The file.
        path: String,
        /// What went wrong.
        message: String,
    },
    /// A dataset has no ground truth where the run needs it.
    #[error("{0} has no ground truth; simulated datasets always do")]
    NoTruth(String),
}

/// Derives an independent seed for one named stream of a run.
pub fn derive_seed(master: u64, stream: &str) -> u64 {
    // FNV-1a of the stream name, then a splitmix64 finaliser over the mix.
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in stream.bytes() {
        h ^= u64::from(b);
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    let mut z = master ^ h;
    z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// A part of a scenario that is simulated on its own seed stream.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Part {
    /// The sample trajectory.
    Sample,
    /// The validation motion.
    Validation,
    /// The test motion of this index.
    Test(usize),
}

/// The seed a run simulates `part` with, derived from the scenario's master seed; `simulate
/// --scenario` uses it too, so both produce the same dataset.
pub fn part_seed(master: u64, part: Part) -> u64 {
    match part {
        Part::Sample => derive_seed(master, "sample"),
        Part::Validation => derive_seed(master, "validation"),
        Part::Test(k) => derive_seed(master, &format!("test{k}")),
    }
}

type Shared<T> = Arc<OnceLock<Result<Arc<T>, String>>>;

/// Feature values of a dataset's frames, one row per frame.
pub type FeatureRows = Vec<Vec<Option<f64>>>;

/// Memoised datasets and feature matrices, shared by the variants of a sweep (and its threads).
#[derive(Default)]
pub struct Workbench {
    datasets: Mutex<HashMap<String, Shared<Dataset>>>,
    features: Mutex<HashMap<String, Shared<FeatureRows>>>,
}

fn memo<T>(
    map: &Mutex<HashMap<String, Shared<T>>>,
    key: String,
    make: impl FnOnce() -> Result<T, String>,
) -> Result<Arc<T>, String> {
    let cell = {
        // A poisoned lock only means another thread panicked while inserting; the map is intact.
        let mut guard = map.lock().unwrap_or_else(|e| e.into_inner());
        guard.entry(key).or_default().clone()
    };
    cell.get_or_init(|| make().map(Arc::new)).clone()
}

impl Workbench {
    /// A new, empty workbench.
    pub fn new() -> Self {
        Self::default()
    }

    /// The dataset `motion` produces on `sim` with `seed`, simulated once.
    pub fn dataset(
        &self,
        sim: &SimSettings,
        motion: &Motion,
        seed: u64,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<Arc<Dataset>, ExperimentError> {
        let key = serde_json::json!({"sim": sim, "motion": motion, "seed": seed}).to_string();
        memo(&self.datasets, key, || {
            crate::sim::simulate(sim, motion, seed, progress).map_err(|e| e.to_string())
        })
        .map_err(|message| ExperimentError::Simulate {
            what: motion.name().to_string(),
            message,
        })
    }

    /// The feature rows of a dataset obtained as in [`Workbench::dataset`].
    pub fn features(
        &self,
        sim: &SimSettings,
        motion: &Motion,
        seed: u64,
        config: &FeatureConfig,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<Arc<FeatureRows>, ExperimentError> {
        let dataset = self.dataset(sim, motion, seed, progress)?;
        let set = config
            .check()
            .map_err(|e| ExperimentError::Features(e.to_string()))?;
        let key =
            serde_json::json!({"sim": sim, "motion": motion, "seed": seed, "features": config})
                .to_string();
        memo(&self.features, key, || {
            Ok(set.extract_batch(dataset.frames.iter().map(|f| &f.image)))
        })
        .map_err(ExperimentError::Features)
    }
}

/// Wall time of each stage of a run, in seconds.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Timings {
    /// Simulating and rendering (0 when the workbench had the datasets already).
    pub simulate: f64,
    /// Feature extraction.
    pub features: f64,
    /// Training (and tuning) the model.
    pub train: f64,
    /// Validation: learning the threshold and per-feature errors.
    pub validate: f64,
    /// Tracking the test motions.
    pub track: f64,
}

/// One tracked frame of a test motion.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FrameRecord {
    /// Which test motion (`test0`, `test1`, …) and its kind.
    pub motion: String,
    /// Frame index within that motion.
    pub frame: usize,
    /// Time (s).
    pub t: f64,
    /// Ground truth (mm).
    pub truth: Option<[f64; 2]>,
    /// Estimate (mm); `None` when no feature was usable.
    pub estimate: Option<[f64; 2]>,
    /// Distance between the two (mm).
    pub error: Option<f64>,
    /// Features combined (indices).
    pub group: Vec<usize>,
    /// Level of conflict of the chosen group.
    pub conflict_level: Option<f64>,
    /// Radius holding the configured share of the relative plausibility (mm).
    pub uncertainty_radius: Option<f64>,
    /// Missing features, fallback, no estimate: empty when the frame is clean.
    pub flags: String,
}

impl FrameRecord {
    /// The record of one tracked frame; `names` are the model's feature names.
    pub fn new(
        motion: &str,
        frame: usize,
        t: f64,
        truth: Option<[f64; 2]>,
        estimate: &FrameEstimate,
        names: &[String],
    ) -> Self {
        Self {
            motion: motion.to_string(),
            frame,
            t,
            truth,
            estimate: estimate.estimate,
            error: estimate.estimate.zip(truth).map(|(e, t)| distance(e, t)),
            group: estimate.group.clone(),
            conflict_level: estimate.conflict_level,
            uncertainty_radius: estimate.uncertainty.map(|u| u.radius),
            flags: frame_flags(estimate, names),
        }
    }
}

/// Writes frame records as CSV (the `frames.csv` of a run, and what `track` prints): one row per
/// frame, the combined group as feature names joined by `+`, empty cells for missing values.
pub fn write_frames_csv<W: std::io::Write>(
    writer: W,
    records: &[FrameRecord],
    names: &[String],
) -> Result<(), csv::Error> {
    let mut csv = csv::Writer::from_writer(writer);
    csv.write_record([
        "motion",
        "frame",
        "t",
        "true_x",
        "true_y",
        "est_x",
        "est_y",
        "error",
        "group",
        "conflict_level",
        "uncertainty_radius",
        "flags",
    ])?;
    let num = |v: Option<f64>| v.map(|v| v.to_string()).unwrap_or_default();
    for r in records {
        let group: Vec<&str> = r.group.iter().map(|&g| names[g].as_str()).collect();
        csv.write_record([
            r.motion.clone(),
            r.frame.to_string(),
            r.t.to_string(),
            num(r.truth.map(|p| p[0])),
            num(r.truth.map(|p| p[1])),
            num(r.estimate.map(|p| p[0])),
            num(r.estimate.map(|p| p[1])),
            num(r.error),
            group.join("+"),
            num(r.conflict_level),
            num(r.uncertainty_radius),
            r.flags.clone(),
        ])?;
    }
    csv.flush()?;
    Ok(())
}

/// What a run measured, small enough to print, store as JSON and compare across runs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunSummary {
    /// Scenario (variant) name.
    pub scenario: String,
    /// Master seed.
    pub seed: u64,
    /// Number of sample poses the model was trained on.
    pub samples: usize,
    /// Samples added by the adaptive trajectory.
    pub adaptive_added: usize,
    /// Feature names.
    pub features: Vec<String>,
    /// Frame size (kept HMM states) of each feature.
    pub states: Vec<usize>,
    /// Belief-function constructor.
    pub constructor: String,
    /// Conflict threshold used (`"inf"` in JSON when every compatible pair is combined).
    pub conflict_threshold: ConflictLevel,
    /// Whether it was learned on the validation motion.
    pub threshold_learned: bool,
    /// Error statistics over every test frame with an estimate.
    pub error: Option<ErrorStats>,
    /// Per test motion.
    pub per_motion: Vec<(String, Option<ErrorStats>)>,
    /// Test frames.
    pub frames: usize,
    /// Test frames without an estimate.
    pub frames_without_estimate: usize,
    /// Test frames with any flag (missing features, features left out, fallback).
    pub frames_flagged: usize,
    /// Mean number of features combined per frame.
    pub mean_group_size: f64,
    /// The paper's figure for this setup, when the scenario gives it.
    pub paper_error: Option<f64>,
    /// What the scenario expects.
    pub expect: Expectations,
    /// Stage timings.
    pub timings: Timings,
}

impl RunSummary {
    /// The expectations this run misses, as readable sentences (empty when all hold).
    pub fn regressions(&self) -> Vec<String> {
        let mut missed = Vec::new();
        if let Some(limit) = self.expect.max_mean_error {
            match &self.error {
                Some(stats) if stats.mean <= limit => {}
                Some(stats) => missed.push(format!(
                    "{}: mean error {:.4} mm exceeds the expected maximum {limit} mm",
                    self.scenario, stats.mean
                )),
                None => missed.push(format!(
                    "{}: no frame has an estimate, expected a mean error ≤ {limit} mm",
                    self.scenario
                )),
            }
        }
        if let Some(limit) = self.expect.max_missing_share {
            let share = self.frames_without_estimate as f64 / self.frames.max(1) as f64;
            if share > limit {
                missed.push(format!(
                    "{}: {:.1}% of frames have no estimate, expected at most {:.1}%",
                    self.scenario,
                    100.0 * share,
                    100.0 * limit
                ));
            }
        }
        missed
    }
}

/// Everything a run produced.
#[derive(Debug, Clone)]
pub struct RunOutput {
    /// The numbers.
    pub summary: RunSummary,
    /// Every tracked test frame.
    pub records: Vec<FrameRecord>,
    /// The trained model (with its learned threshold, if any).
    pub model: EvidentialModel,
    /// For each sample pose of the model, the adaptive round that added it (0: the initial
    /// trajectory).
    pub sample_rounds: Vec<usize>,
}

/// Receives progress: stage name, done, total.
pub type Progress<'a> = &'a mut dyn FnMut(&str, usize, usize);

/// The flags of a tracked frame as short words (`missing:…`, `excluded:…`, `fallback`,
/// `combination_failed`, `no_estimate`); empty when the frame is clean.
pub fn frame_flags(estimate: &FrameEstimate, names: &[String]) -> String {
    let flags = &estimate.flags;
    let mut parts = Vec::new();
    let missing: Vec<&str> = flags.missing().map(|i| names[i].as_str()).collect();
    if !missing.is_empty() {
        parts.push(format!("missing:{}", missing.join("+")));
    }
    if !flags.excluded.is_empty() {
        let excluded: Vec<&str> = flags.excluded.iter().map(|&i| names[i].as_str()).collect();
        parts.push(format!("excluded:{}", excluded.join("+")));
    }
    if flags.fallback {
        parts.push("fallback".into());
    }
    if flags.combination_failed {
        parts.push("combination_failed".into());
    }
    if estimate.estimate.is_none() {
        parts.push("no_estimate".into());
    }
    parts.join(" ")
}

/// The tracker's view of a trained model, with these settings.
pub fn tracker_for(
    model: &EvidentialModel,
    settings: &TrackSettings,
) -> Result<Tracker, ExperimentError> {
    let track_error = |e: track::TrackError| ExperimentError::Track(e.to_string());
    let validation = model.validation_errors();
    let features = model
        .features()
        .iter()
        .enumerate()
        .map(|(i, f)| track::FeatureModel {
            refining: f.refining().clone(),
            validation_error: validation.map(|v| v[i]),
        })
        .collect();
    let tracker_model =
        track::TrackerModel::new(model.sample_poses().to_vec(), features).map_err(track_error)?;
    let checked = settings.clone().check().map_err(track_error)?;
    Tracker::new(tracker_model, checked).map_err(track_error)
}

/// Tracks frames; returns the per-frame estimates.
fn track_rows(
    model: &EvidentialModel,
    tracker: &Tracker,
    rows: &[Vec<Option<f64>>],
) -> Result<Vec<FrameEstimate>, ExperimentError> {
    rows.iter()
        .map(|row| {
            let likelihoods = model
                .likelihoods(row)
                .map_err(|e| ExperimentError::Track(e.to_string()))?;
            tracker
                .track(&likelihoods)
                .map_err(|e| ExperimentError::Track(e.to_string()))
        })
        .collect()
}

fn truths(dataset: &Dataset, what: &str) -> Result<Vec<[f64; 2]>, ExperimentError> {
    dataset
        .truth_positions()
        .ok_or_else(|| ExperimentError::NoTruth(what.to_string()))
}

/// Mean distance of the estimates to the truth, a frame without an estimate counting as
/// `penalty` (the workspace diagonal), so a feature that rarely gives an estimate ranks low and
/// the score stays finite.
fn validation_error(estimates: &[FrameEstimate], truth: &[[f64; 2]], penalty: f64) -> f64 {
    let total: f64 = estimates
        .iter()
        .zip(truth)
        .map(|(e, t)| e.estimate.map_or(penalty, |p| distance(p, *t)))
        .sum();
    total / truth.len().max(1) as f64
}

/// The penalty of a frame without an estimate: the workspace diagonal, the largest error an
/// estimate inside the workspace can have.
fn missing_penalty(sim: &SimSettings) -> f64 {
    let w = sim.geometry.workspace;
    (w.x_max - w.x_min).hypot(w.y_max - w.y_min)
}

/// Scores candidate state counts by the tracking error of the candidate feature alone on the
/// validation motion (§5.2, "learned from the measured estimation error as nᵢ increases").
struct ValidationTuner<'a> {
    rows: &'a [Vec<Option<f64>>],
    truth: &'a [[f64; 2]],
    settings: &'a TrackSettings,
    penalty: f64,
}

impl crate::model::StateCountTuner for ValidationTuner<'_> {
    fn score(
        &mut self,
        feature: usize,
        candidate: &crate::model::FeatureModel,
        sample_poses: &[[f64; 2]],
    ) -> Result<f64, crate::model::TunerError> {
        let tracker_model = track::TrackerModel::new(
            sample_poses.to_vec(),
            vec![track::FeatureModel {
                refining: candidate.refining().clone(),
                validation_error: None,
            }],
        )?;
        let checked = self.settings.clone().check()?;
        let tracker = Tracker::new(tracker_model, checked)?;
        let estimates = self
            .rows
            .iter()
            .map(|row| tracker.track(&[candidate.likelihoods(row[feature])]))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(validation_error(&estimates, self.truth, self.penalty))
    }
}

/// Runs one scenario: simulate, extract, train, validate, track, measure.
pub fn run(
    scenario: &Scenario,
    bench: &Workbench,
    progress: Progress<'_>,
) -> Result<RunOutput, ExperimentError> {
    scenario
        .check()
        .map_err(|e| ExperimentError::Scenario(e.to_string()))?;
    let mut timings = Timings::default();
    let set = scenario
        .features
        .check()
        .map_err(|e| ExperimentError::Features(e.to_string()))?;
    let names = set.names();
    let seed = scenario.seed;
    let sim = &scenario.sim;

    // The sample trajectory.
    let clock = Instant::now();
    let sample_seed = part_seed(seed, Part::Sample);
    let motion = &scenario.sample.motion;
    let dataset = bench.dataset(sim, motion, sample_seed, &mut |d, t| {
        progress("sample", d, t)
    })?;
    timings.simulate += clock.elapsed().as_secs_f64();
    let clock = Instant::now();
    let rows = bench.features(sim, motion, sample_seed, &scenario.features, &mut |_, _| {})?;
    timings.features += clock.elapsed().as_secs_f64();
    let all_poses = truths(&dataset, "the sample trajectory")?;
    let keep = scenario.sample.keep_every;
    let mut poses: Vec<[f64; 2]> = all_poses.iter().step_by(keep).copied().collect();
    let mut sample_rows: Vec<Vec<Option<f64>>> = rows.iter().step_by(keep).cloned().collect();

    // The adaptive sample trajectory (§3.1): the model's features say where samples are
    // missing, the world renders them.
    let mut adaptive_added = 0;
    let mut sample_rounds = vec![0; poses.len()];
    if let Some(adaptive) = &scenario.sample.adaptive {
        let clock = Instant::now();
        let mut round = 0usize;
        let mut measured_truth: Vec<[f64; 2]> = Vec::new();
        let workspace = sim.geometry.workspace;
        let outcome = crate::adaptive::refine(poses.clone(), sample_rows, adaptive, |points| {
            round += 1;
            // Midpoints of boundary samples can lie a few µm outside the workspace, because the
            // samples are simulated (not commanded) poses: clamp them back in.
            let points = points
                .iter()
                .map(|p| {
                    [
                        p[0].clamp(workspace.x_min, workspace.x_max),
                        p[1].clamp(workspace.y_min, workspace.y_max),
                    ]
                })
                .collect();
            let motion = Motion::Points { points };
            let seed = derive_seed(seed, &format!("adaptive{round}"));
            let data =
                crate::sim::simulate(sim, &motion, seed, &mut |d, t| progress("adaptive", d, t))
                    .map_err(|e| e.to_string())?;
            measured_truth.extend(data.truth_positions().ok_or("no ground truth")?);
            Ok(set.extract_batch(data.images()))
        })
        .map_err(|e| ExperimentError::Simulate {
            what: "the adaptive sample trajectory".into(),
            message: e.to_string(),
        })?;
        adaptive_added = outcome.added().len();
        for (round, &count) in outcome.added_per_round.iter().enumerate() {
            sample_rounds.extend(std::iter::repeat_n(round + 1, count));
        }
        poses.extend(measured_truth);
        sample_rows = outcome.features;
        timings.simulate += clock.elapsed().as_secs_f64();
    }

    // Validation data, needed for tuning by validation error and for the threshold.
    let validation = match &scenario.validation {
        Some(motion) => {
            let clock = Instant::now();
            let vseed = part_seed(seed, Part::Validation);
            let data =
                bench.dataset(sim, motion, vseed, &mut |d, t| progress("validation", d, t))?;
            timings.simulate += clock.elapsed().as_secs_f64();
            let clock = Instant::now();
            let rows = bench.features(sim, motion, vseed, &scenario.features, &mut |_, _| {})?;
            timings.features += clock.elapsed().as_secs_f64();
            Some((truths(&data, "the validation motion")?, rows))
        }
        None => None,
    };

    // Training, on its own stream of the master seed (`model.seed` picks among streams).
    let clock = Instant::now();
    let model_settings = crate::model::ModelSettings {
        seed: derive_seed(seed, &format!("model{}", scenario.model.seed)),
        ..scenario.model.clone()
    };
    progress("train", 0, 1);
    let train_error = |e: crate::model::ModelError| ExperimentError::Train(e.to_string());
    let mut model = match (&scenario.model.tuning, &validation) {
        (crate::model::Tuning::Validation { .. }, Some((truth, rows))) => {
            let mut tuner = ValidationTuner {
                rows,
                truth,
                settings: &scenario.track,
                penalty: missing_penalty(sim),
            };
            EvidentialModel::train_with_tuner(
                &poses,
                &names,
                &sample_rows,
                &model_settings,
                &mut tuner,
            )
            .map_err(train_error)?
        }
        (crate::model::Tuning::Validation { .. }, None) => {
            return Err(ExperimentError::Train(
                "tuning state counts by validation error needs a [validation] motion".into(),
            ))
        }
        _ => EvidentialModel::train(&poses, &names, &sample_rows, &model_settings)
            .map_err(train_error)?,
    };
    progress("train", 1, 1);
    timings.train = clock.elapsed().as_secs_f64();

    // Validation: each feature's own error (the fallback's ranking) and the threshold (§4.3).
    let clock = Instant::now();
    let mut track_settings = scenario.track.clone();
    if let Some((truth, rows)) = &validation {
        let mut open = track_settings.clone();
        open.conflict_threshold = f64::INFINITY;
        let tracker = tracker_for(&model, &open)?;
        let mut per_feature = Vec::with_capacity(model.n_features());
        for i in 0..model.n_features() {
            let only_i: Vec<Vec<Option<f64>>> = rows
                .iter()
                .map(|row| {
                    (0..row.len())
                        .map(|j| if j == i { row[j] } else { None })
                        .collect()
                })
                .collect();
            let estimates = track_rows(&model, &tracker, &only_i)?;
            per_feature.push(validation_error(&estimates, truth, missing_penalty(sim)));
        }
        model
            .set_validation_errors(Some(per_feature))
            .map_err(train_error)?;
        if scenario.learn_threshold {
            let estimates = track_rows(&model, &tracker, rows)?;
            let mut levels = Vec::new();
            let mut errors = Vec::new();
            for ((row, estimate), t) in rows.iter().zip(&estimates).zip(truth) {
                if let Some(p) = estimate.estimate {
                    let likelihoods = model.likelihoods(row).map_err(train_error)?;
                    let level = tracker
                        .full_conflict_level(&likelihoods)
                        .map_err(|e| ExperimentError::Track(e.to_string()))?;
                    levels.push(level);
                    errors.push(distance(p, *t));
                }
            }
            let threshold = track::learn_conflict_threshold(&levels, &errors)
                .map_err(|e| ExperimentError::Track(e.to_string()))?;
            // +∞ (no finite level to learn from) is stored as "no threshold".
            model
                .set_conflict_threshold(threshold.is_finite().then_some(threshold))
                .map_err(train_error)?;
            track_settings.conflict_threshold = threshold;
        }
    }
    timings.validate = clock.elapsed().as_secs_f64();

    // Tracking the test motions.
    let tracker = tracker_for(&model, &track_settings)?;
    let mut records = Vec::new();
    let mut per_motion = Vec::new();
    for (k, motion) in scenario.tests.iter().enumerate() {
        let label = format!("test{k}:{}", motion.name());
        let clock = Instant::now();
        let tseed = part_seed(seed, Part::Test(k));
        let data = bench.dataset(sim, motion, tseed, &mut |d, t| progress(&label, d, t))?;
        timings.simulate += clock.elapsed().as_secs_f64();
        let clock = Instant::now();
        let rows = bench.features(sim, motion, tseed, &scenario.features, &mut |_, _| {})?;
        timings.features += clock.elapsed().as_secs_f64();
        let truth = truths(&data, &label)?;
        let clock = Instant::now();
        let estimates = track_rows(&model, &tracker, &rows)?;
        timings.track += clock.elapsed().as_secs_f64();
        let mut errors = Vec::new();
        for (i, ((estimate, frame), t)) in
            estimates.iter().zip(&data.frames).zip(&truth).enumerate()
        {
            let record = FrameRecord::new(&label, i, frame.t, Some(*t), estimate, &names);
            errors.extend(record.error);
            records.push(record);
        }
        per_motion.push((label, ErrorStats::from_errors(&errors)));
    }

    let errors: Vec<f64> = records.iter().filter_map(|r| r.error).collect();
    let with_estimate = records.iter().filter(|r| r.estimate.is_some()).count();
    let summary = RunSummary {
        scenario: scenario.name.clone(),
        seed,
        samples: model.sample_poses().len(),
        adaptive_added,
        features: names.clone(),
        states: model.features().iter().map(|f| f.frame_size()).collect(),
        constructor: format!("{:?}", track_settings.constructor).to_lowercase(),
        conflict_threshold: ConflictLevel::from_value(track_settings.conflict_threshold),
        threshold_learned: scenario.learn_threshold && validation.is_some(),
        error: ErrorStats::from_errors(&errors),
        per_motion,
        frames: records.len(),
        frames_without_estimate: records.len() - with_estimate,
        frames_flagged: records.iter().filter(|r| !r.flags.is_empty()).count(),
        mean_group_size: records.iter().map(|r| r.group.len() as f64).sum::<f64>()
            / records.len().max(1) as f64,
        paper_error: scenario.paper_error,
        expect: scenario.expect.clone(),
        timings,
    };
    Ok(RunOutput {
        summary,
        records,
        model,
        sample_rounds,
    })
}

/// Runs several scenarios on `jobs` threads sharing one workbench; results come back in input
/// order. `progress(variant, stage, done, total)` may be called from any thread.
pub fn run_all(
    scenarios: &[Scenario],
    jobs: usize,
    bench: &Workbench,
    progress: &(dyn Fn(usize, &str, usize, usize) + Sync),
) -> Vec<Result<RunOutput, ExperimentError>> {
    let next = std::sync::atomic::AtomicUsize::new(0);
    let results: Mutex<Vec<Option<Result<RunOutput, ExperimentError>>>> =
        Mutex::new((0..scenarios.len()).map(|_| None).collect());
    std::thread::scope(|scope| {
        for _ in 0..jobs.clamp(1, scenarios.len().max(1)) {
            scope.spawn(|| loop {
                let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                let Some(scenario) = scenarios.get(i) else {
                    break;
                };
                let result = run(scenario, bench, &mut |stage, done, total| {
                    progress(i, stage, done, total)
                });
                results.lock().unwrap_or_else(|e| e.into_inner())[i] = Some(result);
            });
        }
    });
    results
        .into_inner()
        .unwrap_or_else(|e| e.into_inner())
        .into_iter()
        .map(|r| r.unwrap_or_else(|| Err(ExperimentError::Scenario("variant was not run".into()))))
        .collect()
}

fn write_error(path: &std::path::Path, error: impl std::fmt::Display) -> ExperimentError {
    ExperimentError::Write {
        path: path.display().to_string(),
        message: error.to_string(),
    }
}

/// Writes a run's outputs into `dir`: `results.json`, `frames.csv`, `samples.csv` (the sample
/// poses and the adaptive round that added each), `model.json` and one
/// `track-<motion>.png` per test motion (true against estimated positions, like the paper's
/// Figure 2). Returns the files written.
pub fn write_run(
    dir: &std::path::Path,
    output: &RunOutput,
) -> Result<Vec<std::path::PathBuf>, ExperimentError> {
    std::fs::create_dir_all(dir).map_err(|e| write_error(dir, e))?;
    let mut written = Vec::new();
    let results = dir.join("results.json");
    let json =
        serde_json::to_string_pretty(&output.summary).map_err(|e| write_error(&results, e))?;
    std::fs::write(&results, json + "\n").map_err(|e| write_error(&results, e))?;
    written.push(results);

    let frames = dir.join("frames.csv");
    let file = std::fs::File::create(&frames).map_err(|e| write_error(&frames, e))?;
    write_frames_csv(
        std::io::BufWriter::new(file),
        &output.records,
        &output.summary.features,
    )
    .map_err(|e| write_error(&frames, e))?;
    written.push(frames);

    let samples = dir.join("samples.csv");
    let mut csv = csv::Writer::from_path(&samples).map_err(|e| write_error(&samples, e))?;
    csv.write_record(["x", "y", "added_in_round"])
        .map_err(|e| write_error(&samples, e))?;
    for (pose, round) in output
        .model
        .sample_poses()
        .iter()
        .zip(&output.sample_rounds)
    {
        csv.write_record([pose[0].to_string(), pose[1].to_string(), round.to_string()])
            .map_err(|e| write_error(&samples, e))?;
    }
    csv.flush().map_err(|e| write_error(&samples, e))?;
    written.push(samples);

    let model = dir.join("model.json");
    output
        .model
        .save(&model)
        .map_err(|e| write_error(&model, e))?;
    written.push(model);

    for (label, stats) in &output.summary.per_motion {
        let records: Vec<&FrameRecord> = output
            .records
            .iter()
            .filter(|r| &r.motion == label)
            .collect();
        let truth: Vec<[f64; 2]> = records.iter().filter_map(|r| r.truth).collect();
        let estimate: Vec<Option<[f64; 2]>> = records.iter().map(|r| r.estimate).collect();
        let file = dir.join(format!("track-{}.png", label.replace(':', "-")));
        let title = match stats {
            Some(s) => format!(
                "{} — {label}: mean error {:.3} mm",
                output.summary.scenario, s.mean
            ),
            None => format!("{} — {label}: no estimate", output.summary.scenario),
        };
        crate::report::plot_trajectory(
            &file,
            &title,
            &truth,
            &estimate,
            Some(output.model.sample_poses()),
        )
        .map_err(|e| write_error(&file, e))?;
        written.push(file);
    }
    Ok(written)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::track::FrameFlags;

    fn frame(estimate: Option<[f64; 2]>) -> FrameEstimate {
        FrameEstimate {
            estimate,
            group: vec![0],
            conflict_level: Some(0.0),
            uncertainty: None,
            plausibility: Vec::new(),
            alternatives: Vec::new(),
            flags: FrameFlags::default(),
        }
    }

    #[test]
    fn frames_without_estimate_count_as_the_penalty() {
        let truth = [[0.0, 40.0], [1.0, 40.0], [2.0, 40.0]];
        let estimates = [
            frame(Some([0.0, 41.0])),
            frame(None),
            frame(Some([2.0, 43.0])),
        ];
        // (1 + 10 + 3) / 3: the missing frame weighs as much as the penalty, not nothing.
        let score = validation_error(&estimates, &truth, 10.0);
        assert!((score - 14.0 / 3.0).abs() < 1e-12);
        let none = [frame(None), frame(None)];
        assert_eq!(validation_error(&none, &truth[..2], 10.0), 10.0);
        let diagonal = missing_penalty(&SimSettings::default());
        assert!((diagonal - 19.0 * 2f64.sqrt()).abs() < 1e-9);
    }

    #[test]
    fn seeds_differ_by_stream_and_master_and_are_stable() {
        let a = part_seed(1, Part::Sample);
        assert_eq!(a, part_seed(1, Part::Sample));
        assert_ne!(a, part_seed(2, Part::Sample));
        assert_ne!(a, part_seed(1, Part::Validation));
        assert_ne!(part_seed(1, Part::Test(0)), part_seed(1, Part::Test(1)));
        assert_eq!(part_seed(7, Part::Test(3)), derive_seed(7, "test3"));
    }

    #[test]
    fn regressions_name_what_missed() {
        let stats = ErrorStats::from_errors(&[2.0, 4.0]);
        let summary = RunSummary {
            scenario: "s".into(),
            seed: 1,
            samples: 4,
            adaptive_added: 0,
            features: vec!["f".into()],
            states: vec![2],
            constructor: "bayesian".into(),
            conflict_threshold: ConflictLevel::Infinite,
            threshold_learned: false,
            error: stats,
            per_motion: Vec::new(),
            frames: 4,
            frames_without_estimate: 2,
            frames_flagged: 2,
            mean_group_size: 1.0,
            paper_error: None,
            expect: Expectations {
                max_mean_error: Some(2.5),
                max_missing_share: Some(0.25),
            },
            timings: Timings::default(),
        };
        let missed = summary.regressions();
        assert_eq!(missed.len(), 2, "{missed:?}");
        assert!(missed[0].contains("mean error 3.0000 mm exceeds"));
        assert!(missed[1].contains("50.0% of frames have no estimate"));
        let relaxed = RunSummary {
            expect: Expectations {
                max_mean_error: Some(3.0),
                max_missing_share: Some(0.5),
            },
            ..summary
        };
        assert!(relaxed.regressions().is_empty());
    }
}
