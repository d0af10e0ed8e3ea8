//! Every combination rule behind one entry point, [`combine_all`], and discounting by a
//! reliability before any rule ([`discount_all`]).
//!
//! Conflict bookkeeping: the [`Combination`]'s `conflict_mass` κ and `conflict_level`
//! K = −ln(1 − κ) are, for every rule but the cautious and Murphy's, those of the unnormalised
//! conjunctive combination of the inputs as given (after any discounting): how much the sources
//! disagree, computed exactly by Dempster's engine (no underflow, the same whatever the order).
//! Each rule's documentation says where it puts κ. The cautious rule and Murphy's report the
//! conflict of their own conjunctive steps.

mod cautious;
mod dubois_prade;
mod pcr6;

use serde::{Deserialize, Serialize};

use super::combine::{dempster_all_within, unnormalised, Combination};
use super::engine::{frame_of, run, to_mass_function, Mode};
use super::limits::WorkLimits;
use super::mass::MassFunction;
use super::subset::Subset;
use super::EvidenceError;

pub use cautious::MAX_CAUTIOUS_FRAME;

/// A combination rule (the `rule` of the `combine` exchange format).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Rule {
    /// Dempster's rule: the conjunctive combination normalised by 1 − κ; κ is removed. `None` on
    /// total conflict.
    #[default]
    Dempster,
    /// The unnormalised conjunctive rule: κ stays on ∅ (the result's `empty_mass`).
    Conjunctive,
    /// Yager's rule: the conjunctive combination with κ moved to the whole frame Ω.
    Yager,
    /// Dubois and Prade's rule: the product of each tuple of focal sets (one per function) goes to
    /// their intersection, or, when that is empty, to their union. κ is spread over those unions.
    DuboisPrade,
    /// PCR6 (Martin and Osswald's general formula, n-ary, not the sequential pairwise rule): the
    /// product P = Π mᵢ(Aᵢ) of each tuple with an empty intersection goes back to the tuple's
    /// focal sets, Aᵢ receiving P · mᵢ(Aᵢ) / Σⱼ mⱼ(Aⱼ) (a set chosen by several sources receives
    /// each of their shares). κ is spread back over the focal sets of the conflicting tuples.
    Pcr6,
    /// The disjunctive rule: products go to unions; it creates no conflict. κ and K are the
    /// inputs' conjunctive conflict, reported for information only.
    Disjunctive,
    /// Denœux's cautious conjunctive rule, for non-dogmatic functions (m(Ω) > 0): the weights of
    /// the canonical conjunctive decompositions are combined by their minimum. The result is
    /// unnormalised: κ is its own mass on ∅, kept there, and K = −ln(1 − κ).
    Cautious,
    /// Murphy's averaging: the mean of the n functions combined with itself by Dempster's rule
    /// (n − 1 combinations). κ and K are those of that Dempster combination, removed by its
    /// normalisation.
    Murphy,
}

impl Rule {
    /// Every rule, in the order of the documentation.
    pub const ALL: [Rule; 8] = [
        Rule::Dempster,
        Rule::Conjunctive,
        Rule::Yager,
        Rule::DuboisPrade,
        Rule::Pcr6,
        Rule::Disjunctive,
        Rule::Cautious,
        Rule::Murphy,
    ];

    /// The rule's name in the exchange format.
    pub fn name(self) -> &'static str {
        match self {
            Rule::Dempster => "dempster",
            Rule::Conjunctive => "conjunctive",
            Rule::Yager => "yager",
            Rule::DuboisPrade => "dubois_prade",
            Rule::Pcr6 => "pcr6",
            Rule::Disjunctive => "disjunctive",
            Rule::Cautious => "cautious",
            Rule::Murphy => "murphy",
        }
    }
}

/// Combine any number of functions by `rule` within [`WorkLimits::DEFAULT`].
///
/// # Errors
/// As [`combine_all_within`].
pub fn combine_all<'a, I: IntoIterator<Item = &'a MassFunction>>(
    rule: Rule,
    fs: I,
) -> Result<Combination, EvidenceError> {
    combine_all_within(rule, fs, &WorkLimits::DEFAULT)
}

