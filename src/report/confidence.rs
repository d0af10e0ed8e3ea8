//! Whether a method knows when it is wrong, checked against ground truth: risk–coverage (the
//! mean error of the frames it is surest of), its calibrated regions' coverage and its
//! abstentions, on clean and corrupted frames apart.
//!
//! Clean frames are those no injected fault struck; corrupted ones those whose features a fault
//! changed (beyond the faults module's tolerance). A frame a fault struck without changing a
//! feature that much (salt-and-pepper off the body, an occluder beside it) is neither: the image
//! was not clean, so abstaining there is no false alarm, yet the estimate was not misled either.
//! It counts over all frames only.
//!
//! A method ranks its frames by its own doubt: abstained frames last, then by the area of its
//! region (the calibrated region's, from its own covariance), then by its uncertainty radius.
//! Frames it ranks equal are taken in every order equally (the expected risk of a random tie
//! break), so a method that says nothing (the centre) gets a flat curve.

use serde::{Deserialize, Serialize};

use super::records::FrameRecord;
use super::ErrorStats;
use crate::estimator::RenderSource;

/// Coverages at which the curve is sampled: 5 %, 10 %, …, 100 %.
pub const CURVE_POINTS: usize = 20;

/// Coverage and size of the regions a method answered with (abstentions left out, see
/// [`ConfidenceSummary`]) over the clean frames with a truth.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RegionSummary {
    /// Clean frames whose estimate came with a region.
    pub frames: usize,
    /// Clean frames with an estimate but no bounded region.
    pub frames_without_region: usize,
    /// Share of those regions that hold the true pose.
    pub coverage: f64,
    /// Mean area of the regions (mm²).
    pub mean_area: f64,
    /// Median area (mm²).
    pub median_area: f64,
}

impl RegionSummary {
    /// The summary of one method's `records`; `None` when none has a region.
    pub fn of(records: &[FrameRecord]) -> Option<Self> {
        let clean: Vec<&FrameRecord> = (records.iter())
            .filter(|r| !r.struck() && r.estimate.is_some() && r.truth.is_some())
            .filter(|r| !r.flag_set.abstained)
            .collect();
        let with: Vec<(&FrameRecord, f64)> = (clean.iter())
            .filter_map(|r| r.region_area.map(|a| (*r, a)))
            .collect();
        if with.is_empty() {
            return None;
        }
        let covered = with
            .iter()
            .filter(|(r, _)| r.region_covers == Some(true))
            .count();
        let mut areas: Vec<f64> = with.iter().map(|(_, a)| *a).collect();
        areas.sort_by(f64::total_cmp);
        let n = areas.len();
        let median = if n % 2 == 1 {
            areas[n / 2]
        } else {
            0.5 * (areas[n / 2 - 1] + areas[n / 2])
        };
        Some(Self {
            frames: n,
            frames_without_region: clean.len() - n,
            coverage: covered as f64 / n as f64,
            mean_area: areas.iter().sum::<f64>() / n as f64,
            median_area: median,
        })
    }
}

/// A risk–coverage curve and its figures.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RiskCoverage {
    /// Frames ranked (with an estimate and a truth).
    pub frames: usize,
    /// Mean error (mm) of the surest q of the frames, q = 5 %, 10 %, …, 100 %.
    pub curve: Vec<f64>,
    /// Area under the curve: the mean over k = 1…n of the mean error of the k surest frames (mm).
    pub aurc: f64,
    /// Mean error of the surest 80 % (mm).
    pub error_at_80: f64,
    /// Mean error of the surest 95 % (mm).
    pub error_at_95: f64,
    /// The same curve with frames ranked by their true error: the best any ranking can do.
    pub oracle_curve: Vec<f64>,
    /// Its area (mm).
    pub oracle_aurc: f64,
}

/// The doubt key of a record: abstained last, then region area, then uncertainty radius.
fn doubt(record: &FrameRecord) -> (bool, f64, f64) {
    let finite = |v: Option<f64>| v.filter(|x| !x.is_nan()).unwrap_or(0.0);
    (
        record.flag_set.abstained,
        finite(record.region_area),
        finite(record.uncertainty_radius),
    )
}

