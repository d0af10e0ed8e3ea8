//! What a scenario expects of its runs: the limits `sweep --check` holds each method to.
//!
//! A limit (`max_…`, `min_…`) holds a figure on one side only. A *band* (`mean_error`,
//! `corrupted_mean_error`, `detection_auc`) is the figure as measured: the run must stay within
//! `tolerance` of it (3 % unless set) in either direction, so a figure that improves by more
//! than that fails too and is re-measured and updated deliberately (a gain nobody expected may be
//! a leak of ground truth). Bands hold on the seed they were measured on (`seed`, default 1);
//! runs of other seeds (`sweep --seeds N`) answer to the one-sided limits only.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

/// The relative half-width of a band when `tolerance` is not given.
pub const DEFAULT_TOLERANCE: f64 = 0.03;

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
    /// Measured mean error (mm): a band of `tolerance` either side.
    pub mean_error: Option<f64>,
    /// Measured mean error on corrupted frames (mm): a band.
    pub corrupted_mean_error: Option<f64>,
    /// Measured detection AUC: a band.
    pub detection_auc: Option<f64>,
    /// Relative half-width of the bands (default [`DEFAULT_TOLERANCE`]).
    pub tolerance: Option<f64>,
    /// The seed the bands were measured on (default 1).
    pub seed: Option<u64>,
    /// Limits of other methods, by method name.
    pub methods: BTreeMap<String, MethodExpectations>,
}

impl Expectations {
    /// Whether the bands hold for a run of `seed`.
    pub fn bands_hold_for(&self, seed: u64) -> bool {
        self.seed.unwrap_or(1) == seed
    }

