//! `dataset check`: every problem of a dataset folder at once (manifest fields, pose rows,
//! frames), where [`Dataset::read`](super::Dataset::read) stops at the first.

use std::path::Path;

use serde_json::{Map, Value};

use super::files::read_pose_table;
use super::{Rect, Units, FORMAT_VERSION, MANIFEST_FILE, POSES_FILE};

/// What `check_folder` found.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct CheckReport {
    /// Every problem, each naming its file (and line or field); empty when the folder is a
    /// dataset [`Dataset::read`](super::Dataset::read) accepts.
    pub problems: Vec<String>,
    /// Frames listed in `poses.csv` (rows read, good or bad).
    pub frames: usize,
    /// Rows with a ground-truth position.
    pub with_truth: usize,
}

/// The manifest's top-level keys, the required ones first.
const REQUIRED: [&str; 3] = ["format_version", "camera", "frame_count"];
const OPTIONAL: [&str; 5] = ["units", "workspace", "seed", "scenario", "source"];

/// Checks the dataset folder `dir` and reports every problem found, not only the first.
pub fn check_folder(dir: &Path) -> CheckReport {
    let mut report = CheckReport::default();
    let manifest_path = dir.join(MANIFEST_FILE);
    let mut problem = |text: String| report.problems.push(text);
    let manifest = match std::fs::read_to_string(&manifest_path) {
        Ok(text) => check_manifest(&text, &mut |m| {
            problem(format!("{}: {m}", manifest_path.display()))
        }),
        Err(e) => {
            problem(format!(
                "{}: cannot read it ({e}); `evitrack dataset init` writes one",
                manifest_path.display()
            ));
            Partial::default()
        }
    };
    let poses = dir.join(POSES_FILE);
    let table = match read_pose_table(&poses) {
        Ok(table) => table,
        Err(e) => {
            report.problems.push(e.to_string());
            return report;
        }
    };
    report.frames = table.count;
    report
        .problems
        .extend(table.errors.iter().map(|e| e.to_string()));
    if let Some(count) = manifest.frame_count {
        if count != table.count {
            report.problems.push(format!(
                "{}: frame_count is {count} but {POSES_FILE} lists {} frames; fix one of them",
                manifest_path.display(),
                table.count
            ));
        }
    }
    for row in &table.rows {
        let Some(truth) = row.truth else { continue };
        report.with_truth += 1;
        if let Err(message) = truth.check(manifest.workspace.as_ref()) {
            report
                .problems
                .push(format!("{} line {}: {message}", poses.display(), row.line));
        }
    }
    for row in &table.rows {
        let path = dir.join(&row.file);
        let at = format!(
            "{} (listed on line {} of {POSES_FILE})",
            path.display(),
            row.line
        );
        if !path.is_file() {
            report.problems.push(format!(
                "{at}: frame file is missing; restore it or remove its row"
            ));
            continue;
        }
        match image::image_dimensions(&path) {
            Err(e) => report
                .problems
                .push(format!("{at}: cannot decode the image: {e}")),
            Ok((w, h)) => {
                if let Some([cw, ch]) = manifest.size {
                    if (w, h) != (cw, ch) {
                        report.problems.push(format!(
                            "{at}: image is {w}×{h} but the manifest camera is {cw}×{ch}"
                        ));
                    }
                }
            }
        }
    }
    report
}

/// What could be read of a manifest, for the checks of the other files.
#[derive(Default)]
struct Partial {
    frame_count: Option<usize>,
    size: Option<[u32; 2]>,
    workspace: Option<Rect>,
}