/// Mean error of the k surest frames, k = 1…n, for errors ranked in tied groups (the expected
/// value over random orders within each group).
fn risks(groups: &[Vec<f64>]) -> Vec<f64> {
    let n: usize = groups.iter().map(Vec::len).sum();
    let mut out = Vec::with_capacity(n);
    let mut before = 0.0;
    for group in groups {
        let mean = group.iter().sum::<f64>() / group.len() as f64;
        for taken in 1..=group.len() {
            let k = out.len() + 1;
            out.push((before + taken as f64 * mean) / k as f64);
        }
        before += group.iter().sum::<f64>();
    }
    out
}

fn at_share(risks: &[f64], share: f64) -> f64 {
    let k = ((risks.len() as f64 * share).ceil() as usize).clamp(1, risks.len());
    risks[k - 1]
}

fn curve(risks: &[f64]) -> Vec<f64> {
    (1..=CURVE_POINTS)
        .map(|i| at_share(risks, i as f64 / CURVE_POINTS as f64))
        .collect()
}

impl RiskCoverage {
    /// The curve of `records` (frames without an estimate or truth are left out); `None` when
    /// none is left.
    pub fn of<'a>(records: impl IntoIterator<Item = &'a FrameRecord>) -> Option<Self> {
        let mut ranked: Vec<((bool, f64, f64), f64)> = records
            .into_iter()
            .filter_map(|r| Some((doubt(r), r.error.filter(|e| e.is_finite())?)))
            .collect();
        if ranked.is_empty() {
            return None;
        }
        ranked.sort_by(|a, b| {
            (a.0 .0.cmp(&b.0 .0))
                .then(a.0 .1.total_cmp(&b.0 .1))
                .then(a.0 .2.total_cmp(&b.0 .2))
        });
        let mut groups: Vec<Vec<f64>> = Vec::new();
        for (i, (key, error)) in ranked.iter().enumerate() {
            match groups.last_mut() {
                Some(g) if i > 0 && ranked[i - 1].0 == *key => g.push(*error),
                _ => groups.push(vec![*error]),
            }
        }
        let own = risks(&groups);
        let mut sorted: Vec<f64> = ranked.iter().map(|r| r.1).collect();
        sorted.sort_by(f64::total_cmp);
        let oracle = risks(&sorted.iter().map(|&e| vec![e]).collect::<Vec<_>>());
        let area = |r: &[f64]| r.iter().sum::<f64>() / r.len() as f64;
        Some(Self {
            frames: own.len(),
            curve: curve(&own),
            aurc: area(&own),
            error_at_80: at_share(&own, 0.8),
            error_at_95: at_share(&own, 0.95),
            oracle_curve: curve(&oracle),
            oracle_aurc: area(&oracle),
        })
    }
}

/// A method's confidence, checked: risk–coverage, its regions' coverage and its abstentions.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ConfidenceSummary {
    /// Over every frame with an estimate.
    pub all: RiskCoverage,
    /// Over the clean frames, in a run with faults.
    pub clean: Option<RiskCoverage>,
    /// Over the corrupted frames, in a run with faults.
    pub corrupted: Option<RiskCoverage>,
    /// Share of the clean frames with an estimate whose region holds the truth (an abstained
    /// frame's region is the whole workspace); `None` without regions.
    pub coverage_clean: Option<f64>,
    /// The same on the corrupted frames.
    pub coverage_corrupted: Option<f64>,
    /// Clean frames on which the method abstained.
    pub abstained_clean: usize,
    /// Corrupted frames on which it abstained.
    pub abstained_corrupted: usize,
    /// The clean frames (`None` in results written before it was kept: then every frame not
    /// corrupted).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub clean_frames: Option<usize>,
    /// Errors of the frames it answered (an estimate, not abstained).
    pub error_answered: Option<ErrorStats>,
    /// Median area of its regions on the clean frames it answered (mm²).
    pub median_area_answered: Option<f64>,
}

/// Whether `record` is on the corrupted side (`corrupted`) or the clean one (module notes).
fn on_side(record: &FrameRecord, corrupted: bool) -> bool {
    match corrupted {
        true => record.corrupted(),
        false => !record.struck(),
    }
}

impl ConfidenceSummary {
    /// The share of the clean frames it abstained on, of a run of `frames` frames of which
    /// `corrupted` were corrupted (which give the clean frames in results that did not keep
    /// them).
    pub fn abstained_clean_share(&self, frames: usize, corrupted: usize) -> f64 {
        let clean = (self.clean_frames).unwrap_or_else(|| frames.saturating_sub(corrupted));
        self.abstained_clean as f64 / clean.max(1) as f64
    }

