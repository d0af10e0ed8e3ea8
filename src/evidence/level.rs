//! The level of conflict K = −ln(1 − κ) as a value: a number, or +∞ on total conflict. One type
//! for every level and threshold in the crate, written `"inf"` in JSON and TOML, which have no
//! infinity.

use serde::{Deserialize, Deserializer, Serialize, Serializer};

/// A level of conflict (or a threshold on it): a finite number, or +∞.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub enum ConflictLevel {
    /// A finite level K (≥ 0 for a level; a threshold is checked by its owner).
    Finite(f64),
    /// K = +∞: total conflict, or a threshold that admits every finite level.
    #[default]
    Infinite,
}

impl ConflictLevel {
    /// As an `f64` (`f64::INFINITY` for [`ConflictLevel::Infinite`]).
    pub fn value(self) -> f64 {
        match self {
            ConflictLevel::Finite(k) => k,
            ConflictLevel::Infinite => f64::INFINITY,
        }
    }

    /// `Finite(k)` for a finite `k`, otherwise `Infinite`.
    pub fn from_value(k: f64) -> Self {
        if k.is_finite() {
            ConflictLevel::Finite(k)
        } else {
            ConflictLevel::Infinite
        }
    }

    /// As a threshold: whether a pair with level `k` is compatible (finite and at most this).
    pub fn admits(self, k: f64) -> bool {
        k.is_finite() && k <= self.value()
    }

    /// Whether this is a finite number ≥ 0 or +∞ (what a level or threshold must be).
    pub fn is_valid(self) -> bool {
        match self {
            ConflictLevel::Finite(k) => k.is_finite() && k >= 0.0,
            ConflictLevel::Infinite => true,
        }
    }
}

impl Serialize for ConflictLevel {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match self {
            ConflictLevel::Finite(k) => s.serialize_f64(*k),
            ConflictLevel::Infinite => s.serialize_str("inf"),
        }
    }
}

impl<'de> Deserialize<'de> for ConflictLevel {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        #[derive(Deserialize)]
        #[serde(untagged)]
        enum Raw {
            Number(f64),
            Text(String),
        }
        match Raw::deserialize(d)? {
            // TOML's `inf` is a float: the same as "inf".
            Raw::Number(k) if k == f64::INFINITY => Ok(ConflictLevel::Infinite),
            Raw::Number(k) => Ok(ConflictLevel::Finite(k)),
            Raw::Text(t) if t == "inf" => Ok(ConflictLevel::Infinite),
            Raw::Text(t) => Err(serde::de::Error::custom(format!(
                "a level of conflict must be a number or \"inf\", not {t:?}"
            ))),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn infinity_is_written_inf_and_admits_every_finite_level() {
        assert_eq!(
            serde_json::to_string(&ConflictLevel::Infinite).unwrap(),
            "\"inf\""
        );
        assert_eq!(
            serde_json::from_str::<ConflictLevel>("0.5").unwrap(),
            ConflictLevel::Finite(0.5)
        );
        assert!(serde_json::from_str::<ConflictLevel>("\"infinite\"").is_err());
        assert!(ConflictLevel::Infinite.admits(1e300));
        assert!(!ConflictLevel::Infinite.admits(f64::INFINITY));
        assert!(ConflictLevel::Finite(0.5).admits(0.5));
        assert!(!ConflictLevel::Finite(0.5).admits(0.6));
        assert!(!ConflictLevel::Finite(-1.0).is_valid());
        assert!(!ConflictLevel::Finite(f64::NAN).is_valid());
        assert_eq!(
            ConflictLevel::from_value(f64::INFINITY),
            ConflictLevel::Infinite
        );
    }
}
