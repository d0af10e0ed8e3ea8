//! What a run measured: one record per tracked frame (the rows of `frames.csv` and of `track`'s
//! output) and the run's summary (`results.json`, one row of a sweep table).

use serde::{Deserialize, Serialize};

use super::{distance, ErrorStats};
use crate::estimator::PoseEstimate;
use crate::evidence::ConflictLevel;
use crate::model::EvidentialModel;
use crate::scenario::{Expectations, Scenario};

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
    /// Estimate (mm); `None` when the frame gave nothing to estimate from.
    pub estimate: Option<[f64; 2]>,
    /// Distance between the two (mm).
    pub error: Option<f64>,
    /// Features combined (indices), for methods that choose them.
    pub group: Option<Vec<usize>>,
    /// Level of conflict of the chosen group.
    pub conflict_level: Option<f64>,
    /// Radius holding the method's stated share of its belief (mm).
    pub uncertainty_radius: Option<f64>,
    /// Missing features, fallback, no estimate: empty when the frame is clean.
    pub flags: String,
}

impl FrameRecord {
    /// The record of one estimated frame; `names` are the estimator's feature names.
    pub fn new(
        motion: &str,
        frame: usize,
        t: f64,
        truth: Option<[f64; 2]>,
        estimate: &PoseEstimate,
        names: &[String],
    ) -> Self {
        Self {
            motion: motion.to_string(),
            frame,
            t,
            truth,
            estimate: estimate.pose,
            error: estimate.pose.zip(truth).map(|(e, t)| distance(e, t)),
            group: estimate.group.clone(),
            conflict_level: estimate.conflict_level,
            uncertainty_radius: estimate.uncertainty_radius,
            flags: estimate.flag_words(names),
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
        let group: Vec<&str> = r
            .group
            .iter()
            .flatten()
            .map(|&g| names[g].as_str())
            .collect();
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

/// Wall time of each stage of a run, in seconds.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Timings {
    /// Simulating and rendering (0 when the workbench had the datasets already).
    pub simulate: f64,
    /// Feature extraction.
    pub features: f64,
    /// Fitting the estimator, validation included (threshold, per-feature errors, tuning).
    pub train: f64,
    /// Tracking the test motions.
    pub track: f64,
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
    /// The summary of a run of `scenario` whose fitted `model` tracked `records`.
    pub fn new(
        scenario: &Scenario,
        model: &EvidentialModel,
        adaptive_added: usize,
        records: &[FrameRecord],
        per_motion: Vec<(String, Option<ErrorStats>)>,
        timings: Timings,
    ) -> Self {
        let errors: Vec<f64> = records.iter().filter_map(|r| r.error).collect();
        let with_estimate = records.iter().filter(|r| r.estimate.is_some()).count();
        let track = model.track_settings();
        Self {
            scenario: scenario.name.clone(),
            seed: scenario.seed,
            samples: model.sample_poses().len(),
            adaptive_added,
            features: model
                .feature_names()
                .iter()
                .map(|n| n.to_string())
                .collect(),
            states: model
                .frames()
                .features()
                .iter()
                .map(|f| f.frame_size())
                .collect(),
            constructor: format!("{:?}", track.constructor).to_lowercase(),
            conflict_threshold: track.conflict_threshold,
            threshold_learned: model.threshold_learned(),
            error: ErrorStats::from_errors(&errors),
            per_motion,
            frames: records.len(),
            frames_without_estimate: records.len() - with_estimate,
            frames_flagged: records.iter().filter(|r| !r.flags.is_empty()).count(),
            mean_group_size: records
                .iter()
                .map(|r| r.group.as_ref().map_or(0, Vec::len) as f64)
                .sum::<f64>()
                / records.len().max(1) as f64,
            paper_error: scenario.paper_error,
            expect: scenario.expect.clone(),
            timings,
        }
    }

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

#[cfg(test)]
mod tests {
    use super::*;

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
