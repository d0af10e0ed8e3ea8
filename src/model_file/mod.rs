//! Model files: what every method's file shares, written and checked in one place.
//!
//! Every model file is self-contained JSON that opens with its stamp (`format_version`,
//! `method`): a method that wraps another's file writes a [`Stamp`], a fitted method a [`Header`]
//! (the stamp, `provenance`, `feature_config`, `feature_names`), the evidential file the stamp,
//! provenance and feature configuration (its names are its features'). A method's file struct
//! flattens the stamp or header first (`#[serde(flatten)]`), so the JSON keeps this field order.
//!
//! Reading checks the stamp before anything else ([`check_stamp`]), so an old or foreign file is
//! named as such rather than reported as a field-by-field mismatch; [`parse`] then refuses any
//! `null` outside the provenance and feature configuration (a number that was not finite when
//! written) and parses the typed fields. [`load`] names the path in every error.

use std::path::{Path, PathBuf};

use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

use crate::features::FeatureConfig;
use crate::planar::{check_position, Rect};

/// Failures of reading, checking or writing a model file.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ModelFileError {
    /// A model file has no `format_version` field.
    #[error("not a model file: no `format_version` field (expected {expected})")]
    MissingVersion {
        /// Version this reader handles.
        expected: u32,
    },
    /// A model file is of another estimation method.
    #[error("the model file is for method `{found}`, not `{expected}`")]
    WrongMethod {
        /// Method in the file.
        found: String,
        /// Method this reader handles.
        expected: &'static str,
    },
    /// A model file has a format version this build cannot read.
    #[error("model file format version {found} is not supported (this build reads version {supported}); retrain the model or use a matching evitrack")]
    UnsupportedVersion {
        /// Version in the file.
        found: String,
        /// Version this build reads.
        supported: u32,
    },
    /// A model file is not valid JSON or does not describe a valid model.
    #[error("corrupted model file: {0}")]
    Corrupted(String),
    /// Reading or writing a model file failed.
    #[error("model file {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// Loading a model file failed (the path, then the reason).
    #[error("model file {path}: {source}")]
    File {
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        source: Box<ModelFileError>,
    },
}

/// A corrupted-file error saying `what` is wrong.
pub fn corrupted(what: impl Into<String>) -> ModelFileError {
    ModelFileError::Corrupted(what.into())
}

/// What opens every model file: the format version and the method that wrote it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Stamp {
    /// Version of the method's file format.
    pub format_version: u32,
    /// The estimation method (`"evidential"`, `"knn"`, …).
    pub method: String,
}

impl Stamp {
    /// The stamp of a `method` file at format `version`.
    pub fn new(method: &str, version: u32) -> Self {
        Self {
            format_version: version,
            method: method.to_string(),
        }
    }
}

/// The header of a fitted method's file: its stamp, where the model came from and which
/// features it reads. (The stamp's fields are spelled out rather than flattened: serde leaves
/// the fields of a flattened struct inside a flattened struct for the outer file to refuse.)
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Header {
    /// Version of the method's file format.
    pub format_version: u32,
    /// The estimation method.
    pub method: String,
    /// Where the model came from.
    pub provenance: Provenance,
    /// The features' settings, when the model was trained on extracted features.
    pub feature_config: Option<FeatureConfig>,
    /// The features' names, in the order of a frame's values.
    pub feature_names: Vec<String>,
}

/// Where a model came from: the crate that trained it and the run that asked for it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Provenance {
    /// Version of evitrack that trained the model.
    pub crate_version: String,
    /// Scenario (variant) name, when a scenario run trained it.
    pub scenario: Option<String>,
    /// The run's master seed (or the training seed given to `train`).
    pub seed: u64,
    /// The workspace (mm) of the rig the model was trained on, when known: the model's poses are
    /// checked against it on load.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub workspace: Option<Rect>,
}

impl Provenance {
    /// This build's version, with the run's scenario name and seed; no workspace.
    pub fn new(scenario: Option<String>, seed: u64) -> Self {
        Self {
            crate_version: env!("CARGO_PKG_VERSION").to_string(),
            scenario,
            seed,
            workspace: None,
        }
    }

    /// With the workspace of the rig the training data comes from.
    pub fn with_workspace(self, workspace: Option<Rect>) -> Self {
        Self { workspace, ..self }
    }

