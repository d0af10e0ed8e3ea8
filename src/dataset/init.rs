//! `dataset init`: a folder of PNG frames (and optionally a CSV of their positions) made into a
//! dataset by writing its `poses.csv` and `manifest.json`; the frames are left untouched.

use std::collections::HashMap;
use std::fs;
use std::path::Path;

use super::files::{io, pose_table_text};
use super::{
    CameraGeometry, Dataset, DatasetError, Manifest, Polarity, Rect, Truth, Units, FORMAT_VERSION,
    MANIFEST_FILE, POSES_FILE,
};

/// What a folder of frames cannot say about itself; each has a default.
#[derive(Debug, Clone, PartialEq)]
pub struct InitOptions {
    /// Pixel size (mm).
    pub mm_per_px: f64,
    /// World point (mm) at the image centre.
    pub centre: [f64; 2],
    /// Which way round the scene is drawn.
    pub polarity: Polarity,
    /// The workspace (mm), when known: poses are then held to it.
    pub workspace: Option<Rect>,
    /// Frames per second, for the times of a pose CSV without a `t` column (or without a CSV).
    pub fps: f64,
    /// The manifest's `scenario` (a name for the recording).
    pub name: String,
    /// The manifest's `source` (free-form provenance).
    pub source: String,
}

impl Default for InitOptions {
    /// The simulated rig's camera (0.2 mm per pixel, centred on the default workspace, a bright
    /// body on a dark background) at 10 frames/s, without a workspace.
    fn default() -> Self {
        Self {
            mm_per_px: 0.2,
            centre: [0.0, 47.5],
            polarity: Polarity::BrightOnDark,
            workspace: None,
            fps: 10.0,
            name: String::new(),
            source: "evitrack dataset init".into(),
        }
    }
}

/// The PNG files directly in `dir`, by file name in byte order (`00010.png` after `00009.png`;
/// number frames with leading zeros).
pub fn png_files(dir: &Path) -> Result<Vec<String>, DatasetError> {
    let mut names = Vec::new();
    for entry in fs::read_dir(dir).map_err(io(dir))? {
        let entry = entry.map_err(io(dir))?;
        let name = entry.file_name().to_string_lossy().into_owned();
        let is_png = Path::new(&name)
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("png"));
        if is_png && entry.path().is_file() {
            names.push(name);
        }
    }
    names.sort();
    Ok(names)
}

/// Writes `poses.csv` and `manifest.json` for the PNG frames in `dir` (all of one size, which
/// becomes the camera's), with positions from the CSV `poses` when given, then reads the
/// dataset back whole. Refuses to replace an existing manifest or pose table unless `force`.
pub fn init_folder(
    dir: &Path,
    options: &InitOptions,
    poses: Option<&Path>,
    force: bool,
) -> Result<Dataset, DatasetError> {
    let invalid = |message: String| DatasetError::Folder {
        path: dir.to_path_buf(),
        message,
    };
    if !(options.fps.is_finite() && options.fps > 0.0) {
        return Err(invalid(format!("fps = {} must be positive", options.fps)));
    }
    let manifest_path = dir.join(MANIFEST_FILE);
    let table_path = dir.join(POSES_FILE);
    if !force {
        for existing in [&manifest_path, &table_path] {
            // A pose CSV named poses.csv in the folder is the input, read before it is replaced.
            let is_input = poses.is_some_and(|p| same_file(p, existing));
            if existing.exists() && !is_input {
                return Err(invalid(format!(
                    "{} already exists: pass --force to replace it",
                    existing.display()
                )));
            }
        }
    }
    let files = png_files(dir)?;
    if files.is_empty() {
        return Err(invalid(
            "holds no PNG files: put the frames (8-bit grey or colour PNG) directly in it".into(),
        ));
    }
    let size = common_size(dir, &files)?;
    let truths = match poses {
        Some(path) => read_positions(path, &files, options.fps)?,
        None => (0..files.len())
            .map(|k| (k as f64 / options.fps, None))
            .collect(),
    };
    let rows: Vec<(&str, f64, Option<Truth>)> = files
        .iter()
        .zip(&truths)
        .map(|(f, &(t, truth))| (f.as_str(), t, truth))
        .collect();
    let manifest = Manifest {
        format_version: FORMAT_VERSION,
        camera: CameraGeometry {
            width: size[0],
            height: size[1],
            mm_per_px: options.mm_per_px,
            centre: options.centre,
            polarity: options.polarity,
        },
        units: Units::default(),
        workspace: options.workspace,
        seed: None,
        scenario: options.name.clone(),
        source: options.source.clone(),
        frame_count: files.len(),
    };
    manifest.camera.check().map_err(&invalid)?;
    if let Some(w) = &manifest.workspace {
        w.check().map_err(|e| invalid(format!("workspace: {e}")))?;
    }
    for (file, _, truth) in &rows {
        if let Some(t) = truth {
            t.check(manifest.workspace.as_ref())
                .map_err(|e| invalid(format!("the pose of {file}: {e}")))?;
        }
    }
    crate::atomic::write(&table_path, pose_table_text(&rows).as_bytes())
        .map_err(io(&table_path))?;
    let json = serde_json::to_string_pretty(&manifest)
        .map_err(|e| DatasetError::Invalid(format!("manifest does not serialise: {e}")))?;
    crate::atomic::write(&manifest_path, (json + "\n").as_bytes()).map_err(io(&manifest_path))?;
    Dataset::read(dir)
}

fn same_file(a: &Path, b: &Path) -> bool {
    matches!((a.canonicalize(), b.canonicalize()), (Ok(a), Ok(b)) if a == b)
}