    /// The top-level limits: the evidential tracker's.
    pub fn evidential(&self) -> MethodExpectations {
        MethodExpectations {
            max_mean_error: self.max_mean_error,
            max_missing_share: self.max_missing_share,
            max_corrupted_mean_error: self.max_corrupted_mean_error,
            min_detection_auc: self.min_detection_auc,
            mean_error: self.mean_error,
            corrupted_mean_error: self.corrupted_mean_error,
            detection_auc: self.detection_auc,
            tolerance: self.tolerance,
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
    /// Measured mean error (mm): a band of `tolerance` either side.
    pub mean_error: Option<f64>,
    /// Measured mean error on corrupted frames (mm): a band.
    pub corrupted_mean_error: Option<f64>,
    /// Measured detection AUC: a band.
    pub detection_auc: Option<f64>,
    /// Relative half-width of the bands (default [`DEFAULT_TOLERANCE`]).
    pub tolerance: Option<f64>,
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

/// What a run measured of one method, as the expectations name it (`None`: not measured).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct MeasuredFigures {
    /// Mean error over every frame with an estimate (mm).
    pub mean_error: Option<f64>,
    /// Share of frames without an estimate.
    pub missing_share: f64,
    /// Mean error over corrupted frames (mm).
    pub corrupted_mean_error: Option<f64>,
    /// Detection AUC.
    pub detection_auc: Option<f64>,
    /// Coverage of clean frames.
    pub coverage: Option<f64>,
    /// Coverage of corrupted frames.
    pub corrupted_coverage: Option<f64>,
    /// Share of clean frames abstained on.
    pub abstained_share: Option<f64>,
    /// Area under the risk–coverage curve (mm).
    pub aurc: Option<f64>,
}

/// How a figure is held: a one-sided limit or a band around it.
#[derive(Debug, Clone, Copy)]
enum Guard {
    AtMost,
    AtLeast,
    Band(f64),
}

impl MethodExpectations {
    /// Whether any limit is set.
    pub fn any(&self) -> bool {
        self.guards(&MeasuredFigures::default())
            .iter()
            .any(|g| g.1.is_some())
    }

    /// The relative half-width of this method's bands.
    pub fn tolerance(&self) -> f64 {
        self.tolerance.unwrap_or(DEFAULT_TOLERANCE)
    }

    /// Every guard: (what, expected value, how, measured).
    fn guards(&self, m: &MeasuredFigures) -> [(&'static str, Option<f64>, Guard, Option<f64>); 13] {
        let band = Guard::Band(self.tolerance());
        [
            (
                "mean error",
                self.max_mean_error,
                Guard::AtMost,
                m.mean_error,
            ),
            ("mean error", self.mean_error, band, m.mean_error),
            (
                "share of frames without an estimate",
                self.max_missing_share,
                Guard::AtMost,
                Some(m.missing_share),
            ),
            (
                "mean error on corrupted frames",
                self.max_corrupted_mean_error,
                Guard::AtMost,
                m.corrupted_mean_error,
            ),
            (
                "mean error on corrupted frames",
                self.corrupted_mean_error,
                band,
                m.corrupted_mean_error,
            ),
            (
                "detection AUC",
                self.min_detection_auc,
                Guard::AtLeast,
                m.detection_auc,
            ),
            ("detection AUC", self.detection_auc, band, m.detection_auc),
            ("coverage", self.min_coverage, Guard::AtLeast, m.coverage),
            ("coverage", self.max_coverage, Guard::AtMost, m.coverage),
            (
                "coverage on corrupted frames",
                self.min_corrupted_coverage,
                Guard::AtLeast,
                m.corrupted_coverage,
            ),
            (
                "share of clean frames abstained on",
                self.max_abstained_share,
                Guard::AtMost,
                m.abstained_share,
            ),
            ("AURC", self.min_aurc, Guard::AtLeast, m.aurc),
            ("AURC", self.max_aurc, Guard::AtMost, m.aurc),
        ]
    }

    /// What the measured figures miss, one sentence each (empty when every guard holds); the
    /// bands only with `bands`.
    pub fn misses(&self, measured: &MeasuredFigures, bands: bool) -> Vec<String> {
        let mut missed = Vec::new();
        for (what, expected, guard, found) in self.guards(measured) {
            let Some(expected) = expected else { continue };
            if matches!(guard, Guard::Band(_)) && !bands {
                continue;
            }
            let Some(found) = found.filter(|v| !v.is_nan()) else {
                missed.push(format!("{what} was not measured, expected {expected}"));
                continue;
            };
            match guard {
                Guard::AtMost if found > expected => missed.push(format!(
                    "{what} {found:.4} is above the expected maximum {expected}"
                )),
                Guard::AtLeast if found < expected => missed.push(format!(
                    "{what} {found:.4} is below the expected minimum {expected}"
                )),
                Guard::Band(t) if (found - expected).abs() > t * expected.abs() + 1e-12 => {
                    let off = 100.0 * (found - expected) / expected.abs().max(f64::MIN_POSITIVE);
                    let better = (found < expected) == (what != "detection AUC");
                    missed.push(format!(
                        "{what} {found:.4} is {off:+.1} % from the measured {expected} (band ±{:.1} %){}",
                        100.0 * t,
                        if better {
                            ": a better figure is news, not a pass: find out why, then re-measure \
                             and update the expectation deliberately"
                        } else {
                            ""
                        }
                    ));
                }
                _ => {}
            }
        }
        missed
    }

    /// Checks the values of every guard (their range, the tolerance).
    ///
    /// # Errors
    /// A sentence naming the field under `prefix` and what is wrong with it.
    pub fn check(&self, prefix: &str) -> Result<(), String> {
        if let Some(t) = self.tolerance.filter(|t| !(*t > 0.0 && *t < 1.0)) {
            return Err(format!("`{prefix}.tolerance` must lie in (0, 1), not {t}"));
        }
        for (field, value, share) in [
            ("max_mean_error", self.max_mean_error, false),
            ("mean_error", self.mean_error, false),
            (
                "max_corrupted_mean_error",
                self.max_corrupted_mean_error,
                false,
            ),
            ("corrupted_mean_error", self.corrupted_mean_error, false),
            ("max_missing_share", self.max_missing_share, true),
            ("min_detection_auc", self.min_detection_auc, true),
            ("detection_auc", self.detection_auc, true),
        ] {
            match value {
                Some(v) if share && !(0.0..=1.0).contains(&v) => {
                    return Err(format!("`{prefix}.{field}` must lie in [0, 1], not {v}"))
                }
                Some(v) if share || (v.is_finite() && v > 0.0) => {}
                Some(v) => {
                    return Err(format!(
                        "`{prefix}.{field}` must be a positive number of mm, not {v}"
                    ))
                }
                None => {}
            }
        }
        Ok(())
    }

    /// Whether a guard needs corrupted frames (hence `[[faults]]`).
    pub fn needs_faults(&self) -> bool {
        [
            self.max_corrupted_mean_error,
            self.corrupted_mean_error,
            self.min_detection_auc,
            self.detection_auc,
        ]
        .iter()
        .any(Option::is_some)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn measured(mean: f64) -> MeasuredFigures {
        MeasuredFigures {
            mean_error: Some(mean),
            ..MeasuredFigures::default()
        }
    }

    #[test]
    fn a_band_fails_a_figure_better_or_worse_by_more_than_its_tolerance() {
        let band = MethodExpectations {
            mean_error: Some(1.0),
            ..MethodExpectations::default()
        };
        assert!(band.any());
        for inside in [0.971, 1.0, 1.029] {
            assert!(band.misses(&measured(inside), true).is_empty(), "{inside}");
        }
        let better = band.misses(&measured(0.96), true);
        assert_eq!(better.len(), 1);
        assert!(better[0].contains("-4.0 %"), "{better:?}");
        assert!(better[0].contains("update the expectation deliberately"));
        let worse = band.misses(&measured(1.04), true);
        assert!(
            worse[0].contains("+4.0 %") && !worse[0].contains("news"),
            "{worse:?}"
        );
        let wide = MethodExpectations {
            tolerance: Some(0.05),
            ..band.clone()
        };
        assert!(wide.misses(&measured(0.96), true).is_empty());
        // Another seed: only one-sided limits hold.
        assert!(band.misses(&measured(0.5), false).is_empty());
        assert!(band.misses(&MeasuredFigures::default(), true)[0].contains("not measured"));
    }

    #[test]
    fn a_higher_auc_is_the_better_figure() {
        let band = MethodExpectations {
            detection_auc: Some(0.9),
            ..MethodExpectations::default()
        };
        let auc = |a| MeasuredFigures {
            detection_auc: Some(a),
            ..MeasuredFigures::default()
        };
        assert!(band.misses(&auc(0.95), true)[0].contains("news"));
        assert!(!band.misses(&auc(0.85), true)[0].contains("news"));
    }

    #[test]
    fn one_sided_limits_hold_one_side_only() {
        let limits = MethodExpectations {
            max_mean_error: Some(1.0),
            min_aurc: Some(0.1),
            ..MethodExpectations::default()
        };
        let m = MeasuredFigures {
            mean_error: Some(0.1),
            aurc: Some(0.2),
            ..MeasuredFigures::default()
        };
        assert!(limits.misses(&m, true).is_empty());
        let m = MeasuredFigures {
            mean_error: Some(1.5),
            aurc: Some(0.05),
            ..m
        };
        assert_eq!(limits.misses(&m, false).len(), 2);
    }

    #[test]
    fn values_out_of_range_are_named() {
        let bad = MethodExpectations {
            tolerance: Some(1.5),
            ..MethodExpectations::default()
        };
        assert!(bad
            .check("expect")
            .unwrap_err()
            .contains("expect.tolerance"));
        let bad = MethodExpectations {
            detection_auc: Some(1.5),
            ..MethodExpectations::default()
        };
        assert!(bad
            .check("expect.methods.gp")
            .unwrap_err()
            .contains("gp.detection_auc"));
        let bad = MethodExpectations {
            mean_error: Some(-1.0),
            ..MethodExpectations::default()
        };
        assert!(bad.check("expect").unwrap_err().contains("positive"));
    }
}