/// Checks every field of the manifest `text`, calling `problem` for each thing wrong.
fn check_manifest(text: &str, problem: &mut dyn FnMut(String)) -> Partial {
    let mut partial = Partial::default();
    let value: Value = match serde_json::from_str(text) {
        Ok(v) => v,
        Err(e) => {
            problem(format!("not valid JSON: {e}"));
            return partial;
        }
    };
    let Some(object) = value.as_object() else {
        problem("must be a JSON object".into());
        return partial;
    };
    for key in REQUIRED {
        if !object.contains_key(key) {
            problem(format!("required field `{key}` is missing"));
        }
    }
    for key in object.keys() {
        if !REQUIRED.contains(&key.as_str()) && !OPTIONAL.contains(&key.as_str()) {
            problem(format!(
                "unknown field `{key}` (fields: {}, {})",
                REQUIRED.join(", "),
                OPTIONAL.join(", ")
            ));
        }
    }
    match object.get("format_version").map(Value::as_u64) {
        Some(Some(v)) if v == FORMAT_VERSION as u64 => {}
        Some(Some(v)) => problem(format!(
            "format_version {v} is not supported (this build reads version {FORMAT_VERSION})"
        )),
        Some(None) => problem(format!(
            "format_version must be the integer {FORMAT_VERSION}"
        )),
        None => {}
    }
    match object.get("frame_count").map(Value::as_u64) {
        Some(Some(n)) => partial.frame_count = usize::try_from(n).ok(),
        Some(None) => problem("frame_count must be a whole number ≥ 0".into()),
        None => {}
    }
    if let Some(camera) = object.get("camera") {
        partial.size = check_camera(camera, problem);
    }
    if let Some(units) = object.get("units") {
        match serde_json::from_value::<Units>(units.clone()) {
            Ok(u) if u == Units::default() => {}
            Ok(u) => problem(format!(
                "units {u:?} are not supported: poses must be in mm, rad and s"
            )),
            Err(e) => problem(format!("units: {e}")),
        }
    }
    match object.get("workspace") {
        None | Some(Value::Null) => {}
        Some(w) => match serde_json::from_value::<Rect>(w.clone()) {
            Ok(rect) => match rect.check() {
                Ok(()) => partial.workspace = Some(rect),
                Err(e) => problem(format!("workspace: {e}")),
            },
            Err(e) => problem(format!(
                "workspace: {e} (expected {{\"x_min\", \"x_max\", \"y_min\", \"y_max\"}} in mm)"
            )),
        },
    }
    match object.get("seed") {
        None | Some(Value::Null) => {}
        Some(s) if s.as_u64().is_some() => {}
        Some(s) => problem(format!("seed {s} must be a whole number ≥ 0 or null")),
    }
    for key in ["scenario", "source"] {
        if object.get(key).is_some_and(|v| !v.is_string()) {
            problem(format!("{key} must be a string"));
        }
    }
    partial
}

/// Checks each field of the manifest's `camera`; the image size when it is usable.
fn check_camera(camera: &Value, problem: &mut dyn FnMut(String)) -> Option<[u32; 2]> {
    let Some(object) = camera.as_object() else {
        problem("camera must be an object {width, height, mm_per_px, centre, polarity}".into());
        return None;
    };
    let known = ["width", "height", "mm_per_px", "centre", "polarity"];
    for key in object.keys().filter(|k| !known.contains(&k.as_str())) {
        problem(format!(
            "camera: unknown field `{key}` (fields: {})",
            known.join(", ")
        ));
    }
    let mut size = |key: &str| -> Option<u32> {
        match field(object, key, problem, "camera")?.as_u64() {
            Some(n) if n > 0 => u32::try_from(n).ok(),
            _ => {
                problem(format!("camera.{key} must be a whole number of pixels > 0"));
                None
            }
        }
    };
    let (width, height) = (size("width"), size("height"));
    if let Some(s) = field(object, "mm_per_px", problem, "camera") {
        if !s.as_f64().is_some_and(|s| s.is_finite() && s > 0.0) {
            problem(format!(
                "camera.mm_per_px = {s} must be a positive number (mm per pixel)"
            ));
        }
    }
    if let Some(c) = field(object, "centre", problem, "camera") {
        let pair = c.as_array().filter(|a| a.len() == 2);
        if !pair.is_some_and(|a| a.iter().all(|v| v.as_f64().is_some_and(f64::is_finite))) {
            problem(format!(
                "camera.centre = {c} must be [x, y]: the world point (mm) at the image centre"
            ));
        }
    }
    if let Some(p) = object.get("polarity") {
        if serde_json::from_value::<super::Polarity>(p.clone()).is_err() {
            problem(format!(
                "camera.polarity = {p} must be \"bright_on_dark\" or \"dark_on_bright\""
            ));
        }
    }
    Some([width?, height?])
}

/// The field `key` of `object`, or a problem saying it is missing.
fn field<'a>(
    object: &'a Map<String, Value>,
    key: &str,
    problem: &mut dyn FnMut(String),
    within: &str,
) -> Option<&'a Value> {
    let value = object.get(key);
    if value.is_none() {
        problem(format!("required field `{within}.{key}` is missing"));
    }
    value
}
