//! Dempster–Shafer evidence algebra: subsets of finite frames, mass functions, Dempster's rule and
//! every other combination rule ([`combine_all`]), the level of conflict, refinings between
//! frames, constructors from likelihoods, discounting and decisions (relative plausibility,
//! pignistic probability, pointwise estimates).
//!
//! This room is a leaf: it knows nothing of images, robots or the rest of the crate, so every other
//! room can build on it and it can be tested on its own.

mod combine;
mod construct;
mod decision;
mod engine;
pub mod exchange;
mod level;
mod limits;
mod mass;
mod refining;
mod rules;
mod subset;

pub use combine::{
    conflict, conflict_level_all, conjunctive, conjunctive_all, conjunctive_all_within,
    contour_product, dempster, dempster_all, dempster_all_within, level_of_conflict, Combination,
};
pub use construct::{from_likelihoods, Constructor, LikelihoodIssue, Measurement};
pub use decision::{pignistic, pointwise_estimate, relative_plausibility};
pub use exchange::{combine_input, combine_json, CombineInput, CombineReport, RawMassFunction};
pub use level::ConflictLevel;
pub use limits::{WorkLimit, WorkLimits};
pub use mass::{MassFunction, MASS_TOLERANCE};
pub use refining::Refining;
pub use rules::{combine_all, combine_all_within, discount_all, Rule, MAX_CAUTIOUS_FRAME};
pub use subset::{Iter, Subset, INLINE_BITS, MAX_FRAME};