    /// The summary of one method's `records`; `None` when no frame has an estimate.
    pub fn of(records: &[FrameRecord]) -> Option<Self> {
        let faults = records.iter().any(|r| r.faults.is_some());
        let side = |corrupted: bool| records.iter().filter(move |r| on_side(r, corrupted));
        let coverage = |corrupted: bool| {
            let with: Vec<bool> = side(corrupted)
                .filter(|r| r.estimate.is_some())
                .filter_map(|r| r.region_covers)
                .collect();
            (!with.is_empty())
                .then(|| with.iter().filter(|&&c| c).count() as f64 / with.len() as f64)
        };
        let abstained = |corrupted: bool| side(corrupted).filter(|r| r.flag_set.abstained).count();
        let answered: Vec<f64> = (records.iter())
            .filter(|r| !r.flag_set.abstained)
            .filter_map(|r| r.error)
            .collect();
        let mut areas: Vec<f64> = side(false)
            .filter(|r| !r.flag_set.abstained)
            .filter_map(|r| r.region_area)
            .collect();
        areas.sort_by(f64::total_cmp);
        Some(Self {
            all: RiskCoverage::of(records)?,
            clean: faults.then(|| RiskCoverage::of(side(false))).flatten(),
            corrupted: faults.then(|| RiskCoverage::of(side(true))).flatten(),
            coverage_clean: coverage(false),
            coverage_corrupted: coverage(true),
            abstained_clean: abstained(false),
            abstained_corrupted: abstained(true),
            clean_frames: Some(side(false).count()),
            error_answered: ErrorStats::from_errors(&answered),
            median_area_answered: areas.get(areas.len() / 2).copied(),
        })
    }
}

/// What the render check (`[confidence] render_check`) did to one method. Its limit is the
/// run's, learned on the method's clean calibration frames (from the samples, the model file
/// keeps it too, for `track --samples`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RenderCheckSummary {
    /// Where the silhouette at an estimate came from (`confidence.render_from`).
    #[serde(default)]
    pub from: RenderSource,
    /// Mismatches (pixels) above this made the method abstain (`None`: too few calibration
    /// frames, or the rank fell on an undefined one; then none did).
    pub limit_px: Option<f64>,
    /// Frames with more stray pixels than this made the method abstain (`None`: not checked).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stray_limit_px: Option<f64>,
    /// The calibration frames it was learned on.
    pub calibration_frames: usize,
    /// Clean test frames on which the check made the method abstain (`render_mismatch` or
    /// `stray_pixels`).
    pub abstained_clean: usize,
    /// Corrupted test frames on which it did.
    pub abstained_corrupted: usize,
}

