//! Bounds on the work of one combination, apart from the combination API and the engine that
//! both check them.

use super::EvidenceError;

/// Bounds on the work of one combination, so that a small input cannot exhaust memory (two
/// functions of 100 focal sets on a frame of 2²⁴ elements have 10⁴ intersections of 2 MB each).
/// Every function, the inputs and each intermediate result, is checked against both; an excess
/// stops the combination with [`EvidenceError::WorkLimit`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct WorkLimits {
    /// Focal sets any one function may have.
    pub focal_sets: usize,
    /// Bytes of set storage any one function may need: focal sets × ⌈frame size / 64⌉ × 8.
    pub set_bytes: usize,
    /// Tuples of focal sets (one per function) a rule that visits each tuple may visit: PCR6.
    pub tuples: usize,
}

impl WorkLimits {
    /// The defaults of the library and of `evitrack combine`.
    pub const DEFAULT: WorkLimits = WorkLimits {
        focal_sets: 1 << 20,
        set_bytes: 1 << 30,
        tuples: 1 << 26,
    };

    /// Whether `sets` sets of `words` words each are within the limits; which one is not.
    pub(crate) fn check(&self, sets: usize, words: usize) -> Result<(), EvidenceError> {
        if sets > self.focal_sets {
            return Err(EvidenceError::WorkLimit {
                limit: WorkLimit::FocalSets,
                max: self.focal_sets,
            });
        }
        if sets.saturating_mul(words).saturating_mul(8) > self.set_bytes {
            return Err(EvidenceError::WorkLimit {
                limit: WorkLimit::SetBytes,
                max: self.set_bytes,
            });
        }
        Ok(())
    }

    /// Whether `tuples` tuples of focal sets are within the limits.
    pub(crate) fn check_tuples(&self, tuples: usize) -> Result<(), EvidenceError> {
        if tuples > self.tuples {
            return Err(EvidenceError::WorkLimit {
                limit: WorkLimit::Tuples,
                max: self.tuples,
            });
        }
        Ok(())
    }

    /// Largest number of sets of `words` words each within the limits.
    pub(crate) fn max_sets(&self, words: usize) -> usize {
        self.focal_sets.min(self.set_bytes / (8 * words.max(1)))
    }
}

impl Default for WorkLimits {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// Which of the [`WorkLimits`] a combination reached.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WorkLimit {
    /// [`WorkLimits::focal_sets`].
    FocalSets,
    /// [`WorkLimits::set_bytes`].
    SetBytes,
    /// [`WorkLimits::tuples`].
    Tuples,
    /// The output size of the exchange format ([`crate::evidence::exchange::CombineLimits`]).
    OutputElements,
}

impl std::fmt::Display for WorkLimit {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            WorkLimit::FocalSets => "focal sets in one function",
            WorkLimit::SetBytes => "bytes of focal-set storage in one function",
            WorkLimit::Tuples => "tuples of focal sets (one per function) to visit",
            WorkLimit::OutputElements => "elements listed in the output's focal sets",
        })
    }
}