    /// Refuses `poses` (the file's field `what`) that cannot be poses of the model's rig: the
    /// first one that [`check_position`] refuses against the declared workspace (and the
    /// workspace itself, when it is malformed).
    ///
    /// # Errors
    /// [`ModelFileError::Corrupted`] naming the pose.
    pub fn check_poses(&self, what: &str, poses: &[[f64; 2]]) -> Result<(), ModelFileError> {
        if let Some(w) = &self.workspace {
            w.check()
                .map_err(|e| corrupted(format!("provenance: {e}")))?;
        }
        for (i, &p) in poses.iter().enumerate() {
            check_position(p, self.workspace.as_ref())
                .map_err(|e| corrupted(format!("`{what}[{i}]`: {e}")))?;
        }
        Ok(())
    }
}

/// Checks the stamp of a parsed file: a JSON object whose `format_version` is `version` and
/// whose `method` is `method`.
///
/// # Errors
/// [`ModelFileError::MissingVersion`], [`ModelFileError::UnsupportedVersion`],
/// [`ModelFileError::WrongMethod`], or [`ModelFileError::Corrupted`] when there is no object or
/// no `method`.
pub fn check_stamp(
    value: &serde_json::Value,
    method: &'static str,
    version: u32,
) -> Result<(), ModelFileError> {
    let object = value
        .as_object()
        .ok_or_else(|| corrupted("the top level is not a JSON object"))?;
    // Another method's file is named as such before its version is judged.
    let found_method = object.get("method").and_then(|m| m.as_str());
    if let Some(other) = found_method.filter(|&m| m != method) {
        return Err(ModelFileError::WrongMethod {
            found: other.to_string(),
            expected: method,
        });
    }
    let found = object
        .get("format_version")
        .ok_or(ModelFileError::MissingVersion { expected: version })?;
    if found.as_u64() != Some(u64::from(version)) {
        return Err(ModelFileError::UnsupportedVersion {
            found: found.to_string(),
            supported: version,
        });
    }
    match found_method {
        Some(_) => Ok(()),
        None => Err(corrupted(
            "no `method` field (a string naming the estimation method)",
        )),
    }
}

/// Parses a model file of `method` at `version`: the stamp first, then any `null` outside the
/// provenance and feature configuration (a number that was not finite when written), then the
/// typed fields.
///
/// # Errors
/// As [`check_stamp`]; [`ModelFileError::Corrupted`] naming a `null` or the field serde refuses.
pub fn parse<T: DeserializeOwned>(
    text: &str,
    method: &'static str,
    version: u32,
) -> Result<T, ModelFileError> {
    parse_checked(text, method, version, true)
}

/// As [`parse`], for a format in which `null` stands for an absent value (the evidential file's
/// `validation_errors`): serde alone decides where it may stand.
///
/// # Errors
/// As [`parse`].
pub fn parse_with_nulls<T: DeserializeOwned>(
    text: &str,
    method: &'static str,
    version: u32,
) -> Result<T, ModelFileError> {
    parse_checked(text, method, version, false)
}

fn parse_checked<T: DeserializeOwned>(
    text: &str,
    method: &'static str,
    version: u32,
    refuse_nulls: bool,
) -> Result<T, ModelFileError> {
    match probe_stamp(text, refuse_nulls) {
        Some(stamp) => {
            check_stamp(&stamp, method, version)?;
            serde_json::from_str(text).map_err(|e| corrupted(e.to_string()))
        }
        None => parse_document(text, method, version, refuse_nulls),
    }
}

/// [`parse_checked`] through the whole document: the stamp, then the nulls, then the types.
fn parse_document<T: DeserializeOwned>(
    text: &str,
    method: &'static str,
    version: u32,
    refuse_nulls: bool,
) -> Result<T, ModelFileError> {
    let value: serde_json::Value =
        serde_json::from_str(text).map_err(|e| corrupted(e.to_string()))?;
    check_stamp(&value, method, version)?;
    if refuse_nulls {
        for (key, v) in value.as_object().into_iter().flatten() {
            if key != "provenance" && key != "feature_config" {
                if let Some(path) = find_null(v, key.clone()) {
                    return Err(corrupted(format!(
                        "`{path}` is null: it must be a finite number"
                    )));
                }
            }
        }
    }
    // Parsed again from the text so that errors carry line and column.
    serde_json::from_str(text).map_err(|e| corrupted(e.to_string()))
}

