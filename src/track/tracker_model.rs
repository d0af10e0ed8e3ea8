//! What the tracker needs to know: sample poses and, per feature, the refining of its frame onto
//! the sample poses. Plain data, so any trainer (the HMM-based model, a test) can build it.

use super::TrackError;
use crate::evidence::Refining;

/// Largest number of features a tracker accepts (groups are 64-bit masks; the selection's search
/// follows the conflict graph, so its cost does not double with every feature).
pub const MAX_FEATURES: usize = 64;

/// One feature of the model: its refining Θᵢ → Q̃ and, optionally, its validation error (mm), used
/// to pick the fallback feature.
#[derive(Clone, Debug, PartialEq)]
pub struct TrackedFeature {
    /// Refining from the feature's frame onto the sample poses.
    pub refining: Refining,
    /// Mean estimation error of this feature alone on a validation motion, if known.
    pub validation_error: Option<f64>,
}

/// The mean estimation error (mm) of one group of features combined alone on a validation motion:
/// the reliability the splitting policy weighs its alternatives by (§4.2).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GroupError {
    /// Feature indices, ascending.
    pub features: Vec<usize>,
    /// Mean error (mm).
    pub error: f64,
}

impl GroupError {
    /// The group's mask, after checking the features are a non-empty ascending list of indices
    /// below `n_features` and the error is finite and ≥ 0.
    ///
    /// # Errors
    /// What is wrong, as a sentence.
    pub fn check(&self, n_features: usize) -> Result<super::GroupMask, String> {
        if self.features.is_empty() || self.features.windows(2).any(|w| w[0] >= w[1]) {
            return Err("features must be a non-empty ascending list".into());
        }
        if self.features.iter().any(|&i| i >= n_features) {
            return Err(format!("the model has {n_features} features"));
        }
        if !(self.error.is_finite() && self.error >= 0.0) {
            return Err(format!("error {} is not finite and ≥ 0", self.error));
        }
        Ok(self
            .features
            .iter()
            .fold(0, |m: super::GroupMask, &i| m | 1 << i))
    }
}

/// The evidential model the tracker runs on: sample poses Q̃ (mm) and one refining per feature.
#[derive(Clone, Debug, PartialEq)]
pub struct TrackerModel {
    poses: Vec<[f64; 2]>,
    features: Vec<TrackedFeature>,
    /// Validation error of each group, by mask (empty when not learned).
    group_errors: std::collections::HashMap<super::GroupMask, f64>,
}

impl TrackerModel {
    /// Validate and build.
    ///
    /// # Errors
    /// [`TrackError::NoPoses`], [`TrackError::BadPose`], [`TrackError::FeatureCount`],
    /// [`TrackError::FeatureFrame`] (a refining whose fine frame is not the sample poses),
    /// [`TrackError::BadValidationError`].
    pub fn new(poses: Vec<[f64; 2]>, features: Vec<TrackedFeature>) -> Result<Self, TrackError> {
        if poses.is_empty() {
            return Err(TrackError::NoPoses);
        }
        if let Some((i, p)) = poses
            .iter()
            .enumerate()
            .find(|(_, p)| !p.iter().all(|x| x.is_finite()))
        {
            return Err(TrackError::BadPose { index: i, pose: *p });
        }
        if features.is_empty() || features.len() > MAX_FEATURES {
            return Err(TrackError::FeatureCount {
                found: features.len(),
                max: MAX_FEATURES,
            });
        }
        for (i, f) in features.iter().enumerate() {
            if f.refining.fine_size() != poses.len() {
                return Err(TrackError::FeatureFrame {
                    feature: i,
                    found: f.refining.fine_size(),
                    poses: poses.len(),
                });
            }
            if let Some(e) = f.validation_error {
                if !e.is_finite() || e < 0.0 {
                    return Err(TrackError::BadValidationError {
                        feature: i,
                        value: e,
                    });
                }
            }
        }
        Ok(TrackerModel {
            poses,
            features,
            group_errors: Default::default(),
        })
    }

    /// The same model with the groups' validation errors.
    ///
    /// # Errors
    /// [`TrackError::BadGroupError`] for an empty group, an index out of range or repeated, or an
    /// error that is not finite and ≥ 0.
    pub fn with_group_errors(mut self, errors: &[GroupError]) -> Result<Self, TrackError> {
        for g in errors {
            let mask =
                g.check(self.features.len())
                    .map_err(|reason| TrackError::BadGroupError {
                        group: g.features.clone(),
                        reason,
                    })?;
            self.group_errors.insert(mask, g.error);
        }
        Ok(self)
    }

    /// The validation error of a group (by mask), when learned.
    pub(super) fn group_error(&self, mask: super::GroupMask) -> Option<f64> {
        self.group_errors.get(&mask).copied()
    }

    /// Whether the model knows the validation error of any group.
    pub(super) fn knows_group_errors(&self) -> bool {
        !self.group_errors.is_empty()
    }

    /// The sample poses.
    pub fn poses(&self) -> &[[f64; 2]] {
        &self.poses
    }

    /// The features.
    pub fn features(&self) -> &[TrackedFeature] {
        &self.features
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn validation_names_the_fault() {
        let r = Refining::from_assignment(2, &[0, 1, 1]).unwrap();
        let f = |e| TrackedFeature {
            refining: r.clone(),
            validation_error: e,
        };
        let poses = vec![[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]];
        assert!(TrackerModel::new(poses.clone(), vec![f(None), f(Some(0.5))]).is_ok());
        assert_eq!(
            TrackerModel::new(vec![], vec![f(None)]),
            Err(TrackError::NoPoses)
        );
        assert!(matches!(
            TrackerModel::new(vec![[0.0, f64::NAN], [1.0, 0.0], [2.0, 0.0]], vec![f(None)]),
            Err(TrackError::BadPose { index: 0, .. })
        ));
        assert!(matches!(
            TrackerModel::new(poses.clone(), vec![]),
            Err(TrackError::FeatureCount { .. })
        ));
        assert!(matches!(
            TrackerModel::new(poses.clone(), vec![f(None); MAX_FEATURES + 1]),
            Err(TrackError::FeatureCount { .. })
        ));
        assert!(matches!(
            TrackerModel::new(poses[..2].to_vec(), vec![f(None)]),
            Err(TrackError::FeatureFrame { feature: 0, .. })
        ));
        assert!(matches!(
            TrackerModel::new(poses.clone(), vec![f(None), f(Some(-1.0))]),
            Err(TrackError::BadValidationError { feature: 1, .. })
        ));
    }
}
