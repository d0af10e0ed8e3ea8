//! Features from programs in any language (`[[features.external]]`): the frames of a motion are
//! written as a dataset folder without ground truth, each program runs once on it and writes one
//! CSV row per frame, checked (`table`), and its output is cached by its and the frames'
//! content (`cache`). The values follow the built-in ones in every row, in declared order; an
//! empty cell is a missing value, as a built-in feature's `None`.
//!
//! This room sits between `dataset` (whose writer it uses) and the harness (`experiment`, the
//! command line), which call [`extract`] or [`fill`] wherever features are computed.

mod cache;
mod process;
mod table;

pub use cache::{cache_dir, file_digest, program_digest};

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

use crate::dataset::{Dataset, DatasetError, Frame};
use crate::features::{FeatureRows, FeatureSet};

/// Why a feature program's values could not be had. Each names the program by its command line.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ExternalError {
    /// The program could not be started (or waited for).
    #[error(
        "feature program `{program}` could not start: {source} (the program is looked up on \
         PATH; a relative path is taken from the current folder)"
    )]
    Start {
        /// Its command line.
        program: String,
        /// The system's error.
        source: std::io::Error,
    },
    /// The program exited with a failure.
    #[error("feature program `{program}` failed ({status}); the end of its stderr:\n{stderr}")]
    Failed {
        /// Its command line.
        program: String,
        /// How it ended.
        status: String,
        /// The last lines it wrote to stderr.
        stderr: String,
    },
    /// The program ran past its time limit and was stopped.
    #[error(
        "feature program `{program}` was still running after {seconds} s and was stopped: \
         raise its `timeout_seconds` or make it faster"
    )]
    Timeout {
        /// Its command line.
        program: String,
        /// The limit.
        seconds: f64,
    },
    /// The header row is not `frame` and the declared value names.
    #[error("feature program `{program}`, line 1 (the header): {message}")]
    Header {
        /// Its command line.
        program: String,
        /// What is wrong.
        message: String,
    },
    /// A row is wrong: its frame, its field count or one of its values.
    #[error(
        "feature program `{program}`, line {line} (frame {frame}){}: {message}",
        column.as_ref().map(|c| format!(", column `{c}`")).unwrap_or_default()
    )]
    Row {
        /// Its command line.
        program: String,
        /// 1-based line of its output.
        line: u64,
        /// The frame the row is for (0-based).
        frame: usize,
        /// The column at fault, when one is.
        column: Option<String>,
        /// What is wrong.
        message: String,
    },
    /// The program wrote more or fewer rows than there are frames.
    #[error(
        "feature program `{program}` wrote {got} rows for {expected} frames: write one row per \
         frame, in order, after the header"
    )]
    RowCount {
        /// Its command line.
        program: String,
        /// The number of frames.
        expected: usize,
        /// The number of rows.
        got: usize,
    },
    /// The frames could not be written for the program.
    #[error("writing the frames for feature program `{program}`: {source}")]
    Frames {
        /// Its command line.
        program: String,
        /// The dataset writer's error.
        source: DatasetError,
    },
    /// The rows handed to [`fill`] are not one per frame, each as long as the feature set.
    #[error("{rows} feature rows for {frames} frames (each needs {width} values): extract them with the same feature set")]
    Rows {
        /// Rows given.
        rows: usize,
        /// Frames of the dataset.
        frames: usize,
        /// Values of the feature set.
        width: usize,
    },
    /// A file could not be read.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The system's error.
        source: std::io::Error,
    },
}

/// Every value of `set` for every frame of `dataset`: the image extractors' on up to `threads`
/// threads (`progress(done, total)` counts their frames), then each external program's.
///
/// # Errors
/// The first program that fails, named.
pub fn extract(
    set: &FeatureSet,
    dataset: &Dataset,
    threads: usize,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<FeatureRows, ExternalError> {
    let images: Vec<_> = dataset.images().collect();
    let mut rows = set.extract_on(&images, threads, progress);
    fill(set, dataset, &mut rows)?;
    Ok(rows)
}

/// Runs `set`'s external programs on `dataset`'s frames and writes their values into `rows`
/// (one per frame, as [`FeatureSet::extract`] gives them). Nothing happens without a program.
///
/// # Errors
/// The first program that fails, named.
pub fn fill(
    set: &FeatureSet,
    dataset: &Dataset,
    rows: &mut [Vec<Option<f64>>],
) -> Result<(), ExternalError> {
    fill_cached(set, dataset, rows, cache_dir().as_deref())
}

/// [`fill`] with the cache in `dir` (none: every program runs).
fn fill_cached(
    set: &FeatureSet,
    dataset: &Dataset,
    rows: &mut [Vec<Option<f64>>],
    dir: Option<&Path>,
) -> Result<(), ExternalError> {
    if set.external().is_empty() {
        return Ok(());
    }
    if rows.len() != dataset.len() || rows.iter().any(|r| r.len() != set.len()) {
        return Err(ExternalError::Rows {
            rows: rows.len(),
            frames: dataset.len(),
            width: set.len(),
        });
    }
    // Features never see the ground truth.
    let blind = Dataset {
        manifest: dataset.manifest.clone(),
        frames: dataset
            .frames
            .iter()
            .map(|f| Frame {
                truth: None,
                ..f.clone()
            })
            .collect(),
    };
    let files: Vec<String> = blind.frames.iter().map(|f| f.file.clone()).collect();
    let frames_digest = cache::frames_digest(&blind);
    // Written on the first miss only: a hit costs a hash of the pixels.
    let mut folder: Option<Folder> = None;
    let mut offset = set.image_values();
    for program in set.external() {
        let key = cache::key(program, &frames_digest)?;
        let output = match cache::load(dir, &key) {
            Some(output) => output,
            None => {
                let folder = match &mut folder {
                    Some(folder) => folder,
                    None => folder.insert(Folder::write(&blind).map_err(|source| {
                        ExternalError::Frames {
                            program: program.label(),
                            source,
                        }
                    })?),
                };
                let output = process::run(program, &folder.path)?;
                cache::store(dir, &key, &output);
                output
            }
        };
        let values = table::read(&output, program, &files)?;
        for (row, values) in rows.iter_mut().zip(values) {
            row[offset..offset + values.len()].clone_from_slice(&values);
        }
        offset += program.values.len();
    }
    Ok(())
}

/// A dataset folder written for the programs in the system's temporary folder, removed when
/// dropped.
struct Folder {
    path: PathBuf,
}

impl Folder {
    /// `dataset` in a fresh folder.
    fn write(dataset: &Dataset) -> Result<Self, DatasetError> {
        static NEXT: AtomicUsize = AtomicUsize::new(0);
        let name = format!(
            "evitrack-frames-{}-{}",
            std::process::id(),
            NEXT.fetch_add(1, Ordering::Relaxed)
        );
        let folder = Self {
            path: std::env::temp_dir().join(name),
        };
        // A folder of the same name can only be left over from a killed process of this id.
        let _ = std::fs::remove_dir_all(&folder.path);
        dataset.write(&folder.path)?;
        Ok(folder)
    }
}

impl Drop for Folder {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.path);
    }
}

#[cfg(test)]
mod tests;
