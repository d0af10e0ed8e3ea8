//! The JSON exchange format of `evitrack combine FILE.json`, as library code.
//!
//! Input: `{"frame": n, "rule": RULE, "reliability": α or [α, …] (optional), "mass_functions":
//! [{"focal": [[i, …], …], "mass": [m, …]}, …]}` (unknown fields are errors); RULE is one of
//! [`Rule::name`] (`dempster`, `conjunctive`, `yager`, `dubois_prade`, `pcr6`, `disjunctive`,
//! `cautious`, `murphy`), and every function is discounted by its reliability first. Output:
//! `{"focal": […], "mass": […], "conflict_mass": κ, "conflict_level": K, "plausibility": [one value
//! per element]}`, focal sets sorted by decreasing mass (ties: lexicographic element lists); κ and
//! K as each [`Rule`] states. `conflict_level` is the string `"inf"` when K = +∞; when the rule
//! has no result (Dempster's on total conflict, or nothing but ∅ left) `focal` and `mass` are
//! empty and every plausibility is 0. Under the conjunctive and cautious rules the output is
//! unnormalised: masses and plausibilities are not divided by 1 − κ, and the mass on ∅ is
//! reported as `conflict_mass` only.

use serde::{Deserialize, Serialize};

use super::level::ConflictLevel;
use super::limits::{WorkLimit, WorkLimits};
use super::mass::{MassFunction, MASS_TOLERANCE};
use super::rules::{combine_all_within, discount_all, Rule};
use super::subset::{word_count, Subset};
use super::EvidenceError;

/// Input of `evitrack combine`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CombineInput {
    /// Number of elements of the frame.
    pub frame: usize,
    /// Combination rule.
    pub rule: Rule,
    /// Reliabilities α for Shafer's discounting before the rule: one for every function, or one
    /// per function; none keeps the functions as given.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reliability: Option<Reliability>,
    /// The mass functions to combine.
    pub mass_functions: Vec<RawMassFunction>,
}

/// The reliabilities of a combine input: one α or one per function.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum Reliability {
    /// One α for every function.
    All(f64),
    /// One α per function.
    Each(Vec<f64>),
}

impl Reliability {
    /// The values, as [`discount_all`] takes them.
    pub fn values(&self) -> &[f64] {
        match self {
            Reliability::All(a) => std::slice::from_ref(a),
            Reliability::Each(v) => v,
        }
    }
}

/// One mass function of the input, unvalidated.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawMassFunction {
    /// Focal sets as lists of element indices in 0..frame.
    pub focal: Vec<Vec<usize>>,
    /// One mass per focal set.
    pub mass: Vec<f64>,
}

/// Output of `evitrack combine`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CombineReport {
    /// Focal sets of the result (element lists, ascending).
    pub focal: Vec<Vec<usize>>,
    /// Their masses.
    pub mass: Vec<f64>,
    /// Conflict mass κ.
    pub conflict_mass: f64,
    /// Level of conflict K.
    pub conflict_level: ConflictLevel,
    /// Plausibility of every singleton.
    pub plausibility: Vec<f64>,
}

impl CombineReport {
    /// Whether the functions were in total conflict (the CLI warns and exits with status 0).
    pub fn is_total_conflict(&self) -> bool {
        self.conflict_level == ConflictLevel::Infinite
    }

    /// Whether the rule gave a result (every rule but Dempster's does on total conflict).
    pub fn has_result(&self) -> bool {
        !self.focal.is_empty()
    }
}

/// Bounds on one `combine`: the combination's [`WorkLimits`] (each input function and the inputs
/// together are held to them too) and the size of the output.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CombineLimits {
    /// Limits of the combination.
    pub work: WorkLimits,
    /// Elements the output may list: the frame (one plausibility each) plus the elements of the
    /// result's focal sets.
    pub output_elements: usize,
}

impl CombineLimits {
    /// The defaults of `evitrack combine`.
    pub const DEFAULT: CombineLimits = CombineLimits {
        work: WorkLimits::DEFAULT,
        output_elements: 1 << 25,
    };
}

