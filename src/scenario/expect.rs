//! What a scenario expects of its runs: the limits `sweep --check` holds each method to.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

/// What a run is expected to achieve; `sweep --check` fails when a variant misses it. The
/// top-level limits are the evidential tracker's; `[expect.methods.knn]` and so on give other
/// methods their own.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Expectations {
    /// Largest acceptable mean estimation error over all test frames, in mm.
    pub max_mean_error: Option<f64>,
    /// Largest acceptable share of test frames without an estimate (0 to 1).
    pub max_missing_share: Option<f64>,
    /// Largest acceptable mean error over the frames faults corrupted, in mm.
    pub max_corrupted_mean_error: Option<f64>,
    /// Smallest acceptable area under the ROC curve of the detection score (faults only).
    pub min_detection_auc: Option<f64>,
    /// Limits of other methods, by method name.
    pub methods: BTreeMap<String, MethodExpectations>,
}

impl Expectations {
    /// The top-level limits: the evidential tracker's.
    pub fn evidential(&self) -> MethodExpectations {
        MethodExpectations {
            max_mean_error: self.max_mean_error,
            max_missing_share: self.max_missing_share,
            max_corrupted_mean_error: self.max_corrupted_mean_error,
            min_detection_auc: self.min_detection_auc,
            ..MethodExpectations::default()
        }
    }
}

/// What one method is expected to achieve.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MethodExpectations {
    /// Largest acceptable mean estimation error over all test frames, in mm.
    pub max_mean_error: Option<f64>,
    /// Largest acceptable share of test frames without an estimate (0 to 1).
    pub max_missing_share: Option<f64>,
    /// Largest acceptable mean error over the frames faults corrupted, in mm.
    pub max_corrupted_mean_error: Option<f64>,
    /// Smallest acceptable area under the ROC curve of the detection score (faults only).
    pub min_detection_auc: Option<f64>,
    /// Smallest acceptable share of clean frames its calibrated regions hold.
    pub min_coverage: Option<f64>,
    /// Largest acceptable share of clean frames its regions hold (a region too wide says little).
    pub max_coverage: Option<f64>,
    /// Smallest acceptable share of corrupted frames its regions hold (abstentions cover the
    /// workspace).
    pub min_corrupted_coverage: Option<f64>,
    /// Largest acceptable share of clean frames it abstains on.
    pub max_abstained_share: Option<f64>,
    /// Smallest and largest acceptable area under its risk–coverage curve over all frames (mm).
    pub min_aurc: Option<f64>,
    /// See `min_aurc`.
    pub max_aurc: Option<f64>,
}

impl MethodExpectations {
    /// Whether any limit is set.
    pub fn any(&self) -> bool {
        self.max_mean_error.is_some()
            || self.max_missing_share.is_some()
            || self.max_corrupted_mean_error.is_some()
            || self.min_detection_auc.is_some()
            || self.confidence_limits().iter().any(|(_, v, _)| v.is_some())
    }

    /// The confidence limits: (name, limit, whether it is a lower bound).
    pub fn confidence_limits(&self) -> [(&'static str, Option<f64>, bool); 6] {
        [
            ("coverage", self.min_coverage, true),
            ("coverage", self.max_coverage, false),
            (
                "coverage on corrupted frames",
                self.min_corrupted_coverage,
                true,
            ),
            (
                "share of clean frames abstained on",
                self.max_abstained_share,
                false,
            ),
            ("AURC", self.min_aurc, true),
            ("AURC", self.max_aurc, false),
        ]
    }
}
