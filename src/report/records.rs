//! What a run measured: one record per tracked frame (the rows of `frames.csv` and of `track`'s
//! output) and the run's summary (`results.json`, one row of a sweep table).

use serde::{Deserialize, Serialize};

use super::auc::detection_auc;
use super::confidence::{ConfidenceSummary, RegionSummary, RenderCheckSummary};
use super::limit::LimitSummary;
use super::ErrorStats;
use super::{finite, ReportError};
use crate::estimator::{EstimateFlags, PoseEstimate};
use crate::evidence::ConflictLevel;
use crate::faults::FrameFaults;
use crate::model::EvidentialModel;
use crate::planar::distance;
use crate::scenario::{Expectations, MeasuredFigures, MethodExpectations};

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
    /// How unusual the frame looked to the method (see [`PoseEstimate::detection_score`]).
    pub detection_score: Option<f64>,
    /// Area of the method's plausibility region (mm²), for methods that give one.
    #[serde(default)]
    pub region_area: Option<f64>,
    /// Whether that region holds the true pose (`None` without a region or ground truth).
    #[serde(default)]
    pub region_covers: Option<bool>,
    /// Missing features, fallback, no estimate: empty when the frame is clean.
    pub flags: String,
    /// The flags behind `flags`, by feature index.
    pub flag_set: EstimateFlags,
    /// Ground truth of the faults injected into this frame (`None` in a run without faults).
    pub faults: Option<FrameFaults>,
    /// The information limit at this frame, √(tr I⁻¹) (mm), the same for every method
    /// (`None` where I is singular or the run has no limit).
    #[serde(default)]
    pub limit_mm: Option<f64>,
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
            detection_score: estimate.detection_score,
            region_area: estimate.region.map(|r| r.area),
            region_covers: estimate.region.zip(truth).map(|(r, t)| r.covers(t)),
            flags: estimate.flag_words(names),
            flag_set: estimate.flags.clone(),
            faults: None,
            limit_mm: None,
        }
    }

    /// The same record with the ground truth of its frame's faults.
    pub fn with_faults(self, faults: FrameFaults) -> Self {
        Self {
            faults: Some(faults),
            ..self
        }
    }

    /// Whether the frame's measurements were corrupted by an injected fault.
    pub fn corrupted(&self) -> bool {
        self.faults.as_ref().is_some_and(FrameFaults::corrupted)
    }

    /// Whether an injected fault struck the frame (changed features or not): the confidence
    /// figures count as clean only the frames no fault struck.
    pub fn struck(&self) -> bool {
        self.faults.as_ref().is_some_and(FrameFaults::struck)
    }
}

/// Writes frame records as CSV (the `frames.csv` of a run, and what `track` prints): one row per
/// frame and method, the combined group as feature names joined by `+`, empty cells for missing
/// values; the last two columns are the ground truth of injected faults (the faults that struck,
/// the features they changed, or `frame` for a dropped frame), empty without faults; `limit_mm`
/// is the frame's information limit (empty in `track`'s output, which has no feature maps of
/// its own to take it from). Numbers go
/// through [`finite`]: `conflict_level` and `detection_score` may be `inf`, nothing is NaN.
///
/// # Errors
/// [`ReportError::NonFinite`] naming the row and column of a number no file may hold;
/// [`ReportError::Csv`] when writing fails.
pub fn write_frames_csv<W: std::io::Write>(
    writer: W,
    records: &[FrameRecord],
    names: &[String],
) -> Result<(), ReportError> {
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
        "detection_score",
        "faults",
        "changed_features",
        "region_area",
        "region_covers",
        "limit_mm",
    ])?;
    let joined = |list: &[usize]| {
        list.iter()
            .map(|&g| names[g].as_str())
            .collect::<Vec<_>>()
            .join("+")
    };
    for r in records {
        let at = |column: &str| {
            format!(
                "frames.csv, {} {} frame {}: {column}",
                r.method, r.motion, r.frame
            )
        };
        let num = |column: &str, v: Option<f64>| finite::cell(&at(column), v);
        let group = r.group.as_deref().map(joined).unwrap_or_default();
        let (faults, changed) = match &r.faults {
            Some(f) if f.dropped => (f.faults.join("+"), "frame".to_string()),
            Some(f) => (f.faults.join("+"), joined(&f.changed)),
            None => (String::new(), String::new()),
        };
        csv.write_record([
            r.method.clone(),
            r.motion.clone(),
            r.frame.to_string(),
            finite::number(&at("t"), r.t)?,
            num("true_x", r.truth.map(|p| p[0]))?,
            num("true_y", r.truth.map(|p| p[1]))?,
            num("est_x", r.estimate.map(|p| p[0]))?,
            num("est_y", r.estimate.map(|p| p[1]))?,
            num("error", r.error)?,
            group,
            finite::level_cell(&at("conflict_level"), r.conflict_level)?,
            num("uncertainty_radius", r.uncertainty_radius)?,
            r.flags.clone(),
            finite::level_cell(&at("detection_score"), r.detection_score)?,
            faults,
            changed,
            num("region_area", r.region_area)?,
            r.region_covers.map(|c| c.to_string()).unwrap_or_default(),
            num("limit_mm", r.limit_mm)?,
        ])?;
    }
    csv.flush().map_err(csv::Error::from)?;
    Ok(())
}

