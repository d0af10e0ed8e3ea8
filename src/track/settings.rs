//! Tracker settings: raw (serde, `Default`) → [`TrackSettings::check`] → [`CheckedTrackSettings`].

use serde::{Deserialize, Serialize};

pub use super::fusion::{Combine, Discount};
use super::TrackError;
use crate::evidence::{ConflictLevel, Constructor, Rule};

/// How the group of features to combine is chosen among the compatible groups (§4.2).
///
/// A *combinable group* is a set of usable features that is complete in the conflict graph and
/// whose own level of conflict is within the conflict threshold (finite when it is `"inf"`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(try_from = "RawPolicy", into = "RawPolicy")]
pub enum SelectionPolicy {
    /// The largest combinable group; ties go to the lower level of conflict, then to the
    /// lexicographically smallest list of feature indices.
    #[default]
    LargestSubset,
    /// The combinable group of at least `min_size` features with the lowest level of conflict;
    /// ties (within 1e-12) go to the larger group, then to the lexicographically smallest list.
    LowestConflict {
        /// Smallest group size considered.
        min_size: usize,
    },
    /// Every maximal combinable group of at least `min_size` features gives its own estimate
    /// (listed as alternatives by decreasing size, then increasing conflict, then feature list);
    /// the first alternative is the estimate (so the pick follows the largest-subset rule).
    Splitting {
        /// Smallest group size considered.
        min_size: usize,
    },
}

/// Serde form of [`SelectionPolicy`]: `{ policy = "...", min_size = n }` (flat, so that unknown
/// fields and a `min_size` on the largest-subset policy are errors).
#[derive(Clone, Copy, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawPolicy {
    policy: PolicyName,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    min_size: Option<usize>,
}

#[derive(Clone, Copy, Debug, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
enum PolicyName {
    LargestSubset,
    LowestConflict,
    Splitting,
}

impl TryFrom<RawPolicy> for SelectionPolicy {
    type Error = String;
    fn try_from(raw: RawPolicy) -> Result<Self, String> {
        match (raw.policy, raw.min_size) {
            (PolicyName::LargestSubset, None) => Ok(SelectionPolicy::LargestSubset),
            (PolicyName::LargestSubset, Some(_)) => {
                Err("policy `largest_subset` takes no `min_size`".into())
            }
            (PolicyName::LowestConflict, Some(min_size)) => {
                Ok(SelectionPolicy::LowestConflict { min_size })
            }
            (PolicyName::Splitting, Some(min_size)) => Ok(SelectionPolicy::Splitting { min_size }),
            (_, None) => Err("policies `lowest_conflict` and `splitting` need `min_size`".into()),
        }
    }
}

impl From<SelectionPolicy> for RawPolicy {
    fn from(p: SelectionPolicy) -> Self {
        let (policy, min_size) = match p {
            SelectionPolicy::LargestSubset => (PolicyName::LargestSubset, None),
            SelectionPolicy::LowestConflict { min_size } => {
                (PolicyName::LowestConflict, Some(min_size))
            }
            SelectionPolicy::Splitting { min_size } => (PolicyName::Splitting, Some(min_size)),
        };
        RawPolicy { policy, min_size }
    }
}

impl SelectionPolicy {
    /// Smallest eligible group size (1 for the largest-subset policy).
    pub fn min_size(self) -> usize {
        match self {
            SelectionPolicy::LargestSubset => 1,
            SelectionPolicy::LowestConflict { min_size }
            | SelectionPolicy::Splitting { min_size } => min_size,
        }
    }
}

/// How the pose estimate is read off the combined belief function (§4.4).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum PoseRule {
    /// Σ p(q) q with p the relative plausibility of the sample poses (the paper's estimate).
    #[default]
    WeightedMean,
    /// The sample pose of highest relative plausibility (ties: lowest sample index).
    Map,
    /// Σ BetP(q) q with BetP the pignistic probability of the combined function.
    Pignistic,
}

/// Raw tracker settings, as read from a scenario or model file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrackSettings {
    /// Measurement function constructor (§3.6).
    pub constructor: Constructor,
    /// Conflict threshold: features i, j are compatible (an edge of the conflict graph) when K_ij
    /// is finite and K_ij ≤ threshold, and a group may be combined when its own level is within
    /// it too. `"inf"` (the default) admits every pair and group with finite conflict.
    pub conflict_threshold: ConflictLevel,
    /// Group selection policy.
    pub selection: SelectionPolicy,
    /// Pose estimator.
    pub estimator: PoseRule,
    /// Share of the relative plausibility the reported uncertainty radius must hold, in (0, 1].
    pub uncertainty_mass: f64,
    /// Which features are combined: the selected group (the paper's) or every usable feature.
    #[serde(skip_serializing_if = "Combine::is_default")]
    pub combine: Combine,
    /// The combination rule (Dempster's, the paper's, by default).
    #[serde(skip_serializing_if = "is_dempster")]
    pub rule: Rule,
    /// Shafer's discounting of each feature before the rule.
    #[serde(skip_serializing_if = "Discount::is_none")]
    pub discount: Discount,
    /// The splitting policy's cap: a frame estimates and weighs at most this many alternatives
    /// (the most reliable when the model has group errors, else the first in the policy's
    /// order), and records how many it found (1 to
    /// [`MAX_ALTERNATIVES`]).
    #[serde(skip_serializing_if = "is_default_max_alternatives")]
    pub max_alternatives: usize,
}

