//! The dataset on disk: writing a folder and reading one back, checking every file.

use std::fs;
use std::path::Path;

use super::{
    safe_relative, Dataset, DatasetError, Frame, Manifest, Truth, Units, FORMAT_VERSION,
    MANIFEST_FILE, POSES_FILE,
};

/// Columns of `poses.csv`, in order.
const HEADER: [&str; 6] = ["file", "t", "x", "y", "theta1", "theta2"];

/// Wraps an I/O error with the path it concerns.
pub(super) fn io(path: &Path) -> impl FnOnce(std::io::Error) -> DatasetError + '_ {
    move |source| DatasetError::Io {
        path: path.to_path_buf(),
        source,
    }
}

impl Dataset {
    /// Writes the dataset into folder `dir` (created if needed; existing files are overwritten),
    /// each file atomically and the manifest last.
    pub fn write(&self, dir: impl AsRef<Path>) -> Result<(), DatasetError> {
        let dir = dir.as_ref();
        self.validate()?;
        fs::create_dir_all(dir).map_err(io(dir))?;
        for f in &self.frames {
            let path = dir.join(&f.file);
            if let Some(parent) = path.parent() {
                fs::create_dir_all(parent).map_err(io(parent))?;
            }
            let mut png = Vec::new();
            f.image
                .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
                .map_err(|e| DatasetError::Io {
                    path: path.clone(),
                    source: std::io::Error::other(e),
                })?;
            crate::atomic::write(&path, &png).map_err(io(&path))?;
        }
        let rows: Vec<(&str, f64, Option<Truth>)> = self
            .frames
            .iter()
            .map(|f| (f.file.as_str(), f.t, f.truth))
            .collect();
        let table = pose_table_text(&rows);
        let poses = dir.join(POSES_FILE);
        crate::atomic::write(&poses, table.as_bytes()).map_err(io(&poses))?;
        let manifest = dir.join(MANIFEST_FILE);
        let json = serde_json::to_string_pretty(&self.manifest)
            .map_err(|e| DatasetError::Invalid(format!("manifest does not serialise: {e}")))?;
        // Last: a folder with a manifest holds a whole dataset.
        crate::atomic::write(&manifest, (json + "\n").as_bytes()).map_err(io(&manifest))?;
        Ok(())
    }

    /// Reads and checks the dataset in folder `dir`: the manifest and its version, every row of
    /// `poses.csv`, and every frame (present, decodable, of the camera's size).
    pub fn read(dir: impl AsRef<Path>) -> Result<Dataset, DatasetError> {
        let dir = dir.as_ref();
        let manifest = read_manifest(&dir.join(MANIFEST_FILE))?;
        let poses = dir.join(POSES_FILE);
        let rows = read_poses(&poses)?;
        if rows.len() != manifest.frame_count {
            return Err(DatasetError::Manifest {
                path: dir.join(MANIFEST_FILE),
                message: format!(
                    "frame_count is {} but {POSES_FILE} lists {} frames; fix one of them",
                    manifest.frame_count,
                    rows.len()
                ),
            });
        }
        for row in &rows {
            if let Some(t) = row.truth {
                t.check(manifest.workspace.as_ref())
                    .map_err(|message| DatasetError::Row {
                        path: poses.clone(),
                        line: row.line,
                        message,
                    })?;
            }
        }
        let mut frames = Vec::with_capacity(rows.len());
        for row in rows {
            let path = dir.join(&row.file);
            let frame_err = |message: String| DatasetError::Frame {
                path: path.clone(),
                line: row.line,
                message,
            };
            if !path.is_file() {
                return Err(frame_err(
                    "frame file is missing; restore it or remove its row".into(),
                ));
            }
            let img = image::open(&path)
                .map_err(|e| frame_err(format!("cannot decode the image: {e}")))?;
            let image = match img {
                image::DynamicImage::ImageLuma8(g) => g,
                other => other.to_luma8(),
            };
            let c = &manifest.camera;
            if image.width() != c.width || image.height() != c.height {
                return Err(frame_err(format!(
                    "image is {}×{} but the manifest camera is {}×{}",
                    image.width(),
                    image.height(),
                    c.width,
                    c.height
                )));
            }
            frames.push(Frame {
                file: row.file,
                t: row.t,
                image,
                truth: row.truth,
            });
        }
        Ok(Dataset { manifest, frames })
    }
}

fn read_manifest(path: &Path) -> Result<Manifest, DatasetError> {
    let err = |message: String| DatasetError::Manifest {
        path: path.to_path_buf(),
        message,
    };
    let text = fs::read_to_string(path).map_err(io(path))?;
    let value: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| err(format!("not valid JSON: {e}")))?;
    match value.get("format_version").and_then(|v| v.as_u64()) {
        Some(v) if v == FORMAT_VERSION as u64 => {}
        Some(v) => {
            return Err(err(format!(
                "format_version {v} is not supported (this build reads version \
                 {FORMAT_VERSION}); convert the dataset or use a matching evitrack"
            )))
        }
        None => {
            return Err(err(format!(
                "missing or non-integer format_version (expected {FORMAT_VERSION})"
            )))
        }
    }
    let m: Manifest =
        serde_json::from_value(value).map_err(|e| err(format!("malformed manifest: {e}")))?;
    m.camera.check().map_err(err)?;
    if let Some(w) = &m.workspace {
        w.check().map_err(err)?;
    }
    if m.units != Units::default() {
        return Err(err(format!(
            "units {:?} are not supported: poses must be in mm, rad and s",
            m.units
        )));
    }
    Ok(m)
}