impl RenderCheckSummary {
    /// The summary of one method's `records`, checked against its limits (mismatch, stray).
    pub fn of(
        from: RenderSource,
        (limit_px, stray_limit_px): (Option<f64>, Option<f64>),
        calibration_frames: usize,
        records: &[FrameRecord],
    ) -> Self {
        let flagged = |corrupted: bool| {
            (records.iter())
                .filter(|r| on_side(r, corrupted))
                .filter(|r| r.flag_set.render_mismatch || r.flag_set.stray_pixels)
                .count()
        };
        Self {
            from,
            limit_px,
            stray_limit_px,
            calibration_frames,
            abstained_clean: flagged(false),
            abstained_corrupted: flagged(true),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimator::{EstimateFlags, PoseEstimate};
    use crate::faults::FrameFaults;

    fn record(error: f64, area: f64, abstained: bool) -> FrameRecord {
        let estimate = PoseEstimate {
            pose: Some([error, 0.0]),
            flags: EstimateFlags {
                abstained,
                ..EstimateFlags::default()
            },
            ..Default::default()
        };
        let mut r = FrameRecord::new("m", "test0", 0, 0.0, Some([0.0, 0.0]), &estimate, &[]);
        r.region_area = Some(area);
        r
    }

    #[test]
    fn a_perfect_ranking_meets_the_oracle_and_ties_average() {
        // Errors 1…4 ranked by areas in the same order: the oracle's curve exactly.
        let perfect: Vec<FrameRecord> = (1..=4)
            .map(|e| record(f64::from(e), f64::from(e), false))
            .collect();
        let rc = RiskCoverage::of(&perfect).unwrap();
        // Risks 1, 1.5, 2, 2.5: area 1.75.
        assert_eq!(rc.aurc, 1.75);
        assert_eq!(rc.aurc, rc.oracle_aurc);
        assert_eq!(rc.error_at_80, 2.5, "the surest ⌈3.2⌉ = 4 frames");
        assert_eq!(rc.curve.len(), CURVE_POINTS);
        assert_eq!(*rc.curve.last().unwrap(), 2.5);
        // Reversed: the worst first.
        let reversed: Vec<FrameRecord> = (1..=4)
            .map(|e| record(f64::from(e), f64::from(5 - e), false))
            .collect();
        let worst = RiskCoverage::of(&reversed).unwrap();
        // Risks 4, 3.5, 3, 2.5.
        assert_eq!(worst.aurc, 3.25);
        // All tied: every prefix has the mean error.
        let tied: Vec<FrameRecord> = (1..=4).map(|e| record(f64::from(e), 1.0, false)).collect();
        let flat = RiskCoverage::of(&tied).unwrap();
        assert!(flat.curve.iter().all(|&r| r == 2.5));
        assert_eq!(flat.aurc, 2.5);
        // Abstained frames rank last, whatever their area.
        let mut abstaining = perfect.clone();
        abstaining[0] = record(10.0, 0.0, true);
        let rc = RiskCoverage::of(&abstaining).unwrap();
        assert_eq!(
            rc.curve[0], 2.0,
            "the surest frame is the answered one of error 2"
        );
        assert!(RiskCoverage::of(&[]).is_none());
    }

    #[test]
    fn the_summary_counts_coverage_and_abstentions() {
        let mut records: Vec<FrameRecord> =
            (1..=4).map(|e| record(f64::from(e), 1.0, e == 4)).collect();
        for (r, covers) in records.iter_mut().zip([true, false, true, true]) {
            r.region_covers = Some(covers);
        }
        let s = ConfidenceSummary::of(&records).unwrap();
        assert_eq!(s.coverage_clean, Some(0.75));
        assert_eq!(s.coverage_corrupted, None);
        assert_eq!((s.abstained_clean, s.abstained_corrupted), (1, 0));
        assert_eq!(s.error_answered.unwrap().mean, 2.0);
        assert!(s.clean.is_none(), "no faults: no split");
        assert_eq!(s.abstained_clean_share(4, 0), 0.25);
    }

    #[test]
    fn a_frame_struck_without_a_changed_feature_is_neither_clean_nor_corrupted() {
        let label = |faults: &[&str], changed: &[usize]| FrameFaults {
            faults: faults.iter().map(|f| f.to_string()).collect(),
            changed: changed.to_vec(),
            dropped: false,
        };
        // Clean (covered), struck and changed (abstained), struck alone (abstained), clean
        // (abstained).
        let records: Vec<FrameRecord> = [
            (label(&[], &[]), false),
            (label(&["salt_pepper"], &[0]), true),
            (label(&["salt_pepper"], &[]), true),
            (label(&[], &[]), true),
        ]
        .into_iter()
        .map(|(faults, abstained)| {
            let mut r = record(1.0, 1.0, abstained).with_faults(faults);
            r.region_covers = Some(true);
            r
        })
        .collect();
        let s = ConfidenceSummary::of(&records).unwrap();
        assert_eq!(s.clean_frames, Some(2));
        assert_eq!((s.abstained_clean, s.abstained_corrupted), (1, 1));
        assert_eq!(s.abstained_clean_share(4, 1), 0.5);
        let frames = |c: &Option<RiskCoverage>| c.as_ref().map(|c| c.frames);
        assert_eq!((frames(&s.clean), frames(&s.corrupted)), (Some(2), Some(1)));
        assert_eq!(s.all.frames, 4);
        // Results written before the count was kept: every frame not corrupted.
        let old = ConfidenceSummary {
            clean_frames: None,
            ..s
        };
        assert_eq!(old.abstained_clean_share(4, 1), 1.0 / 3.0);
        let regions = RegionSummary::of(&records).unwrap();
        assert_eq!(regions.frames, 1, "the clean frame answered");
    }
}
