//! How far the test frames lie from the calibration motion: the regions and abstention limits
//! are order statistics of the calibration frames and hold for test frames like them, so a run
//! states how many of its test poses the calibration motion came near, and each method's clean
//! coverage and abstentions on either side (docs/results.md, "Clean abstentions off the file").

use std::collections::HashMap;

use serde::{Deserialize, Serialize};

use super::FrameRecord;

/// A test pose farther than this (mm) from every calibration pose is out of the calibration's
/// reach: the sample mesh's usual spacing.
pub const REACH_MM: f64 = 1.0;

/// The test frames' distance from the calibration motion's poses.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CalibrationReach {
    /// The distance (mm) beyond which a test pose counts as far.
    pub within_mm: f64,
    /// Test frames with a true pose.
    pub frames: usize,
    /// Of those, the ones farther than `within_mm` from every calibration pose.
    pub far_frames: usize,
    /// Median distance (mm) of a test pose from its nearest calibration pose.
    pub median_mm: f64,
    /// Each method's clean frames, coverage and abstentions, near and far.
    pub methods: Vec<MethodReach>,
}

/// One method's clean frames near and far from the calibration motion, its abstentions there,
/// and how many of their regions hold the truth (counted as the clean coverage is: frames with
/// an estimate and a region, an abstention's whole-workspace region included).
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct MethodReach {
    /// The method.
    pub method: String,
    /// Clean frames within the reach.
    pub clean_near: usize,
    /// Of `clean_near`, the frames the method abstained on.
    pub abstained_near: usize,
    /// Of `clean_near`, the frames with an estimate and a region.
    pub regions_near: usize,
    /// Of `regions_near`, those whose region holds the truth.
    pub covered_near: usize,
    /// Clean frames beyond the reach.
    pub clean_far: usize,
    /// Of `clean_far`, the frames the method abstained on.
    pub abstained_far: usize,
    /// Of `clean_far`, the frames with an estimate and a region.
    pub regions_far: usize,
    /// Of `regions_far`, those whose region holds the truth.
    pub covered_far: usize,
}

impl MethodReach {
    /// The clean coverage of the regions near and far (`None` on a side without regions).
    pub fn coverage(&self) -> (Option<f64>, Option<f64>) {
        let share = |covered: usize, of: usize| (of > 0).then(|| covered as f64 / of as f64);
        (
            share(self.covered_near, self.regions_near),
            share(self.covered_far, self.regions_far),
        )
    }
}

impl CalibrationReach {
    /// From the calibration motion's true poses and the run's records (every method's, in
    /// method order); `None` without calibration poses or test frames with a truth.
    pub fn of(calibration: &[[f64; 2]], records: &[FrameRecord]) -> Option<Self> {
        if calibration.is_empty() {
            return None;
        }
        let nearest = |p: [f64; 2]| {
            (calibration.iter())
                .map(|q| (p[0] - q[0]).hypot(p[1] - q[1]))
                .fold(f64::INFINITY, f64::min)
        };
        let first = records.first()?.method.clone();
        // Every method sees the same frames: each frame's distance once, from the first
        // method's records.
        let distance: HashMap<(&str, usize), f64> = (records.iter())
            .filter(|r| r.method == first)
            .filter_map(|r| Some(((r.motion.as_str(), r.frame), nearest(r.truth?))))
            .collect();
        if distance.is_empty() {
            return None;
        }
        let mut methods: Vec<MethodReach> = Vec::new();
        for r in records.iter().filter(|r| !r.struck()) {
            let Some(&d) = distance.get(&(r.motion.as_str(), r.frame)) else {
                continue;
            };
            if methods.last().is_none_or(|m| m.method != r.method) {
                methods.push(MethodReach {
                    method: r.method.clone(),
                    ..MethodReach::default()
                });
            }
            let m = methods.last_mut().expect("pushed above");
            let abstained = usize::from(r.flag_set.abstained);
            let covers = r.region_covers.filter(|_| r.estimate.is_some());
            let (region, covered) = (
                usize::from(covers.is_some()),
                usize::from(covers == Some(true)),
            );
            if d > REACH_MM {
                m.clean_far += 1;
                m.abstained_far += abstained;
                m.regions_far += region;
                m.covered_far += covered;
            } else {
                m.clean_near += 1;
                m.abstained_near += abstained;
                m.regions_near += region;
                m.covered_near += covered;
            }
        }
        let mut distances: Vec<f64> = distance.into_values().collect();
        let frames = distances.len();
        let far_frames = distances.iter().filter(|&&d| d > REACH_MM).count();
        distances.sort_by(f64::total_cmp);
        let median_mm = match frames % 2 {
            1 => distances[frames / 2],
            _ => 0.5 * (distances[frames / 2 - 1] + distances[frames / 2]),
        };
        Some(Self {
            within_mm: REACH_MM,
            frames,
            far_frames,
            median_mm,
            methods,
        })
    }

