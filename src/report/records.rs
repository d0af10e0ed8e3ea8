//! What a run measured: one record per tracked frame (the rows of `frames.csv` and of `track`'s
//! output) and the run's summary (`results.json`, one row of a sweep table).

use serde::{Deserialize, Serialize};

use super::{distance, ErrorStats};
use crate::estimator::PoseEstimate;
use crate::evidence::ConflictLevel;
use crate::model::EvidentialModel;
use crate::scenario::{Expectations, MethodExpectations};

/// One tracked frame of a test motion, by one method.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FrameRecord {
    /// The estimation method (`evidential`, `knn`, …).
    pub method: String,
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
    /// The record of one frame estimated by `method`; `names` are the estimator's feature
    /// names.
    pub fn new(
        method: &str,
        motion: &str,
        frame: usize,
        t: f64,
        truth: Option<[f64; 2]>,
        estimate: &PoseEstimate,
        names: &[String],
    ) -> Self {
        Self {
            method: method.to_string(),
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
/// frame and method, the combined group as feature names joined by `+`, empty cells for missing
/// values.
pub fn write_frames_csv<W: std::io::Write>(
    writer: W,
    records: &[FrameRecord],
    names: &[String],
) -> Result<(), csv::Error> {
    let mut csv = csv::Writer::from_writer(writer);
    csv.write_record([
        "method",
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
            r.method.clone(),
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

/// Wall time of the shared stages of a run, in seconds (each method's own times are in its
/// [`MethodSummary`]).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Timings {
    /// Simulating and rendering (0 when the workbench had the datasets already).
    pub simulate: f64,
    /// Feature extraction.
    pub features: f64,
}

/// What one method measured on a run's test frames.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MethodSummary {
    /// The method.
    pub method: String,
    /// Error statistics over every test frame with an estimate.
    pub error: Option<ErrorStats>,
    /// Per test motion.
    pub per_motion: Vec<(String, Option<ErrorStats>)>,
    /// Test frames without an estimate.
    pub frames_without_estimate: usize,
    /// Test frames with any flag (missing features, features left out, fallback, no estimate).
    pub frames_flagged: usize,
    /// Mean number of features combined per frame, for methods that choose them.
    pub mean_group_size: Option<f64>,
    /// Fitting (validation included), in seconds.
    pub fit_seconds: f64,
    /// Estimating every test frame, in seconds.
    pub track_seconds: f64,
}

impl MethodSummary {
    /// The summary of one method's `records` (all of one method).
    pub fn new(
        method: &str,
        records: &[FrameRecord],
        per_motion: Vec<(String, Option<ErrorStats>)>,
        fit_seconds: f64,
        track_seconds: f64,
    ) -> Self {
        let errors: Vec<f64> = records.iter().filter_map(|r| r.error).collect();
        let with_estimate = records.iter().filter(|r| r.estimate.is_some()).count();
        let groups: Vec<usize> = records
            .iter()
            .filter_map(|r| r.group.as_ref().map(Vec::len))
            .collect();
        Self {
            method: method.to_string(),
            error: ErrorStats::from_errors(&errors),
            per_motion,
            frames_without_estimate: records.len() - with_estimate,
            frames_flagged: records.iter().filter(|r| !r.flags.is_empty()).count(),
            mean_group_size: (!groups.is_empty())
                .then(|| groups.iter().sum::<usize>() as f64 / records.len().max(1) as f64),
            fit_seconds,
            track_seconds,
        }
    }
}

/// The evidential model of a run, in brief.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EvidentialSummary {
    /// Frame size (kept HMM states) of each feature.
    pub states: Vec<usize>,
    /// Belief-function constructor.
    pub constructor: String,
    /// Conflict threshold used (`"inf"` in JSON when every compatible pair is combined).
    pub conflict_threshold: ConflictLevel,
    /// Whether it was learned on the validation motion.
    pub threshold_learned: bool,
}

impl EvidentialSummary {
    /// The summary of a fitted evidential model.
    pub fn of(model: &EvidentialModel) -> Self {
        let track = model.track_settings();
        Self {
            states: model
                .frames()
                .features()
                .iter()
                .map(|f| f.frame_size())
                .collect(),
            constructor: format!("{:?}", track.constructor).to_lowercase(),
            conflict_threshold: track.conflict_threshold,
            threshold_learned: model.threshold_learned(),
        }
    }
}

/// What a run measured, small enough to print, store as JSON and compare across runs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunSummary {
    /// Scenario (variant) name.
    pub scenario: String,
    /// Master seed.
    pub seed: u64,
    /// Number of sample poses the estimators were trained on.
    pub samples: usize,
    /// Samples added by the adaptive trajectory.
    pub adaptive_added: usize,
    /// Feature names.
    pub features: Vec<String>,
    /// Test frames (each method estimates every one).
    pub frames: usize,
    /// The evidential model, when the run has the evidential method.
    pub evidential: Option<EvidentialSummary>,
    /// One entry per method, in the scenario's order.
    pub methods: Vec<MethodSummary>,
    /// The paper's figure for this setup (the evidential tracker's), when the scenario gives it.
    pub paper_error: Option<f64>,
    /// What the scenario expects.
    pub expect: Expectations,
    /// Shared stage timings.
    pub timings: Timings,
}

impl RunSummary {
    /// The summary of one method, if the run has it.
    pub fn method(&self, name: &str) -> Option<&MethodSummary> {
        self.methods.iter().find(|m| m.method == name)
    }

    /// The expectations this run misses, as readable sentences (empty when all hold). The
    /// top-level expectations apply to the evidential method; `expect.methods.NAME` to NAME.
    pub fn regressions(&self) -> Vec<String> {
        let mut missed = Vec::new();
        let mut check = |name: &str, limits: &MethodExpectations| {
            let Some(m) = self.method(name) else {
                missed.push(format!(
                    "{}: expectations are given for method `{name}`, which did not run",
                    self.scenario
                ));
                return;
            };
            if let Some(limit) = limits.max_mean_error {
                match &m.error {
                    Some(stats) if stats.mean <= limit => {}
                    Some(stats) => missed.push(format!(
                        "{} ({name}): mean error {:.4} mm exceeds the expected maximum {limit} mm",
                        self.scenario, stats.mean
                    )),
                    None => missed.push(format!(
                        "{} ({name}): no frame has an estimate, expected a mean error ≤ {limit} mm",
                        self.scenario
                    )),
                }
            }
            if let Some(limit) = limits.max_missing_share {
                let share = m.frames_without_estimate as f64 / self.frames.max(1) as f64;
                if share > limit {
                    missed.push(format!(
                        "{} ({name}): {:.1}% of frames have no estimate, expected at most {:.1}%",
                        self.scenario,
                        100.0 * share,
                        100.0 * limit
                    ));
                }
            }
        };
        let top = MethodExpectations {
            max_mean_error: self.expect.max_mean_error,
            max_missing_share: self.expect.max_missing_share,
        };
        if top.max_mean_error.is_some() || top.max_missing_share.is_some() {
            check("evidential", &top);
        }
        for (name, limits) in &self.expect.methods {
            check(name, limits);
        }
        missed
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn method(name: &str, errors: &[f64], without: usize) -> MethodSummary {
        MethodSummary {
            method: name.into(),
            error: ErrorStats::from_errors(errors),
            per_motion: Vec::new(),
            frames_without_estimate: without,
            frames_flagged: without,
            mean_group_size: None,
            fit_seconds: 0.0,
            track_seconds: 0.0,
        }
    }

    #[test]
    fn regressions_name_the_method_and_what_missed() {
        let mut expect = Expectations {
            max_mean_error: Some(2.5),
            max_missing_share: Some(0.25),
            ..Expectations::default()
        };
        expect.methods.insert(
            "knn".into(),
            MethodExpectations {
                max_mean_error: Some(0.5),
                max_missing_share: None,
            },
        );
        expect
            .methods
            .insert("gp".into(), MethodExpectations::default());
        let summary = RunSummary {
            scenario: "s".into(),
            seed: 1,
            samples: 4,
            adaptive_added: 0,
            features: vec!["f".into()],
            frames: 4,
            evidential: None,
            methods: vec![
                method("evidential", &[2.0, 4.0], 2),
                method("knn", &[0.4, 0.8], 0),
            ],
            paper_error: None,
            expect,
            timings: Timings::default(),
        };
        let missed = summary.regressions();
        assert_eq!(missed.len(), 4, "{missed:?}");
        assert!(missed[0].contains("(evidential): mean error 3.0000 mm exceeds"));
        assert!(missed[1].contains("(evidential): 50.0% of frames have no estimate"));
        // BTreeMap order: gp before knn.
        assert!(missed[2].contains("method `gp`, which did not run"));
        assert!(missed[3].contains("(knn): mean error 0.6000 mm exceeds the expected maximum 0.5"));
        let mut relaxed = summary.clone();
        relaxed.expect = Expectations {
            max_mean_error: Some(3.0),
            max_missing_share: Some(0.5),
            ..Expectations::default()
        };
        assert!(relaxed.regressions().is_empty());
    }
}
