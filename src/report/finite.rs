//! One rule for every number a run's output files hold (`frames.csv`, `samples.csv`, `track`'s
//! CSV, `sweep.csv`): finite, except the `inf` the README documents for a level of conflict, a
//! detection score and a conflict threshold. NaN and −∞ are never written: they are errors,
//! naming the number, instead of a file that looks finished.

use super::ReportError;

/// A number as an output file writes it; `what` names it in the error.
///
/// # Errors
/// [`ReportError::NonFinite`] for NaN and ±∞.
pub fn number(what: &str, value: f64) -> Result<String, ReportError> {
    if value.is_finite() {
        Ok(value.to_string())
    } else {
        Err(non_finite(what, value))
    }
}

/// A level of conflict, a detection score or a threshold: +∞ is a value (total conflict, or a
/// score beyond the largest double), written `inf` as `combine` writes it.
///
/// # Errors
/// [`ReportError::NonFinite`] for NaN and −∞.
pub fn level(what: &str, value: f64) -> Result<String, ReportError> {
    if value == f64::INFINITY {
        Ok("inf".into())
    } else {
        number(what, value)
    }
}

/// [`number`] of an optional value; an empty cell without one.
///
/// # Errors
/// As [`number`].
pub fn cell(what: &str, value: Option<f64>) -> Result<String, ReportError> {
    value.map_or(Ok(String::new()), |v| number(what, v))
}

/// [`level`] of an optional value; an empty cell without one.
///
/// # Errors
/// As [`level`].
pub fn level_cell(what: &str, value: Option<f64>) -> Result<String, ReportError> {
    value.map_or(Ok(String::new()), |v| level(what, v))
}

fn non_finite(what: &str, value: f64) -> ReportError {
    ReportError::NonFinite {
        what: what.to_string(),
        value,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_a_level_may_be_infinite_and_nothing_nan() {
        assert_eq!(number("x", 1.5).unwrap(), "1.5");
        assert_eq!(level("k", f64::INFINITY).unwrap(), "inf");
        assert_eq!(level_cell("k", None).unwrap(), "");
        for v in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
            let error = cell("frame 3 error", Some(v)).unwrap_err().to_string();
            assert!(error.contains("frame 3 error"), "{error}");
        }
        for v in [f64::NAN, f64::NEG_INFINITY] {
            assert!(level("k", v).is_err());
        }
    }
}