/// The one size of every frame; frames of another size than the first are all named.
fn common_size(dir: &Path, files: &[String]) -> Result<[u32; 2], DatasetError> {
    let mut sizes = Vec::with_capacity(files.len());
    for file in files {
        let path = dir.join(file);
        let (w, h) = image::image_dimensions(&path).map_err(|e| DatasetError::Folder {
            path: path.clone(),
            message: format!("cannot read the image: {e}"),
        })?;
        sizes.push([w, h]);
    }
    let first = sizes[0];
    let odd: Vec<String> = files
        .iter()
        .zip(&sizes)
        .filter(|(_, s)| **s != first)
        .map(|(f, s)| format!("{f} is {}×{}", s[0], s[1]))
        .collect();
    if !odd.is_empty() {
        return Err(DatasetError::Folder {
            path: dir.to_path_buf(),
            message: format!(
                "every frame must have one size; {} is {}×{} but {}",
                files[0],
                first[0],
                first[1],
                odd.join(", ")
            ),
        });
    }
    Ok(first)
}

/// Time and position of each frame from a CSV with a header naming its columns: `x`, `y`
/// (mm), optionally `t` (s; else frame k is at k / fps) and `file` (the frame's name; else rows
/// are the frames in file-name order). An empty `x, y` leaves the frame without truth.
fn read_positions(
    path: &Path,
    files: &[String],
    fps: f64,
) -> Result<Vec<(f64, Option<Truth>)>, DatasetError> {
    let row_err = |line: u64, message: String| DatasetError::Row {
        path: path.to_path_buf(),
        line,
        message,
    };
    let file = fs::File::open(path).map_err(io(path))?;
    let mut rdr = csv::ReaderBuilder::new()
        .trim(csv::Trim::All)
        .from_reader(file);
    let header = rdr
        .headers()
        .map_err(|e| row_err(1, format!("unreadable header: {e}")))?
        .clone();
    let column = |name: &str| header.iter().position(|h| h == name);
    let known = ["file", "t", "x", "y"];
    if let Some(other) = header.iter().find(|h| !known.contains(h)) {
        return Err(row_err(
            1,
            format!("unknown column `{other}`: the columns are x, y and optionally t and file"),
        ));
    }
    let (Some(x), Some(y)) = (column("x"), column("y")) else {
        return Err(row_err(
            1,
            "the header must name columns `x` and `y` (and optionally `t` and `file`)".into(),
        ));
    };
    let (t_col, file_col) = (column("t"), column("file"));
    let mut by_frame: Vec<Option<(f64, Option<Truth>)>> = vec![None; files.len()];
    let index: HashMap<&str, usize> = files
        .iter()
        .enumerate()
        .map(|(k, f)| (f.as_str(), k))
        .collect();
    for (count, rec) in rdr.records().enumerate() {
        let rec = rec.map_err(|e| {
            let line = e.position().map_or(0, |p| p.line());
            row_err(line, format!("unreadable row: {e}"))
        })?;
        let line = rec.position().map_or(0, |p| p.line());
        let k = match file_col {
            Some(c) => *index.get(&rec[c]).ok_or_else(|| {
                row_err(line, format!("no PNG named {:?} in the folder", &rec[c]))
            })?,
            None => count,
        };
        if k >= files.len() {
            return Err(row_err(
                line,
                format!(
                    "more rows than the folder's {} PNG files (rows are the frames in file-name \
                     order; add a `file` column to name them)",
                    files.len()
                ),
            ));
        }
        if by_frame[k].is_some() {
            return Err(row_err(line, format!("frame {} listed twice", files[k])));
        }
        let num = |c: usize, name: &str| -> Result<Option<f64>, DatasetError> {
            if rec[c].is_empty() {
                return Ok(None);
            }
            match rec[c].parse::<f64>() {
                Ok(v) if v.is_finite() => Ok(Some(v)),
                _ => Err(row_err(
                    line,
                    format!("{name} = {:?} is not a finite number", &rec[c]),
                )),
            }
        };
        let t = match t_col {
            Some(c) => num(c, "t")?
                .ok_or_else(|| row_err(line, "t is empty: give every frame its time".into()))?,
            None => k as f64 / fps,
        };
        let truth = match (num(x, "x")?, num(y, "y")?) {
            (Some(x), Some(y)) => Some(Truth { x, y, angles: None }),
            (None, None) => None,
            _ => {
                return Err(row_err(
                    line,
                    "x and y must both be filled or both empty".into(),
                ))
            }
        };
        by_frame[k] = Some((t, truth));
    }
    let missing: Vec<&str> = files
        .iter()
        .zip(&by_frame)
        .filter(|(_, r)| r.is_none())
        .map(|(f, _)| f.as_str())
        .collect();
    if !missing.is_empty() {
        return Err(DatasetError::Folder {
            path: path.to_path_buf(),
            message: format!(
                "{} frame(s) have no row: {} (leave x and y empty for a frame without a pose)",
                missing.len(),
                shorten(&missing)
            ),
        });
    }
    let rows: Vec<(f64, Option<Truth>)> = by_frame.into_iter().flatten().collect();
    if let Some(k) = (1..rows.len()).find(|&k| rows[k].0 < rows[k - 1].0) {
        return Err(DatasetError::Folder {
            path: path.to_path_buf(),
            message: format!(
                "time goes backwards at {} ({} s after {} s): frames are in file-name order, \
                 so name them in time order",
                files[k],
                rows[k].0,
                rows[k - 1].0
            ),
        });
    }
    Ok(rows)
}

/// At most five names, then how many more.
fn shorten(names: &[&str]) -> String {
    match names.len() {
        0..=5 => names.join(", "),
        n => format!("{}, … and {} more", names[..5].join(", "), n - 5),
    }
}