/// The two stamp fields of a file, each as the document holds it (`null` too) or absent.
#[derive(Deserialize)]
struct StampProbe {
    #[serde(default, deserialize_with = "present")]
    method: Option<serde_json::Value>,
    #[serde(default, deserialize_with = "present")]
    format_version: Option<serde_json::Value>,
}

/// A field that is present, whatever its value (`null` is `Some(Value::Null)`, as in the
/// document).
fn present<'de, D: serde::Deserializer<'de>>(
    field: D,
) -> Result<Option<serde_json::Value>, D::Error> {
    serde_json::Value::deserialize(field).map(Some)
}

/// The stamp fields of `text` as an object, read without building the rest of the file (a
/// model file's document would cost more than its typed parse), when the full path could not
/// decide otherwise: an object that the probe reads, without `null` anywhere when nulls are
/// refused (so there is none to refuse). Otherwise `None`, and [`parse_checked`] reads the
/// document, so every error is reported as it always was.
fn probe_stamp(text: &str, refuse_nulls: bool) -> Option<serde_json::Value> {
    if !text.trim_start().starts_with('{') || (refuse_nulls && null_outside_strings(text)) {
        return None;
    }
    let probe: StampProbe = serde_json::from_str(text).ok()?;
    let mut stamp = serde_json::Map::new();
    for (key, value) in [
        ("method", probe.method),
        ("format_version", probe.format_version),
    ] {
        if let Some(value) = value {
            stamp.insert(key.to_string(), value);
        }
    }
    Some(serde_json::Value::Object(stamp))
}

/// Whether `text` holds `null` outside its strings: in a well-formed document, whether it holds
/// a `null` value (a model file embedded as a string, as the temporal evidential tracker's, holds
/// the word in its text without holding the value).
fn null_outside_strings(text: &str) -> bool {
    // Past the last occurrence nothing can be one.
    let Some(last) = text.rfind("null") else {
        return false;
    };
    let bytes = text.as_bytes();
    let mut in_string = false;
    let mut k = 0;
    while k <= last {
        match bytes[k] {
            b'\\' if in_string => k += 1,
            b'"' => in_string = !in_string,
            b'n' if !in_string && bytes[k..].starts_with(b"null") => return true,
            _ => {}
        }
        k += 1;
    }
    false
}

/// The path of the first `null` in `value`.
fn find_null(value: &serde_json::Value, path: String) -> Option<String> {
    match value {
        serde_json::Value::Null => Some(path),
        serde_json::Value::Array(items) => items
            .iter()
            .enumerate()
            .find_map(|(i, v)| find_null(v, format!("{path}[{i}]"))),
        serde_json::Value::Object(map) => map
            .iter()
            .find_map(|(k, v)| find_null(v, format!("{path}.{k}"))),
        _ => None,
    }
}

/// A model file's text (pretty JSON).
///
/// # Errors
/// [`ModelFileError::Corrupted`] when serde cannot serialise it.
pub fn to_text<T: Serialize>(file: &T) -> Result<String, ModelFileError> {
    serde_json::to_string_pretty(file)
        .map_err(|e| corrupted(format!("cannot serialise the model: {e}")))
}

