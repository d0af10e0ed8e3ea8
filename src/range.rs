//! Ranges of numeric settings. Every setting that decides how long or how big a run is
//! (iterations, steps, samples, variants) or that has a physical meaning (noise in grey levels)
//! has one, so that a typo is refused before anything runs instead of running for hours or
//! reporting a plausible number from an absurd setting. README.md lists them ("Limits").

use std::fmt::Display;
use std::ops::RangeInclusive;

/// A sentence naming `value` and `range` when `value` lies outside it (NaN always does).
///
/// # Errors
/// The sentence, for the caller to attach to the setting's name.
pub fn within<T: PartialOrd + Display>(value: T, range: RangeInclusive<T>) -> Result<(), String> {
    if range.contains(&value) {
        Ok(())
    } else {
        Err(format!(
            "{value} is outside its range {}..={}",
            range.start(),
            range.end()
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::within;

    #[test]
    fn ends_are_inside_and_nan_is_outside() {
        assert!(within(1, 1..=100).is_ok());
        assert!(within(100, 1..=100).is_ok());
        assert_eq!(
            within(0, 1..=100).unwrap_err(),
            "0 is outside its range 1..=100"
        );
        assert!(within(f64::NAN, 0.0..=255.0).is_err());
        assert!(within(1e308, 0.0..=255.0).is_err());
    }
}