/// The text of `poses.csv` for rows (file, time, truth); the angle columns only when some row
/// has them (a real object has none).
pub(super) fn pose_table_text(rows: &[(&str, f64, Option<Truth>)]) -> String {
    let with_angles = rows.iter().any(|r| r.2.is_some_and(|t| t.angles.is_some()));
    let columns = if with_angles {
        &HEADER[..]
    } else {
        &HEADER[..4]
    };
    let mut table = columns.join(",") + "\n";
    for &(file, t, truth) in rows {
        // `{}` on f64 prints the shortest string that parses back to the same value.
        table.push_str(&format!("{file},{t}"));
        match truth {
            Some(p) => table.push_str(&format!(",{},{}", p.x, p.y)),
            None => table.push_str(",,"),
        }
        if with_angles {
            match truth.and_then(|p| p.angles) {
                Some([a, b]) => table.push_str(&format!(",{a},{b}")),
                None => table.push_str(",,"),
            }
        }
        table.push('\n');
    }
    table
}

pub(super) struct Row {
    pub(super) line: u64,
    pub(super) file: String,
    pub(super) t: f64,
    pub(super) truth: Option<Truth>,
}

/// The rows of a pose table, and each bad row's error (a bad row is left out of `rows`).
pub(super) struct PoseTable {
    pub(super) rows: Vec<Row>,
    pub(super) errors: Vec<DatasetError>,
    /// Data rows in the file, good and bad.
    pub(super) count: usize,
}

fn read_poses(path: &Path) -> Result<Vec<Row>, DatasetError> {
    let mut table = read_pose_table(path)?;
    match table.errors.is_empty() {
        true => Ok(table.rows),
        false => Err(table.errors.remove(0)),
    }
}

/// Reads `poses.csv` to the end, collecting every bad row's error instead of stopping at the
/// first (`dataset check` reports them all); an unreadable file or header is an error at once.
pub(super) fn read_pose_table(path: &Path) -> Result<PoseTable, DatasetError> {
    let file = fs::File::open(path).map_err(io(path))?;
    let mut rdr = csv::ReaderBuilder::new()
        .has_headers(true)
        .flexible(true)
        .trim(csv::Trim::All)
        .from_reader(file);
    let row_err = |line: u64, message: String| DatasetError::Row {
        path: path.to_path_buf(),
        line,
        message,
    };
    let header = rdr
        .headers()
        .map_err(|e| row_err(1, format!("unreadable header: {e}")))?
        .clone();
    let found: Vec<&str> = header.iter().collect();
    let columns: &[&str] = if found == HEADER {
        &HEADER
    } else if found == HEADER[..4] {
        &HEADER[..4]
    } else {
        return Err(row_err(
            1,
            format!(
                "header must be `{}` or `{}` (joint angles are optional), found `{}`",
                HEADER[..4].join(","),
                HEADER.join(","),
                found.join(",")
            ),
        ));
    };
    let mut table = PoseTable {
        rows: Vec::new(),
        errors: Vec::new(),
        count: 0,
    };
    let mut seen = std::collections::HashSet::new();
    let mut last_t = f64::NEG_INFINITY;
    for rec in rdr.records() {
        table.count += 1;
        let rec = match rec {
            Ok(rec) => rec,
            Err(e) => {
                let line = e.position().map(|p| p.line()).unwrap_or(0);
                table
                    .errors
                    .push(row_err(line, format!("unreadable row: {e}")));
                continue;
            }
        };
        let line = rec.position().map(|p| p.line()).unwrap_or(0);
        match parse_row(&rec, columns, &mut seen, &mut last_t) {
            Ok(row) => table.rows.push(Row { line, ..row }),
            Err(message) => table.errors.push(row_err(line, message)),
        }
    }
    Ok(table)
}

/// One data row of `poses.csv` (`line` left 0 for the caller), or what is wrong with it.
fn parse_row(
    rec: &csv::StringRecord,
    columns: &[&str],
    seen: &mut std::collections::HashSet<String>,
    last_t: &mut f64,
) -> Result<Row, String> {
    if rec.len() != columns.len() {
        return Err(format!(
            "expected {} fields ({}), found {}",
            columns.len(),
            columns.join(","),
            rec.len()
        ));
    }
    let file = rec[0].to_string();
    safe_relative(&file)?;
    if !seen.insert(file.clone()) {
        return Err(format!("frame {file:?} listed twice"));
    }
    let num = |k: usize| -> Result<f64, String> {
        let v: f64 = rec[k]
            .parse()
            .map_err(|_| format!("{} = {:?} is not a number", columns[k], &rec[k]))?;
        if !v.is_finite() {
            return Err(format!("{} = {v} must be finite", columns[k]));
        }
        Ok(v)
    };
    let t = num(1)?;
    if t < *last_t {
        return Err(format!(
            "time {t} s goes backwards (previous row {last_t} s); sort the rows"
        ));
    }
    *last_t = t;
    let filled = |range: std::ops::Range<usize>| range.filter(|&k| !rec[k].is_empty()).count();
    let angles = match filled(4..columns.len()) {
        0 => None,
        2 => Some([num(4)?, num(5)?]),
        _ => return Err("theta1 and theta2 must both be filled or both be empty".into()),
    };
    let truth = match filled(2..4) {
        0 if angles.is_none() => None,
        0 => return Err("joint angles without x, y: fill x and y, or empty the angles".into()),
        2 => Some(Truth {
            x: num(2)?,
            y: num(3)?,
            angles,
        }),
        _ => return Err("x and y must both be filled or both be empty".into()),
    };
    Ok(Row {
        line: 0,
        file,
        t,
        truth,
    })
}