/// Reads a model file's text.
///
/// # Errors
/// [`ModelFileError::Io`] naming the path.
pub fn read_text(path: &Path) -> Result<String, ModelFileError> {
    std::fs::read_to_string(path).map_err(|source| ModelFileError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// Writes a model file's text whole ([`crate::atomic::write`]).
///
/// # Errors
/// [`ModelFileError::Io`] naming the path.
pub fn write_text(path: &Path, text: &str) -> Result<(), ModelFileError> {
    crate::atomic::write(path, text.as_bytes()).map_err(|source| ModelFileError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// Reads a model file and parses it with `from_json`, naming the path in errors.
///
/// # Errors
/// [`ModelFileError::Io`] when it cannot be read; [`ModelFileError::File`] with the path and
/// what `from_json` refused otherwise.
pub fn load<T, E: Into<ModelFileError>>(
    path: &Path,
    from_json: impl FnOnce(&str) -> Result<T, E>,
) -> Result<T, ModelFileError> {
    let text = read_text(path)?;
    parse_at(path, &text, from_json)
}

/// Parses a model file's `text` read from `path` with `from_json`, naming the path in errors.
///
/// # Errors
/// [`ModelFileError::File`] with the path and what `from_json` refused.
pub fn parse_at<T, E: Into<ModelFileError>>(
    path: &Path,
    text: &str,
    from_json: impl FnOnce(&str) -> Result<T, E>,
) -> Result<T, ModelFileError> {
    from_json(text).map_err(|e| ModelFileError::File {
        path: path.to_path_buf(),
        source: Box::new(e.into()),
    })
}

/// Checks that every number of a fitted state is finite, naming the field otherwise.
///
/// # Errors
/// [`ModelFileError::Corrupted`] naming the first value that is not finite.
pub fn check_finite(field: &str, values: &[f64]) -> Result<(), ModelFileError> {
    match values.iter().position(|v| !v.is_finite()) {
        Some(i) => Err(corrupted(format!("`{field}[{i}]` is not finite"))),
        None => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, PartialEq, Deserialize)]
    #[serde(deny_unknown_fields)]
    struct File {
        format_version: u32,
        method: String,
        value: f64,
    }

    #[test]
    fn the_stamp_probe_decides_as_the_whole_document() {
        let texts = [
            r#"{"format_version": 3, "method": "m", "value": 1.5}"#,
            r#"  {"method": "m", "value": 1.5, "format_version": 3}"#,
            r#"{"format_version": 3, "method": "other", "value": 1.5}"#,
            r#"{"method": "m", "value": 1.5}"#,
            r#"{"format_version": "3", "method": "m", "value": 1.5}"#,
            r#"{"format_version": 4, "method": "m", "value": 1.5}"#,
            r#"{"format_version": 3, "value": 1.5}"#,
            r#"{"format_version": 3, "method": 7, "value": 1.5}"#,
            r#"{"format_version": 3, "method": "m", "value": "x"}"#,
            r#"{"format_version": 3, "method": "m", "value": 1.5, "extra": [1, {"a": 2}]}"#,
            r#"{"format_version": 3, "method": "m", "value": 1."#,
            r#"{"format_version": 3, "method": "m", "method": "m", "value": 1.5}"#,
            r#"{"format_version": 3, "method": "m", "value": null}"#,
            r#"{"format_version": null, "method": "m", "value": 1.5}"#,
            r#"{"format_version": 3, "method": null, "value": 1.5}"#,
            // The word in a string is not a null: read as the document reads it.
            r#"{"format_version": 3, "method": "null", "value": 1.5}"#,
            r#"{"format_version": 3, "method": "m", "value": 1.5, "note": "a \"null\" \\"}"#,
            r#"{"format_version": 3, "method": "m", "note": "\\", "value": null}"#,
            r#"{"format_version": 3, "method": "m", "value": 1.5, "note": "null}"#,
            r#"[3, "m"]"#,
            "",
        ];
        let (mut probed, mut probed_with_nulls) = (0, 0);
        for text in texts {
            probed += usize::from(probe_stamp(text, true).is_some());
            probed_with_nulls += usize::from(probe_stamp(text, false).is_some());
            for refuse in [true, false] {
                let fast = parse_checked::<File>(text, "m", 3, refuse).map_err(|e| e.to_string());
                let whole = parse_document::<File>(text, "m", 3, refuse).map_err(|e| e.to_string());
                assert_eq!(fast, whole, "{text}");
            }
        }
        // The well-formed objects without null took the probe.
        assert!(probed >= 11, "{probed}");
        // Where nulls are taken, the objects with one took it too.
        assert!(probed_with_nulls >= probed + 3, "{probed_with_nulls}");
        assert!(parse::<File>(texts[0], "m", 3).is_ok());
    }

    #[test]
    fn only_a_null_outside_strings_counts() {
        assert!(!null_outside_strings(r#"{"a": "null", "b": "x\"null\""}"#));
        assert!(null_outside_strings(r#"{"a": "\\", "b": null}"#));
        assert!(null_outside_strings(r#"{"a": "null", "b": [1, null]}"#));
        assert!(!null_outside_strings(r#"{"a": 1}"#));
        // An embedded file with nulls of its own, as the temporal tracker writes it.
        let inner = r#"{"feature_config": null, "x": [null]}"#;
        let outer = serde_json::json!({ "method": "m", "inner": inner }).to_string();
        assert!(!null_outside_strings(&outer), "{outer}");
    }
}
