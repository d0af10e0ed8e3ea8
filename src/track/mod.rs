//! Per-frame inference (§4, §5.3): likelihoods → measurement belief functions → vacuous extension
//! onto the sample poses → pairwise conflicts and conflict graph → chosen group → Dempster's rule →
//! pose estimate with an uncertainty, plus learning the conflict threshold (§4.3).
//!
//! The tracker takes plain data (sample poses, refinings, likelihood vectors) so that it does not
//! depend on how the model was trained.

mod cell_levels;
mod cell_products;
mod cells;
mod conflict;
mod estimate;
mod fusion;
mod group_search;
mod mask_map;
mod past;
mod settings;
mod threshold;
mod tracker;
mod tracker_model;
mod tracking;
mod tuples;

pub use fusion::MAX_RULE_TUPLES;
#[cfg(test)]
pub(crate) use group_search::select_group_exhaustive;
pub use group_search::{
    members, present_mask, select_group, GroupLevels, GroupMask, LevelBounds, Selection,
};
pub use past::{group_beside_past, group_beside_past_with, past_outweighs, PastFrame};
pub use settings::{
    CheckedTrackSettings, Combine, Discount, PoseRule, SelectionPolicy, TrackSettings,
    DEFAULT_MAX_ALTERNATIVES, MAX_ALTERNATIVES,
};
pub use threshold::{learn_conflict_threshold, quantile_threshold, ThresholdRule};
pub use tracker::{Alternative, FeatureIssue, FrameEstimate, FrameFlags, Tracker, Uncertainty};
pub use tracker_model::{GroupError, TrackedFeature, TrackerModel, MAX_FEATURES};

use crate::evidence::EvidenceError;

/// Everything that can go wrong when building or running the tracker.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum TrackError {
    /// A setting is out of range.
    #[error("tracker setting `{field}`: {reason}")]
    InvalidSetting {
        /// The field at fault.
        field: &'static str,
        /// What is wrong and what is accepted.
        reason: String,
    },
    /// The model has no sample pose.
    #[error("the model has no sample pose: train it on a non-empty sample trajectory")]
    NoPoses,
    /// A sample pose has a NaN or infinite coordinate.
    #[error("sample pose {index} is {pose:?}: coordinates must be finite")]
    BadPose {
        /// Index of the pose.
        index: usize,
        /// The pose.
        pose: [f64; 2],
    },
    /// Too few or too many features.
    #[error("the model has {found} features: the tracker needs 1 to {max}")]
    FeatureCount {
        /// Number of features given.
        found: usize,
        /// The maximum, [`MAX_FEATURES`].
        max: usize,
    },
    /// A feature's refining does not end on the sample poses.
    #[error("feature {feature}: its refining maps onto {found} elements but the model has {poses} sample poses")]
    FeatureFrame {
        /// The feature.
        feature: usize,
        /// Fine frame size of its refining.
        found: usize,
        /// Number of sample poses.
        poses: usize,
    },
    /// A validation error is NaN, infinite or negative.
    #[error("feature {feature}: validation error {value} is not a finite non-negative number")]
    BadValidationError {
        /// The feature.
        feature: usize,
        /// The value.
        value: f64,
    },
    /// A frame gives likelihoods for a different number of features than the model has.
    #[error("the frame has likelihoods for {found} features but the model has {expected}: pass one entry per feature (None when missing)")]
    FeatureInputCount {
        /// Features in the model.
        expected: usize,
        /// Entries given.
        found: usize,
    },
    /// Conflict levels and errors for threshold learning differ in length.
    #[error("threshold learning: {levels} conflict levels but {errors} errors; give one of each per frame")]
    LearningLengths {
        /// Number of levels.
        levels: usize,
        /// Number of errors.
        errors: usize,
    },
    /// A group's validation error is malformed.
    #[error("group validation error for features {group:?}: {reason}")]
    BadGroupError {
        /// The group's features.
        group: Vec<usize>,
        /// What is wrong.
        reason: String,
    },
    /// An estimation error for threshold learning is NaN, infinite or negative.
    #[error(
        "threshold learning: error of frame {frame} is {value}, not a finite non-negative number"
    )]
    LearningError {
        /// The frame.
        frame: usize,
        /// The value.
        value: f64,
    },
    /// An error of the evidence algebra.
    #[error("{}{source}", match .feature { Some(f) => format!("feature {f}: "), None => String::new() })]
    Evidence {
        /// The feature concerned, when one is.
        feature: Option<usize>,
        /// The underlying error.
        #[source]
        source: EvidenceError,
    },
}