/// Wall times of a run, in seconds: kept apart from the [`RunSummary`] so that two runs of the
/// same scenario and seed write byte-identical results (`timings.json` only on request).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Timings {
    /// Simulating and rendering (0 when the workbench had the datasets already).
    pub simulate: f64,
    /// Feature extraction.
    pub features: f64,
    /// Each method's, in the scenario's order.
    pub methods: Vec<MethodTimings>,
}

/// Wall times of one method.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MethodTimings {
    /// The method.
    pub method: String,
    /// Fitting (validation included).
    pub fit_seconds: f64,
    /// Estimating every test frame.
    pub track_seconds: f64,
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
    /// Test frames with a missing feature.
    pub frames_with_missing_features: usize,
    /// Test frames where the method left usable features out (the conflict graph's rejections,
    /// fallbacks included).
    pub frames_with_features_left_out: usize,
    /// Test frames where no group was eligible and one feature was used alone.
    pub frames_fallback: usize,
    /// Mean number of features combined per frame, for methods that choose them.
    pub mean_group_size: Option<f64>,
    /// Clean against corrupted frames, in a run with faults.
    pub faults: Option<FaultSummary>,
    /// How the plausibility regions fared on the clean frames, for methods that give them.
    #[serde(default)]
    pub region: Option<RegionSummary>,
    /// Whether it knows when it is wrong: risk–coverage, coverage and abstentions.
    #[serde(default)]
    pub confidence: Option<ConfidenceSummary>,
    /// Its RMS error over the information limit's on the same clean frames
    /// ([`super::limit::efficiency`]).
    #[serde(default)]
    pub efficiency: Option<f64>,
    /// What the render check did, in a run with `[confidence] render_check`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub render_check: Option<RenderCheckSummary>,
}

impl MethodSummary {
    /// The summary of one method's `records` (all of one method).
    pub fn new(
        method: &str,
        records: &[FrameRecord],
        per_motion: Vec<(String, Option<ErrorStats>)>,
    ) -> Self {
        let errors: Vec<f64> = records.iter().filter_map(|r| r.error).collect();
        let with_estimate = records.iter().filter(|r| r.estimate.is_some()).count();
        let groups: Vec<usize> = records
            .iter()
            .filter_map(|r| r.group.as_ref().map(Vec::len))
            .collect();
        let count =
            |test: fn(&EstimateFlags) -> bool| records.iter().filter(|r| test(&r.flag_set)).count();
        Self {
            method: method.to_string(),
            error: ErrorStats::from_errors(&errors),
            per_motion,
            frames_without_estimate: records.len() - with_estimate,
            frames_with_missing_features: count(|f| !f.missing.is_empty()),
            frames_with_features_left_out: count(|f| !f.excluded.is_empty()),
            frames_fallback: count(|f| f.fallback),
            mean_group_size: (!groups.is_empty())
                .then(|| groups.iter().sum::<usize>() as f64 / records.len().max(1) as f64),
            faults: FaultSummary::of(records),
            region: RegionSummary::of(records),
            confidence: ConfidenceSummary::of(records),
            efficiency: None,
            render_check: None,
        }
    }
}

/// How a method fared on the frames faults corrupted, against the clean ones.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FaultSummary {
    /// Frames whose measurements a fault changed (or dropped).
    pub corrupted_frames: usize,
    /// The other frames.
    pub clean_frames: usize,
    /// Errors on the clean frames with an estimate.
    pub error_clean: Option<ErrorStats>,
    /// Errors on the corrupted frames with an estimate.
    pub error_corrupted: Option<ErrorStats>,
    /// Corrupted frames without an estimate.
    pub corrupted_without_estimate: usize,
    /// Area under the ROC curve of the detection score against "frame corrupted" (a frame
    /// without a score ranks as +∞); `None` when the method gives no score or a class is empty.
    pub detection_auc: Option<f64>,
    /// Share of the features left out that a fault had changed (pooled over frames).
    pub left_out_precision: Option<f64>,
    /// Share of the changed features still present that were left out (pooled over frames).
    pub left_out_recall: Option<f64>,
}

