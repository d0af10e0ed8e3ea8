//! The information limit beside a run's methods: the RMS of the Cramér–Rao bound over the clean
//! test frames (`crate::information`), and each method's efficiency against it.

use serde::{Deserialize, Serialize};

use super::FrameRecord;

/// The noise covariance the bound assumed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LimitNoise {
    /// `validation_full` (the validation residuals' covariance, correlations included) or
    /// `leave_one_out_diagonal` (no validation motion: the samples' leave-one-out scales,
    /// independent).
    pub source: String,
    /// Eigenvalues of the measured correlation matrix raised to `floor` (1/N for N frames).
    pub floored: usize,
    /// That floor (0 for the diagonal).
    pub floor: f64,
}

impl LimitNoise {
    /// The validation residuals' full covariance, with `floored` eigenvalues raised to `floor`.
    pub fn full(floored: usize, floor: f64) -> Self {
        Self {
            source: "validation_full".into(),
            floored,
            floor,
        }
    }

    /// Independent features with the leave-one-out noise scales.
    pub fn diagonal() -> Self {
        Self {
            source: "leave_one_out_diagonal".into(),
            floored: 0,
            floor: 0.0,
        }
    }
}

/// The limit of a run: what an unbiased estimator cannot beat with these features.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LimitSummary {
    /// √(mean tr I⁻¹) over the clean test frames with a bound (mm): the RMS error floor.
    pub rms: Option<f64>,
    /// Clean test frames with a bound.
    pub frames: usize,
    /// Clean test frames without one (fewer than two features, or slopes along one line).
    pub frames_without: usize,
    /// Frames a fault corrupted: left out, the bound being for clean features.
    pub corrupted_frames: usize,
    /// The noise it assumed.
    pub noise: LimitNoise,
}

impl LimitSummary {
    /// The summary of `frames`: (bound in mm², whether a fault corrupted the frame).
    pub fn of(frames: &[(Option<f64>, bool)], noise: LimitNoise) -> Self {
        let clean: Vec<Option<f64>> = (frames.iter())
            .filter(|(_, corrupted)| !corrupted)
            .map(|(b, _)| *b)
            .collect();
        let bounds: Vec<f64> = clean.iter().flatten().copied().collect();
        Self {
            rms: (!bounds.is_empty())
                .then(|| (bounds.iter().sum::<f64>() / bounds.len() as f64).sqrt()),
            frames: bounds.len(),
            frames_without: clean.len() - bounds.len(),
            corrupted_frames: frames.len() - clean.len(),
            noise,
        }
    }
}

/// A method's RMS error over the limit's RMS on the same frames: the clean ones where it has
/// an estimate and the frame a bound. 1 is the best an unbiased estimator can do; a biased one
/// may go below. `None` without such a frame.
pub fn efficiency(records: &[&FrameRecord]) -> Option<f64> {
    let (mut errors, mut bounds, mut count) = (0.0, 0.0, 0usize);
    for r in records.iter().filter(|r| !r.corrupted()) {
        if let (Some(e), Some(l)) = (r.error, r.limit_mm) {
            errors += e * e;
            bounds += l * l;
            count += 1;
        }
    }
    (count > 0 && bounds > 0.0).then(|| (errors / bounds).sqrt())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_limit_and_efficiency_use_clean_frames_only() {
        let summary = LimitSummary::of(
            &[
                (Some(4.0), false),
                (Some(16.0), false),
                (None, false),
                (Some(100.0), true),
            ],
            LimitNoise::diagonal(),
        );
        assert_eq!(summary.rms, Some(10f64.sqrt()));
        assert_eq!((summary.frames, summary.frames_without), (2, 1));
        assert_eq!(summary.corrupted_frames, 1);
    }

    fn record(error: f64, limit: Option<f64>, corrupted: bool) -> FrameRecord {
        let estimate = crate::estimator::PoseEstimate {
            pose: Some([error, 0.0]),
            ..Default::default()
        };
        let r = FrameRecord::new("m", "test0", 0, 0.0, Some([0.0, 0.0]), &estimate, &[]);
        let faults = crate::faults::FrameFaults {
            dropped: corrupted,
            ..crate::faults::FrameFaults::default()
        };
        FrameRecord {
            limit_mm: limit,
            ..r.with_faults(faults)
        }
    }

    #[test]
    fn efficiency_pairs_the_clean_frames_with_a_bound() {
        let records = [
            record(2.0, Some(1.0), false),
            record(4.0, Some(1.0), false),
            record(9.0, None, false),
            record(50.0, Some(1.0), true),
        ];
        let refs: Vec<&FrameRecord> = records.iter().collect();
        // √((4 + 16) / 2) over √1.
        assert_eq!(efficiency(&refs), Some(10f64.sqrt()));
        assert_eq!(efficiency(&refs[2..3]), None);
    }
}