/// Combine any number of functions by `rule` (see [`Rule`] for each rule's definition and
/// conflict bookkeeping). Only Dempster's rule can have no result (`mass: None`, total conflict);
/// the others give a function on total conflict too, with K = +∞.
///
/// # Errors
/// [`EvidenceError::NothingToCombine`], [`EvidenceError::FrameMismatch`],
/// [`EvidenceError::WorkLimit`]; [`EvidenceError::UnnormalisedInput`] for Yager's, Dubois and
/// Prade's, PCR6 and the disjunctive rule given mass on ∅; for the cautious rule
/// [`EvidenceError::Dogmatic`] and [`EvidenceError::FrameTooLargeForRule`] beyond
/// [`MAX_CAUTIOUS_FRAME`].
pub fn combine_all_within<'a, I: IntoIterator<Item = &'a MassFunction>>(
    rule: Rule,
    fs: I,
    limits: &WorkLimits,
) -> Result<Combination, EvidenceError> {
    let (n, fs) = frame_of(fs)?;
    if matches!(
        rule,
        Rule::Yager | Rule::DuboisPrade | Rule::Pcr6 | Rule::Disjunctive
    ) {
        if let Some(function) = fs.iter().position(|f| f.empty_mass() > 0.0) {
            return Err(EvidenceError::UnnormalisedInput {
                rule: rule.name(),
                function,
            });
        }
    }
    let copies = fs.iter().copied();
    match rule {
        Rule::Dempster => dempster_all_within(copies, limits),
        Rule::Conjunctive => {
            let c = dempster_all_within(copies, limits)?;
            Ok(Combination {
                mass: Some(unnormalised(n, &c)),
                ..c
            })
        }
        Rule::Yager => {
            let c = dempster_all_within(copies, limits)?;
            let mass = Some(yager(n, &c));
            Ok(Combination { mass, ..c })
        }
        Rule::DuboisPrade => {
            let c = dempster_all_within(copies, limits)?;
            let m = dubois_prade::combine(n, &fs, limits)?;
            Ok(Combination { mass: Some(m), ..c })
        }
        Rule::Pcr6 => {
            let c = dempster_all_within(copies, limits)?;
            let m = pcr6::combine(n, &fs, &c, limits)?;
            Ok(Combination { mass: Some(m), ..c })
        }
        Rule::Disjunctive => {
            let c = dempster_all_within(copies, limits)?;
            let m = run(n, &fs, (Mode::Disjunctive, limits), |out| {
                to_mass_function(out, false)
            })?;
            Ok(Combination { mass: m, ..c })
        }
        Rule::Cautious => cautious::combine(n, &fs),
        Rule::Murphy => {
            let k = fs.len() as f64;
            let pairs = fs
                .iter()
                .flat_map(|f| f.focal().map(move |(s, m)| (s.clone(), m / k)))
                .collect();
            let mean = MassFunction::unnormalised(n, pairs)?;
            dempster_all_within(std::iter::repeat_n(&mean, fs.len()), limits)
        }
    }
}

/// Yager's combination from Dempster's `c`: its function scaled by e^(−K), κ added on Ω (on the
/// words, so no subset is built).
fn yager(n: usize, c: &Combination) -> MassFunction {
    let conj = unnormalised(n, c);
    let full = Subset::full(n);
    let full = full.words();
    let mut words = Vec::with_capacity((conj.len() + 1) * full.len());
    let mut mass = Vec::with_capacity(conj.len() + 1);
    let mut on_full = c.conflict_mass;
    for (s, &m) in conj.set_words().zip(conj.masses()) {
        if s == full {
            on_full += m;
        } else if s.iter().any(|&x| x != 0) {
            words.extend_from_slice(s);
            mass.push(m);
        }
    }
    if on_full > 0.0 {
        words.extend_from_slice(full);
        mass.push(on_full);
    }
    MassFunction::from_words(n, words, mass)
}

/// A function from (set, mass) pairs that sum to 1 up to rounding: identical sets merged, zero
/// masses dropped, no check of the sum (the rules' results are sums of products).
pub(super) fn from_pairs(n: usize, pairs: Vec<(Subset, f64)>) -> MassFunction {
    let mut index = std::collections::HashMap::with_capacity(pairs.len());
    let mut focal = Vec::with_capacity(pairs.len());
    let mut mass: Vec<f64> = Vec::with_capacity(pairs.len());
    for (s, m) in pairs {
        if m <= 0.0 {
            continue;
        }
        match index.get(&s) {
            Some(&k) => mass[k] += m,
            None => {
                index.insert(s.clone(), focal.len());
                focal.push(s);
                mass.push(m);
            }
        }
    }
    MassFunction::from_parts(n, focal, mass)
}

/// Shafer's discounting of every function: m'(A) = α m(A), m'(Ω) += 1 − α, with one reliability
/// α for all (`alphas` of length 1) or one per function.
///
/// # Errors
/// [`EvidenceError::LengthMismatch`] when `alphas` has neither 1 nor `fs.len()` values,
/// [`EvidenceError::InvalidReliability`] for an α outside [0, 1] or NaN.
pub fn discount_all(
    fs: &[MassFunction],
    alphas: &[f64],
) -> Result<Vec<MassFunction>, EvidenceError> {
    if alphas.len() != 1 && alphas.len() != fs.len() {
        return Err(EvidenceError::LengthMismatch {
            what: "reliabilities (one for all functions, or one per function)",
            expected: fs.len(),
            found: alphas.len(),
        });
    }
    fs.iter()
        .enumerate()
        .map(|(i, f)| f.discount(alphas[if alphas.len() == 1 { 0 } else { i }]))
        .collect()
}

#[cfg(test)]
mod brute;
#[cfg(test)]
mod tests;
