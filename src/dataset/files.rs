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
fn io(path: &Path) -> impl FnOnce(std::io::Error) -> DatasetError + '_ {
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
        let mut table = String::from("file,t,x,y,theta1,theta2\n");
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
            // `{}` on f64 prints the shortest string that parses back to the same value.
            match f.truth {
                Some(t) => table.push_str(&format!(
                    "{},{},{},{},{},{}\n",
                    f.file, f.t, t.x, t.y, t.theta1, t.theta2
                )),
                None => table.push_str(&format!("{},{},,,,\n", f.file, f.t)),
            }
        }
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

struct Row {
    line: u64,
    file: String,
    t: f64,
    truth: Option<Truth>,
}

fn read_poses(path: &Path) -> Result<Vec<Row>, DatasetError> {
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
    if header.iter().collect::<Vec<_>>() != HEADER {
        return Err(row_err(
            1,
            format!(
                "header must be `{}`, found `{}`",
                HEADER.join(","),
                header.iter().collect::<Vec<_>>().join(",")
            ),
        ));
    }
    let mut rows = Vec::new();
    let mut seen = std::collections::HashSet::new();
    let mut last_t = f64::NEG_INFINITY;
    for rec in rdr.records() {
        let rec = rec.map_err(|e| {
            let line = e.position().map(|p| p.line()).unwrap_or(0);
            row_err(line, format!("unreadable row: {e}"))
        })?;
        let line = rec.position().map(|p| p.line()).unwrap_or(0);
        if rec.len() != HEADER.len() {
            return Err(row_err(
                line,
                format!(
                    "expected {} fields ({}), found {}",
                    HEADER.len(),
                    HEADER.join(","),
                    rec.len()
                ),
            ));
        }
        let file = rec[0].to_string();
        safe_relative(&file).map_err(|e| row_err(line, e))?;
        if !seen.insert(file.clone()) {
            return Err(row_err(line, format!("frame {file:?} listed twice")));
        }
        let num = |k: usize| -> Result<f64, DatasetError> {
            let v: f64 = rec[k].parse().map_err(|_| {
                row_err(
                    line,
                    format!("{} = {:?} is not a number", HEADER[k], &rec[k]),
                )
            })?;
            if !v.is_finite() {
                return Err(row_err(line, format!("{} = {v} must be finite", HEADER[k])));
            }
            Ok(v)
        };
        let t = num(1)?;
        if t < last_t {
            return Err(row_err(
                line,
                format!("time {t} s goes backwards (previous row {last_t} s); sort the rows"),
            ));
        }
        last_t = t;
        let empty = (2..6).filter(|&k| rec[k].is_empty()).count();
        let truth = match empty {
            4 => None,
            0 => Some(Truth {
                x: num(2)?,
                y: num(3)?,
                theta1: num(4)?,
                theta2: num(5)?,
            }),
            _ => {
                return Err(row_err(
                    line,
                    "x, y, theta1, theta2 must be all filled or all empty".into(),
                ))
            }
        };
        rows.push(Row {
            line,
            file,
            t,
            truth,
        });
    }
    Ok(rows)
}