/// The default cap on the splitting policy's alternatives: above the most any frame of the
/// stored scenarios has, so that their outputs are those of the uncapped policy.
pub const DEFAULT_MAX_ALTERNATIVES: usize = 16;

/// The largest cap accepted: each alternative holds a plausibility per sample pose (80 kB at
/// 10,000 poses), and a frame estimates every one it keeps.
pub const MAX_ALTERNATIVES: usize = 1024;

/// Default fields are left out of files, so files of the defaults read as before.
fn is_dempster(rule: &Rule) -> bool {
    *rule == Rule::Dempster
}

fn is_default_max_alternatives(cap: &usize) -> bool {
    *cap == DEFAULT_MAX_ALTERNATIVES
}

impl Default for TrackSettings {
    fn default() -> Self {
        TrackSettings {
            constructor: Constructor::Bayesian,
            conflict_threshold: ConflictLevel::Infinite,
            selection: SelectionPolicy::LargestSubset,
            estimator: PoseRule::WeightedMean,
            uncertainty_mass: 0.9,
            combine: Combine::Selected,
            rule: Rule::Dempster,
            discount: Discount::None,
            max_alternatives: DEFAULT_MAX_ALTERNATIVES,
        }
    }
}

/// Settings that passed [`TrackSettings::check`].
#[derive(Clone, Debug, PartialEq)]
pub struct CheckedTrackSettings(TrackSettings);

impl CheckedTrackSettings {
    /// The validated settings.
    pub fn get(&self) -> &TrackSettings {
        &self.0
    }
}

impl TrackSettings {
    /// Validate: the threshold is not NaN and not negative, `min_size` ≥ 1, `uncertainty_mass` in
    /// (0, 1], `max_alternatives` in 1..=[`MAX_ALTERNATIVES`] (the other policies have no
    /// alternatives and ignore it: the fit's own trackers take the scenario's settings with
    /// another policy).
    ///
    /// # Errors
    /// [`TrackError::InvalidSetting`] naming the field and what is accepted.
    pub fn check(self) -> Result<CheckedTrackSettings, TrackError> {
        if !self.conflict_threshold.is_valid() {
            return Err(TrackError::InvalidSetting {
                field: "conflict_threshold",
                reason: format!(
                    "{} is not a level of conflict: use a number ≥ 0 or \"inf\"",
                    self.conflict_threshold.value()
                ),
            });
        }
        if self.selection.min_size() == 0 {
            return Err(TrackError::InvalidSetting {
                field: "selection.min_size",
                reason: "must be at least 1".into(),
            });
        }
        if !(1..=MAX_ALTERNATIVES).contains(&self.max_alternatives) {
            return Err(TrackError::InvalidSetting {
                field: "max_alternatives",
                reason: format!(
                    "{} is not a number of alternatives: use 1 to {MAX_ALTERNATIVES}",
                    self.max_alternatives
                ),
            });
        }
        if !(self.uncertainty_mass > 0.0 && self.uncertainty_mass <= 1.0) {
            return Err(TrackError::InvalidSetting {
                field: "uncertainty_mass",
                reason: format!("{} is not in (0, 1]", self.uncertainty_mass),
            });
        }
        self.check_fusion()?;
        Ok(CheckedTrackSettings(self))
    }