    /// The run's line for the printed tables, when a tenth or more of its test frames are out of
    /// reach (else `None`: the calibration motion covers the test).
    pub fn note(&self, run: &str) -> Option<String> {
        if self.far_frames * 10 < self.frames {
            return None;
        }
        let share = |n: usize, of: usize| match of {
            0 => "—".to_string(),
            _ => format!("{:.1} %", 100.0 * n as f64 / of as f64),
        };
        let methods: Vec<String> = (self.methods.iter())
            .filter(|m| m.abstained_near + m.abstained_far > 0)
            .map(|m| {
                let near = share(m.abstained_near, m.clean_near);
                let far = share(m.abstained_far, m.clean_far);
                format!("{} {near} / {far}", m.method)
            })
            .collect();
        let mut line = format!(
            "{run}: {} of {} test frames lie over {} mm from every calibration pose (median \
             {:.2} mm); regions and abstention limits hold for frames like the calibration \
             motion's",
            self.far_frames, self.frames, self.within_mm, self.median_mm
        );
        if !methods.is_empty() {
            line.push_str(&format!(
                ". Clean frames abstained on, near / far: {}",
                methods.join(", ")
            ));
        }
        let side = |c: Option<f64>| c.map_or("—".to_string(), |c| format!("{c:.3}"));
        let coverage: Vec<String> = (self.methods.iter())
            .filter_map(|m| match m.coverage() {
                (None, None) => None,
                (near, far) => Some(format!("{} {} / {}", m.method, side(near), side(far))),
            })
            .collect();
        if !coverage.is_empty() {
            line.push_str(&format!(
                ". Clean coverage near / far: {}",
                coverage.join(", ")
            ));
        }
        Some(line)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimator::PoseEstimate;

    fn record(method: &str, frame: usize, truth: [f64; 2], abstained: bool) -> FrameRecord {
        let mut estimate = PoseEstimate {
            pose: Some(truth),
            ..PoseEstimate::default()
        };
        estimate.flags.abstained = abstained;
        FrameRecord::new(method, "test0", frame, 0.0, Some(truth), &estimate, &[])
    }

    /// `record`, with a region that holds the truth or not.
    fn with_region(mut record: FrameRecord, covers: bool) -> FrameRecord {
        record.region_covers = Some(covers);
        record
    }

    #[test]
    fn frames_beyond_the_reach_are_counted_with_each_methods_abstentions() {
        let calibration = [[0.0, 40.0], [1.0, 40.0]];
        // Distances 0, 0.5, 2 and 3 mm from the nearest calibration pose.
        let truths = [[0.0, 40.0], [1.5, 40.0], [3.0, 40.0], [0.0, 37.0]];
        let mut records = Vec::new();
        for method in ["a", "b"] {
            for (i, &t) in truths.iter().enumerate() {
                records.push(record(method, i, t, method == "b" && i >= 2));
            }
        }
        let reach = CalibrationReach::of(&calibration, &records).unwrap();
        assert_eq!((reach.frames, reach.far_frames), (4, 2));
        assert_eq!(reach.median_mm, 1.25);
        assert_eq!(reach.methods.len(), 2);
        let b = &reach.methods[1];
        assert_eq!(
            (b.clean_near, b.abstained_near, b.clean_far, b.abstained_far),
            (2, 0, 2, 2)
        );
        // Neither method has regions: no coverage on either side.
        assert_eq!(b.coverage(), (None, None));
        let note = reach.note("run").unwrap();
        assert!(note.contains("2 of 4 test frames lie over 1 mm"), "{note}");
        assert!(note.contains("b 0.0 % / 100.0 %"), "{note}");
        assert!(!note.contains(" a "), "a abstained nowhere: {note}");
        assert!(!note.contains("coverage"), "{note}");
    }

    #[test]
    fn coverage_is_counted_on_each_side_over_the_frames_with_a_region() {
        let calibration = [[0.0, 40.0]];
        // Near: covered, covered, missed; far: missed, covered, no region, no estimate.
        let near = [[0.0, 40.0], [0.5, 40.0], [0.0, 40.5]];
        let far = [[3.0, 40.0], [0.0, 43.0], [0.0, 45.0], [2.0, 40.0]];
        let mut records = vec![
            with_region(record("a", 0, near[0], false), true),
            with_region(record("a", 1, near[1], false), true),
            with_region(record("a", 2, near[2], false), false),
            with_region(record("a", 3, far[0], false), false),
            // An abstention's whole-workspace region holds the truth, as in the clean coverage.
            with_region(record("a", 4, far[1], true), true),
            record("a", 5, far[2], false),
            with_region(record("a", 6, far[3], false), true),
        ];
        records[6].estimate = None;
        let reach = CalibrationReach::of(&calibration, &records).unwrap();
        let a = &reach.methods[0];
        assert_eq!(
            (a.regions_near, a.covered_near, a.regions_far, a.covered_far),
            (3, 2, 2, 1)
        );
        assert_eq!((a.clean_near, a.clean_far), (3, 4));
        let (near, far) = a.coverage();
        assert_eq!((near, far), (Some(2.0 / 3.0), Some(0.5)));
        let note = reach.note("run").unwrap();
        assert!(
            note.ends_with("Clean coverage near / far: a 0.667 / 0.500"),
            "{note}"
        );
    }

    #[test]
    fn a_test_on_the_calibration_motion_is_within_reach() {
        let calibration = [[0.0, 40.0], [0.5, 40.0], [1.0, 40.0]];
        let records: Vec<_> = (calibration.iter().enumerate())
            .map(|(i, &t)| record("a", i, t, false))
            .collect();
        let reach = CalibrationReach::of(&calibration, &records).unwrap();
        assert_eq!((reach.far_frames, reach.median_mm), (0, 0.0));
        assert_eq!(reach.note("run"), None);
        assert_eq!(CalibrationReach::of(&[], &records), None);
        assert_eq!(CalibrationReach::of(&calibration, &[]), None);
    }
}
