//! Combination of mass functions: the unnormalised conjunctive rule, Dempster's rule, the conflict
//! mass κ and the level of conflict K = ln(1/(1 − κ)).
//! The engine that does the work is [`super::engine`].

use super::engine::{frame_of, run, to_mass_function, Mode};
use super::limits::WorkLimits;
use super::mass::MassFunction;
use super::subset::word_count;
use super::EvidenceError;

/// Result of a combination rule (Dempster's, or any [`super::Rule`]).
#[derive(Clone, Debug, PartialEq)]
pub struct Combination {
    /// The combined function; `None` only when the rule has no result (Dempster's rule on total
    /// conflict, κ = 1).
    pub mass: Option<MassFunction>,
    /// Conflict mass κ: for Dempster's rule, the mass the unnormalised conjunctive combination
    /// puts on ∅ (each [`super::Rule`] states what it is for that rule).
    pub conflict_mass: f64,
    /// Level of conflict K = ln(1/(1 − κ)) ∈ [0, +∞]; `f64::INFINITY` on total conflict, never NaN.
    pub conflict_level: f64,
}

impl Combination {
    /// Whether the functions have no orthogonal sum.
    pub fn is_total_conflict(&self) -> bool {
        self.mass.is_none()
    }
}

/// K = ln(1/(1 − κ)) for a conflict mass κ: +∞ for κ ≥ 1 and for NaN (an unknown conflict counts
/// as total), 0 for κ ≤ 0. Never NaN.
pub fn level_of_conflict(kappa: f64) -> f64 {
    if kappa.is_nan() || kappa >= 1.0 {
        f64::INFINITY
    } else if kappa <= 0.0 {
        0.0
    } else {
        -(-kappa).ln_1p()
    }
}

/// Unnormalised conjunctive combination of two functions (conflict stays on ∅).
///
/// # Errors
/// [`EvidenceError::FrameMismatch`] when the frames differ.
pub fn conjunctive(a: &MassFunction, b: &MassFunction) -> Result<MassFunction, EvidenceError> {
    conjunctive_all([a, b])
}

/// Unnormalised conjunctive combination of any number of functions: Dempster's combination
/// scaled back by 1 − κ = e^(−K), with κ on ∅. The level K is exact (see [`dempster_all`]);
/// a focal set whose unnormalised mass is below the smallest f64 is left out.
///
/// # Errors
/// [`EvidenceError::NothingToCombine`], [`EvidenceError::FrameMismatch`],
/// [`EvidenceError::WorkLimit`] beyond [`WorkLimits::DEFAULT`].
pub fn conjunctive_all<'a, I: IntoIterator<Item = &'a MassFunction>>(
    fs: I,
) -> Result<MassFunction, EvidenceError> {
    conjunctive_all_within(fs, &WorkLimits::DEFAULT)
}

/// [`conjunctive_all`] within the given work limits.
///
/// # Errors
/// As [`conjunctive_all`], [`EvidenceError::WorkLimit`] beyond `limits`.
pub fn conjunctive_all_within<'a, I: IntoIterator<Item = &'a MassFunction>>(
    fs: I,
    limits: &WorkLimits,
) -> Result<MassFunction, EvidenceError> {
    let (n, fs) = frame_of(fs)?;
    let c = dempster_all_within(fs, limits)?;
    Ok(unnormalised(n, &c))
}

/// The conjunctive combination on a frame of `n` from Dempster's `c`: its function (none on total
/// conflict) scaled by e^(−K), and κ on ∅ (on the words, so no subset is built).
pub(super) fn unnormalised(n: usize, c: &Combination) -> MassFunction {
    let scale = (-c.conflict_level).exp();
    let kappa = -(-c.conflict_level).exp_m1();
    let w = word_count(n).max(1);
    let mut words = Vec::new();
    let mut mass = Vec::new();
    if let Some(k) = &c.mass {
        words.reserve((k.len() + 1) * w);
        mass.reserve(k.len() + 1);
        for (s, &m) in k.set_words().zip(k.masses()) {
            if m * scale > 0.0 {
                words.extend_from_slice(s);
                mass.push(m * scale);
            }
        }
    }
    if kappa > 0.0 {
        words.resize(words.len() + w, 0);
        mass.push(kappa);
    }
    MassFunction::from_words(n, words, mass)
}

