//! Settings of a feature program written in any language: `[[features.external]]` in a scenario,
//! `--feature-program FILE.toml` on the command line. Only the settings live here (this room sees
//! images, not folders); [`crate::external`] writes the frames, runs the program and reads its
//! values.

use serde::{Deserialize, Serialize};

use super::FeatureError;

/// Whether a program may leave a value empty (a missing feature, as a built-in one can be).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MissingValues {
    /// An empty cell (or `NA`) is an error naming the row and column (default).
    #[default]
    Error,
    /// An empty cell (or `NA`) is a missing value.
    Allowed,
}

/// One external feature program and the values it returns.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExternalFeatureConfig {
    /// The program and its arguments; the dataset folder's path is appended as the last one.
    /// Looked up on `PATH`; a relative path is taken from the current folder.
    pub command: Vec<String>,
    /// Names of the values it writes, in the order they join the feature vector.
    pub values: Vec<String>,
    /// Whether a value may be missing (default: an error).
    #[serde(default)]
    pub missing: MissingValues,
    /// Seconds the program may run on one dataset folder before it is stopped (default 120).
    #[serde(default = "default_timeout")]
    pub timeout_seconds: f64,
}

fn default_timeout() -> f64 {
    120.0
}

/// The longest a program may be given on one folder: a day.
pub const MAX_TIMEOUT_SECONDS: f64 = 86_400.0;

impl ExternalFeatureConfig {
    /// The program as errors name it: its command line.
    pub fn label(&self) -> String {
        self.command.join(" ")
    }

    /// Checks the command, the value names and the timeout.
    ///
    /// # Errors
    /// [`FeatureError::BadProgram`] naming the program and what to fix.
    pub fn check(&self) -> Result<(), FeatureError> {
        let bad = |reason: String| FeatureError::BadProgram {
            program: self.label(),
            reason,
        };
        if self.command.first().is_none_or(|c| c.trim().is_empty()) {
            return Err(bad(
                "`command` is empty: give the program and its arguments, e.g. \
                 [\"python3\", \"centroid.py\"]"
                    .into(),
            ));
        }
        if self.values.is_empty() {
            return Err(bad("`values` is empty: name every value it writes".into()));
        }
        for name in &self.values {
            let fine = !name.is_empty()
                && name != "frame"
                && name
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || "_-.".contains(c));
            if !fine {
                return Err(bad(format!(
                    "value name {name:?} must be letters, digits, `_`, `-` or `.`, and not `frame`"
                )));
            }
        }
        crate::range::within(self.timeout_seconds, 0.001..=MAX_TIMEOUT_SECONDS)
            .map_err(|e| bad(format!("timeout_seconds {e}")))?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn program(text: &str) -> Result<ExternalFeatureConfig, String> {
        toml::from_str::<ExternalFeatureConfig>(text).map_err(|e| e.to_string())
    }

    #[test]
    fn defaults_and_checks() {
        let p = program("command = [\"prog\", \"-v\"]\nvalues = [\"cx\", \"cy\"]\n").unwrap();
        assert_eq!(p.missing, MissingValues::Error);
        assert_eq!(p.timeout_seconds, 120.0);
        assert_eq!(p.label(), "prog -v");
        assert!(p.check().is_ok());
        for (field, expected) in [
            ("command = []\nvalues = [\"a\"]", "`command` is empty"),
            ("command = [\"p\"]\nvalues = []", "`values` is empty"),
            (
                "command = [\"p\"]\nvalues = [\"a,b\"]",
                "value name \"a,b\"",
            ),
            ("command = [\"p\"]\nvalues = [\"frame\"]", "not `frame`"),
            (
                "command = [\"p\"]\nvalues = [\"a\"]\ntimeout_seconds = 0",
                "timeout_seconds 0 is outside",
            ),
        ] {
            let message = program(field).unwrap().check().unwrap_err().to_string();
            assert!(message.contains(expected), "{field}: {message}");
        }
        assert!(program("command = [\"p\"]\nvalues = [\"a\"]\ntimeout = 3").is_err());
        let allowed = program("command = [\"p\"]\nvalues = [\"a\"]\nmissing = \"allowed\"");
        assert_eq!(allowed.unwrap().missing, MissingValues::Allowed);
    }
}