impl Default for CombineLimits {
    fn default() -> Self {
        Self::DEFAULT
    }
}

fn bad(mass_function: usize, focal_set: Option<usize>, reason: String) -> EvidenceError {
    EvidenceError::BadInput {
        mass_function,
        focal_set,
        reason,
    }
}

/// Validate one raw function, naming the function and focal set at fault.
fn validate(
    frame: usize,
    index: usize,
    raw: &RawMassFunction,
) -> Result<MassFunction, EvidenceError> {
    if raw.focal.len() != raw.mass.len() {
        return Err(bad(
            index,
            None,
            format!(
                "has {} focal sets but {} masses: give exactly one mass per focal set",
                raw.focal.len(),
                raw.mass.len()
            ),
        ));
    }
    if raw.focal.is_empty() {
        return Err(bad(
            index,
            None,
            "has no focal set: give at least one".into(),
        ));
    }
    let mut pairs = Vec::with_capacity(raw.focal.len());
    let mut sum = 0.0;
    for (j, (set, &m)) in raw.focal.iter().zip(&raw.mass).enumerate() {
        if set.is_empty() {
            return Err(bad(
                index,
                Some(j),
                "is empty: a focal set needs at least one element".into(),
            ));
        }
        if let Some(&e) = set.iter().find(|&&e| e >= frame) {
            return Err(bad(
                index,
                Some(j),
                format!("element {e} is out of range: elements must be in 0..{frame}"),
            ));
        }
        if !m.is_finite() || m < 0.0 {
            return Err(bad(
                index,
                Some(j),
                format!("mass {m} is not a finite non-negative number"),
            ));
        }
        sum += m;
        pairs.push((Subset::from_indices(frame, set.iter().copied())?, m));
    }
    if (sum - 1.0).abs() > MASS_TOLERANCE {
        return Err(bad(
            index,
            None,
            format!("masses sum to {sum}, not 1 (tolerance {MASS_TOLERANCE}): rescale them"),
        ));
    }
    MassFunction::new(frame, pairs).map_err(|e| bad(index, None, e.to_string()))
}

/// Validate and combine a parsed input within [`CombineLimits::DEFAULT`].
///
/// # Errors
/// [`EvidenceError::EmptyFrame`], [`EvidenceError::FrameTooLarge`],
/// [`EvidenceError::NothingToCombine`], [`EvidenceError::BadInput`],
/// [`EvidenceError::WorkLimit`].
pub fn combine_input(input: &CombineInput) -> Result<CombineReport, EvidenceError> {
    combine_input_within(input, &CombineLimits::DEFAULT)
}

/// Validate and combine a parsed input within `limits`.
///
/// # Errors
/// As [`combine_input`].
pub fn combine_input_within(
    input: &CombineInput,
    limits: &CombineLimits,
) -> Result<CombineReport, EvidenceError> {
    if input.frame == 0 {
        return Err(EvidenceError::EmptyFrame);
    }
    super::subset::check_frame(input.frame)?;
    if input.mass_functions.is_empty() {
        return Err(EvidenceError::NothingToCombine);
    }
    // Checked before any set is built: one function of the input, and all of them together.
    let words = word_count(input.frame);
    let sets: Vec<usize> = input.mass_functions.iter().map(|f| f.focal.len()).collect();
    for &n in &sets {
        limits.work.check(n, words)?;
    }
    limits.work.check(sets.iter().sum(), words)?;
    let fs = input
        .mass_functions
        .iter()
        .enumerate()
        .map(|(i, raw)| validate(input.frame, i, raw))
        .collect::<Result<Vec<_>, _>>()?;
    let fs = match &input.reliability {
        Some(r) => discount_all(&fs, r.values())?,
        None => fs,
    };
    let c = combine_all_within(input.rule, &fs, &limits.work)?;
    let (conflict_mass, level) = (c.conflict_mass, c.conflict_level);
    // A result with nothing but ∅ (the conjunctive rule on total conflict) lists nothing.
    let result = c
        .mass
        .filter(|m| m.focal().any(|(s, x)| !s.is_empty() && x > 0.0));
    let Some(m) = result else {
        return Ok(CombineReport {
            focal: Vec::new(),
            mass: Vec::new(),
            conflict_mass,
            conflict_level: ConflictLevel::from_value(level),
            plausibility: vec![0.0; input.frame],
        });
    };
    let listed = m
        .focal()
        .map(|(s, _)| s.count())
        .fold(input.frame, usize::saturating_add);
    if listed > limits.output_elements {
        return Err(EvidenceError::WorkLimit {
            limit: WorkLimit::OutputElements,
            max: limits.output_elements,
        });
    }
    let mut rows: Vec<(Vec<usize>, f64)> = m
        .focal()
        .filter(|(s, _)| !s.is_empty())
        .map(|(s, x)| (s.to_vec(), x))
        .collect();
    rows.sort_by(|a, b| b.1.total_cmp(&a.1).then_with(|| a.0.cmp(&b.0)));
    let (focal, mass) = rows.into_iter().unzip();
    Ok(CombineReport {
        focal,
        mass,
        conflict_mass,
        conflict_level: ConflictLevel::from_value(level),
        plausibility: m.contour(),
    })
}