    /// The rule, discounting and combined group fit together.
    fn check_fusion(&self) -> Result<(), TrackError> {
        let bad = |field, reason: &str| {
            Err(TrackError::InvalidSetting {
                field,
                reason: reason.into(),
            })
        };
        if let Discount::Fixed(alpha) = self.discount {
            if !(0.0..=1.0).contains(&alpha) {
                return bad(
                    "discount",
                    &format!("{alpha} is not a reliability: use a number in [0, 1], \"learned\" or \"none\""),
                );
            }
        }
        if self.combine == Combine::All && self.selection != SelectionPolicy::LargestSubset {
            return bad(
                "selection",
                "`combine = \"all\"` combines every usable feature: it takes no selection policy",
            );
        }
        if self.rule != Rule::Dempster
            && matches!(self.selection, SelectionPolicy::Splitting { .. })
        {
            return bad(
                "rule",
                "the splitting policy weighs its alternatives by Dempster's rule: use `rule = \"dempster\"` with it",
            );
        }
        if self.rule == Rule::Cautious
            && self.constructor == Constructor::Bayesian
            && self.discount == Discount::None
        {
            return bad(
                "rule",
                "the cautious rule takes non-dogmatic functions, and Bayesian measurements are \
                 dogmatic: discount them (`discount = \"learned\"` or a number below 1)",
            );
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_round_trip_through_json_and_toml() {
        let s = TrackSettings::default();
        let json = serde_json::to_string(&s).unwrap();
        assert!(json.contains("\"conflict_threshold\":\"inf\""), "{json}");
        assert_eq!(serde_json::from_str::<TrackSettings>(&json).unwrap(), s);
        let t = TrackSettings {
            conflict_threshold: ConflictLevel::Finite(0.25),
            selection: SelectionPolicy::LowestConflict { min_size: 3 },
            estimator: PoseRule::Map,
            constructor: Constructor::Consonant,
            uncertainty_mass: 0.5,
            combine: Combine::All,
            rule: Rule::Murphy,
            discount: Discount::Fixed(0.25),
            max_alternatives: DEFAULT_MAX_ALTERNATIVES,
        };
        let text = toml::to_string(&t).unwrap();
        assert_eq!(toml::from_str::<TrackSettings>(&text).unwrap(), t);
        let parsed: TrackSettings = toml::from_str(
            "constructor = \"consonant\"\nselection = { policy = \"splitting\", min_size = 2 }\n",
        )
        .unwrap();
        assert_eq!(parsed.selection, SelectionPolicy::Splitting { min_size: 2 });
        assert_eq!(parsed.conflict_threshold, ConflictLevel::Infinite);
    }

    #[test]
    fn unknown_fields_and_bad_values_are_rejected() {
        assert!(toml::from_str::<TrackSettings>("treshold = 1.0").is_err());
        assert!(toml::from_str::<TrackSettings>(
            "selection = { policy = \"largest_subset\", min_size = 2 }"
        )
        .is_err());
        let bad = |f: fn(&mut TrackSettings)| {
            let mut s = TrackSettings::default();
            f(&mut s);
            s.check()
        };
        assert!(toml::from_str::<TrackSettings>("selection = { policy = \"splitting\" }").is_err());
        assert!(toml::from_str::<TrackSettings>(
            "selection = { policy = \"splitting\", min_size = 2, x = 1 }"
        )
        .is_err());
        assert!(bad(|s| s.conflict_threshold = ConflictLevel::Finite(f64::NAN)).is_err());
        assert!(bad(|s| s.conflict_threshold = ConflictLevel::Finite(-1.0)).is_err());
        assert!(bad(|s| s.selection = SelectionPolicy::Splitting { min_size: 0 }).is_err());
        assert!(bad(|s| s.uncertainty_mass = 0.0).is_err());
        assert!(bad(|s| s.uncertainty_mass = f64::NAN).is_err());
        assert!(bad(|s| s.conflict_threshold = ConflictLevel::Finite(0.0)).is_ok());
    }

    #[test]
    fn the_cap_on_alternatives_is_read_checked_and_left_out_of_files_at_its_default() {
        let split = |cap: usize| TrackSettings {
            selection: SelectionPolicy::Splitting { min_size: 2 },
            max_alternatives: cap,
            ..TrackSettings::default()
        };
        let parsed: TrackSettings = toml::from_str(
            "selection = { policy = \"splitting\", min_size = 2 }\nmax_alternatives = 3\n",
        )
        .unwrap();
        assert_eq!(parsed, split(3));
        assert!(toml::to_string(&split(3))
            .unwrap()
            .contains("max_alternatives = 3"));
        // Files written with the default read as before: the key is left out.
        let text = toml::to_string(&split(DEFAULT_MAX_ALTERNATIVES)).unwrap();
        assert!(!text.contains("max_alternatives"), "{text}");
        assert_eq!(TrackSettings::default().max_alternatives, 16);
        let message = |s: TrackSettings| s.check().unwrap_err().to_string();
        assert_eq!(
            message(split(0)),
            "tracker setting `max_alternatives`: 0 is not a number of alternatives: use 1 to 1024"
        );
        assert!(message(split(MAX_ALTERNATIVES + 1)).contains("use 1 to 1024"));
        assert!(split(1).check().is_ok() && split(MAX_ALTERNATIVES).check().is_ok());
        // The other policies ignore it, and the range holds for them too.
        let largest = |cap| TrackSettings {
            max_alternatives: cap,
            ..TrackSettings::default()
        };
        assert!(largest(4).check().is_ok());
        assert!(message(largest(0)).contains("use 1 to 1024"));
    }
}