/// Everything that can go wrong in the evidence algebra.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum EvidenceError {
    /// A frame of discernment needs at least one element.
    #[error("the frame of discernment is empty: give it at least one element")]
    EmptyFrame,
    /// A frame larger than [`MAX_FRAME`].
    #[error("a frame of {frame} elements is larger than the supported maximum of {max}")]
    FrameTooLarge {
        /// The requested size.
        frame: usize,
        /// The maximum, [`MAX_FRAME`].
        max: usize,
    },
    /// An element index is not below the frame size.
    #[error("element {index} is out of range for a frame of {frame} elements (valid: 0..{frame})")]
    IndexOutOfRange {
        /// The offending index.
        index: usize,
        /// The frame size.
        frame: usize,
    },
    /// Two objects live on frames of different sizes.
    #[error("frame size mismatch: expected {expected} elements, found {found}; combine only functions on the same frame (extend them through a refining first)")]
    FrameMismatch {
        /// The frame size required.
        expected: usize,
        /// The frame size found.
        found: usize,
    },
    /// A mass is NaN, infinite or negative.
    #[error("focal set {focal}: mass {mass} is not a finite non-negative number")]
    InvalidMass {
        /// Index of the focal set.
        focal: usize,
        /// The offending mass.
        mass: f64,
    },
    /// A normalised mass function puts mass on the empty set.
    #[error("focal set {focal} is empty; a normalised mass function cannot put mass on the empty set (use MassFunction::unnormalised if you mean it)")]
    EmptyFocalSet {
        /// Index of the focal set.
        focal: usize,
    },
    /// The masses do not sum to one.
    #[error("masses sum to {sum}, not 1 (tolerance {tolerance}); rescale them so they sum to 1")]
    MassSum {
        /// The actual sum.
        sum: f64,
        /// The accepted absolute deviation.
        tolerance: f64,
    },
    /// A combination was asked for with no mass function.
    #[error("no mass function to combine: give at least one")]
    NothingToCombine,
    /// A refining needs at least one block.
    #[error("a refining needs at least one block (one per coarse element)")]
    NoBlocks,
    /// A block of a refining is empty.
    #[error("block {block} of the refining is empty: every coarse element must map to at least one fine element")]
    EmptyBlock {
        /// Index of the coarse element.
        block: usize,
    },
    /// Two blocks of a refining share an element.
    #[error("blocks {first} and {second} of the refining both contain fine element {element}: blocks must be disjoint")]
    OverlappingBlocks {
        /// First block.
        first: usize,
        /// Second block.
        second: usize,
        /// A shared fine element.
        element: usize,
    },
    /// A fine element is in no block.
    #[error("fine element {element} is in no block: the blocks must cover the fine frame")]
    UncoveredElement {
        /// The uncovered fine element.
        element: usize,
    },
    /// A coarse element receives no fine element in an assignment.
    #[error("coarse element {coarse} has no fine element assigned to it: drop the state or assign samples to it")]
    UnusedCoarseElement {
        /// The coarse element.
        coarse: usize,
    },
    /// A reliability factor outside [0, 1].
    #[error("reliability {alpha} is not in [0, 1]")]
    InvalidReliability {
        /// The offending factor.
        alpha: f64,
    },
    /// Two inputs that must have the same length do not.
    #[error("{what}: expected {expected} values, found {found}")]
    LengthMismatch {
        /// What was being compared.
        what: &'static str,
        /// Expected length.
        expected: usize,
        /// Actual length.
        found: usize,
    },
    /// A weight or coordinate is NaN or infinite, or a weight is negative.
    #[error("{what} {index} is {value}: expected a finite{} number", if *.non_negative { " non-negative" } else { "" })]
    InvalidNumber {
        /// What the number is.
        what: &'static str,
        /// Its index.
        index: usize,
        /// Its value.
        value: f64,
        /// Whether negative values are invalid too.
        non_negative: bool,
    },
    /// All singleton plausibilities (or weights) are zero: nothing to normalise.
    #[error(
        "all {what} are zero: there is nothing to normalise (total conflict or empty evidence)"
    )]
    AllZero {
        /// What was zero.
        what: &'static str,
    },
    /// A combination would exceed one of its [`WorkLimits`].
    #[error("the combination needs more than {max} {limit}, the limit")]
    WorkLimit {
        /// Which limit.
        limit: WorkLimit,
        /// Its value.
        max: usize,
    },
    /// A rule that needs normalised inputs was given a function with mass on ∅.
    #[error("mass function {function} puts mass on the empty set; the {rule} rule needs normalised functions (combine it with Dempster's or the conjunctive rule)")]
    UnnormalisedInput {
        /// The rule's name.
        rule: &'static str,
        /// Index of the function.
        function: usize,
    },
    /// The cautious rule was given a dogmatic function (no mass on the whole frame).
    #[error("mass function {function} is dogmatic (no mass on the whole frame); the cautious rule needs m(Ω) > 0: discount it first (a reliability below 1)")]
    Dogmatic {
        /// Index of the function.
        function: usize,
    },
    /// A rule that works on every subset of the frame was given a larger frame than it allows.
    #[error("the {rule} rule works on all 2^n subsets of the frame and takes frames of at most {max} elements, not {frame}")]
    FrameTooLargeForRule {
        /// The rule's name.
        rule: &'static str,
        /// The frame size.
        frame: usize,
        /// The largest frame it takes.
        max: usize,
    },
    /// The combine input is not valid JSON of the expected shape.
    #[error("combine input: {0}")]
    Json(String),
    /// The combine input has a problem in one mass function.
    #[error("mass function {mass_function}{}: {reason}", match .focal_set { Some(f) => format!(", focal set {f}"), None => String::new() })]
    BadInput {
        /// Index of the mass function at fault.
        mass_function: usize,
        /// Index of the focal set at fault, when one is.
        focal_set: Option<usize>,
        /// What is wrong and how to fix it.
        reason: String,
    },
}

/// Random mass functions for the property tests of this room.
#[cfg(test)]
pub(crate) mod testutil {
    use super::{MassFunction, Subset};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// A random normalised mass function on `n` elements with 1..=`max_focal` focal sets.
    pub fn random_mass(n: usize, max_focal: usize, seed: u64) -> MassFunction {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let k = rng.random_range(1..=max_focal);
        let mut pairs = Vec::new();
        for _ in 0..k {
            let density: f64 = rng.random_range(0.05..1.0);
            let mut s = Subset::empty(n);
            for i in 0..n {
                if rng.random_bool(density) {
                    s.insert(i);
                }
            }
            if s.is_empty() {
                s.insert(rng.random_range(0..n));
            }
            pairs.push((s, rng.random_range(0.01..1.0)));
        }
        let total: f64 = pairs.iter().map(|p| p.1).sum();
        for p in &mut pairs {
            p.1 /= total;
        }
        MassFunction::new(n, pairs).expect("random mass function is valid")
    }
}