/// Parse, validate and combine the text of a `combine` input file.
///
/// # Errors
/// [`EvidenceError::Json`] (with line and column) for malformed JSON or unknown fields, and the
/// errors of [`combine_input`].
pub fn combine_json(text: &str) -> Result<CombineReport, EvidenceError> {
    combine_json_within(text, &CombineLimits::DEFAULT)
}

/// [`combine_json`] within `limits`.
///
/// # Errors
/// As [`combine_json`].
pub fn combine_json_within(
    text: &str,
    limits: &CombineLimits,
) -> Result<CombineReport, EvidenceError> {
    combine_input_within(&parse_input(text)?, limits)
}

/// Parse the text of a `combine` input file, without validating it.
///
/// # Errors
/// [`EvidenceError::Json`] (with line and column) for malformed JSON or unknown fields.
pub fn parse_input(text: &str) -> Result<CombineInput, EvidenceError> {
    serde_json::from_str(text).map_err(|e| EvidenceError::Json(e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_by_hand() {
        let text = r#"{"frame": 3, "rule": "dempster", "mass_functions": [
            {"focal": [[0], [0, 1]], "mass": [0.6, 0.4]},
            {"focal": [[1], [0, 1, 2]], "mass": [0.5, 0.5]}]}"#;
        let r = combine_json(text).unwrap();
        assert!((r.conflict_mass - 0.3).abs() < 1e-15);
        assert_eq!(r.focal, vec![vec![0], vec![0, 1], vec![1]]);
        assert!((r.mass[0] - 0.3 / 0.7).abs() < 1e-15);
        assert!((r.plausibility[0] - 0.5 / 0.7).abs() < 1e-15);
        assert!((r.plausibility[2]).abs() < 1e-15);
        assert!(!r.is_total_conflict());
        let json = serde_json::to_value(&r).unwrap();
        assert!(json["conflict_level"].is_number());
    }

    #[test]
    fn total_conflict_serialises_inf() {
        let text = r#"{"frame": 2, "rule": "dempster", "mass_functions": [
            {"focal": [[0]], "mass": [1.0]}, {"focal": [[1]], "mass": [1.0]}]}"#;
        let r = combine_json(text).unwrap();
        assert!(r.is_total_conflict());
        let json = serde_json::to_value(&r).unwrap();
        assert_eq!(json["conflict_level"], "inf");
        assert_eq!(json["focal"].as_array().map(Vec::len), Some(0));
        let back: CombineReport = serde_json::from_value(json).unwrap();
        assert_eq!(back, r);
        let conj = combine_json(&text.replace("dempster", "conjunctive")).unwrap();
        assert!(conj.is_total_conflict());
        assert_eq!(conj.conflict_mass, 1.0);
    }
}