/// Dempster's rule for two functions.
///
/// # Errors
/// [`EvidenceError::FrameMismatch`] when the frames differ. Total conflict is not an error: see
/// [`Combination::mass`].
pub fn dempster(a: &MassFunction, b: &MassFunction) -> Result<Combination, EvidenceError> {
    dempster_all([a, b])
}

/// Dempster's rule for any number of functions (sequentially, merging identical intersections
/// after each step). A single function is returned normalised (its mass on ∅, if any, counts as
/// conflict).
///
/// # Errors
/// [`EvidenceError::NothingToCombine`], [`EvidenceError::FrameMismatch`],
/// [`EvidenceError::WorkLimit`] beyond [`WorkLimits::DEFAULT`].
pub fn dempster_all<'a, I: IntoIterator<Item = &'a MassFunction>>(
    fs: I,
) -> Result<Combination, EvidenceError> {
    dempster_all_within(fs, &WorkLimits::DEFAULT)
}

/// [`dempster_all`] within the given work limits.
///
/// # Errors
/// As [`dempster_all`], [`EvidenceError::WorkLimit`] beyond `limits`.
pub fn dempster_all_within<'a, I: IntoIterator<Item = &'a MassFunction>>(
    fs: I,
    limits: &WorkLimits,
) -> Result<Combination, EvidenceError> {
    let (n, fs) = frame_of(fs)?;
    let done = run(n, &fs, (Mode::Dempster, limits), |out| {
        let level = out.level;
        Combination {
            mass: Some(to_mass_function(out, false)),
            conflict_mass: (-(-level).exp_m1()).clamp(0.0, 1.0),
            conflict_level: level,
        }
    })?;
    Ok(match done {
        Some(c) => c,
        None => Combination {
            mass: None,
            conflict_mass: 1.0,
            conflict_level: f64::INFINITY,
        },
    })
}

/// Level of conflict K of Dempster's combination of any number of functions, without building the
/// combined function (cheaper than [`dempster_all`] when only K is needed); +∞ on total conflict.
///
/// # Errors
/// [`EvidenceError::NothingToCombine`], [`EvidenceError::FrameMismatch`],
/// [`EvidenceError::WorkLimit`] beyond [`WorkLimits::DEFAULT`].
pub fn conflict_level_all<'a, I: IntoIterator<Item = &'a MassFunction>>(
    fs: I,
) -> Result<f64, EvidenceError> {
    let (n, fs) = frame_of(fs)?;
    Ok(run(n, &fs, (Mode::Dempster, &WorkLimits::DEFAULT), |out| {
        out.level
    })?
    .unwrap_or(f64::INFINITY))
}

/// Conflict mass κ between two functions, without building their combination.
///
/// # Errors
/// [`EvidenceError::FrameMismatch`] when the frames differ.
pub fn conflict(a: &MassFunction, b: &MassFunction) -> Result<f64, EvidenceError> {
    if a.frame_size() != b.frame_size() {
        return Err(EvidenceError::FrameMismatch {
            expected: a.frame_size(),
            found: b.frame_size(),
        });
    }
    let mut k = 0.0;
    for (x, mx) in a.focal() {
        for (y, my) in b.focal() {
            if !x.intersects(y) {
                k += mx * my;
            }
        }
    }
    Ok(k.clamp(0.0, 1.0))
}

/// Fast path: relative plausibility of the singletons of the orthogonal sum, computed as the
/// normalised product of the contour functions (exact under Dempster's rule), in O(Σ|A| + n) per
/// function. `Ok(None)` exactly when the functions are in total conflict.
///
/// # Errors
/// [`EvidenceError::NothingToCombine`], [`EvidenceError::FrameMismatch`].
pub fn contour_product<'a, I: IntoIterator<Item = &'a MassFunction>>(
    fs: I,
) -> Result<Option<Vec<f64>>, EvidenceError> {
    let (n, fs) = frame_of(fs)?;
    let mut p = vec![1.0; n];
    for f in fs {
        let c = f.contour();
        let mut max = 0.0f64;
        for (x, y) in p.iter_mut().zip(&c) {
            *x *= y;
            max = max.max(*x);
        }
        if max <= 0.0 {
            return Ok(None);
        }
        // Rescale so long products do not underflow.
        for x in &mut p {
            *x /= max;
        }
    }
    let s: f64 = p.iter().sum();
    for x in &mut p {
        *x /= s;
    }
    Ok(Some(p))
}

#[cfg(test)]
#[path = "combine_tests.rs"]
mod tests;