impl FaultSummary {
    /// The summary of one method's records; `None` when they carry no fault labels.
    pub fn of(records: &[FrameRecord]) -> Option<Self> {
        if records.iter().all(|r| r.faults.is_none()) {
            return None;
        }
        let errors = |corrupted: bool| {
            let e: Vec<f64> = records
                .iter()
                .filter(|r| r.corrupted() == corrupted)
                .filter_map(|r| r.error)
                .collect();
            ErrorStats::from_errors(&e)
        };
        let corrupted_frames = records.iter().filter(|r| r.corrupted()).count();
        let (mut left_out, mut hits, mut changed_present) = (0usize, 0usize, 0usize);
        for r in records {
            let Some(f) = &r.faults else { continue };
            let excluded = &r.flag_set.excluded;
            left_out += excluded.len();
            hits += excluded.iter().filter(|i| f.changed.contains(i)).count();
            changed_present += (f.changed.iter())
                .filter(|i| !r.flag_set.missing.contains(i))
                .count();
        }
        let any_groups = records.iter().any(|r| r.group.is_some());
        let share =
            |num: usize, den: usize| (any_groups && den > 0).then(|| num as f64 / den as f64);
        Some(Self {
            corrupted_frames,
            clean_frames: records.len() - corrupted_frames,
            error_clean: errors(false),
            error_corrupted: errors(true),
            corrupted_without_estimate: (records.iter())
                .filter(|r| r.corrupted() && r.estimate.is_none())
                .count(),
            detection_auc: detection_auc(records),
            left_out_precision: share(hits, left_out),
            left_out_recall: share(hits, changed_present),
        })
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
    /// The information limit of the clean test frames, when the feature maps could be fitted.
    #[serde(default)]
    pub limit: Option<LimitSummary>,
    /// What the scenario expects.
    pub expect: Expectations,
    /// How far the test poses lie from the calibration motion's (runs with a calibration or
    /// validation motion).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub calibration_reach: Option<super::CalibrationReach>,
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
        let bands = self.expect.bands_hold_for(self.seed);
        let mut check = |name: &str, limits: &MethodExpectations| {
            let Some(m) = self.method(name) else {
                missed.push(format!(
                    "{}: expectations are given for method `{name}`, which did not run",
                    self.scenario
                ));
                return;
            };
            let faults = m.faults.as_ref();
            let confidence = m.confidence.as_ref();
            let corrupted = faults.map_or(0, |f| f.corrupted_frames);
            let measured = MeasuredFigures {
                mean_error: m.error.map(|s| s.mean),
                missing_share: m.frames_without_estimate as f64 / self.frames.max(1) as f64,
                corrupted_mean_error: faults.and_then(|f| f.error_corrupted).map(|s| s.mean),
                detection_auc: faults.and_then(|f| f.detection_auc),
                coverage: confidence.and_then(|c| c.coverage_clean),
                corrupted_coverage: confidence.and_then(|c| c.coverage_corrupted),
                abstained_share: confidence
                    .map(|c| c.abstained_clean_share(self.frames, corrupted)),
                aurc: confidence.map(|c| c.all.aurc),
            };
            for miss in limits.misses(&measured, bands) {
                missed.push(format!("{} ({name}): {miss}", self.scenario));
            }
        };
        let top = self.expect.evidential();
        if top.any() {
            check("evidential", &top);
        }
        for (name, limits) in &self.expect.methods {
            check(name, limits);
        }
        missed
    }
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;

    /// A method's summary with these errors and this many frames without an estimate.
    pub(in crate::report) fn method(name: &str, errors: &[f64], without: usize) -> MethodSummary {
        MethodSummary {
            method: name.into(),
            error: ErrorStats::from_errors(errors),
            per_motion: Vec::new(),
            frames_without_estimate: without,
            frames_with_missing_features: 0,
            frames_with_features_left_out: 0,
            frames_fallback: 0,
            mean_group_size: None,
            faults: None,
            region: None,
            confidence: None,
            efficiency: None,
            render_check: None,
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
                ..MethodExpectations::default()
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
            limit: None,
            expect,
            calibration_reach: None,
        };
        let missed = summary.regressions();
        assert_eq!(missed.len(), 4, "{missed:?}");
        assert!(
            missed[0].contains("(evidential): mean error 3.0000 is above the expected maximum 2.5")
        );
        assert!(missed[1].contains(
            "(evidential): share of frames without an estimate 0.5000 is above the expected maximum 0.25"
        ));
        // BTreeMap order: gp before knn.
        assert!(missed[2].contains("method `gp`, which did not run"));
        assert!(missed[3].contains("(knn): mean error 0.6000 is above the expected maximum 0.5"));
        let mut relaxed = summary.clone();
        relaxed.expect = Expectations {
            max_mean_error: Some(3.0),
            max_missing_share: Some(0.5),
            ..Expectations::default()
        };
        assert!(relaxed.regressions().is_empty());
    }
}
