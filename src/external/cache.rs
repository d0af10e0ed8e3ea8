//! The cache of feature programs' outputs, keyed by what they depend on: the command line, the
//! content of every argument that names a file (the script or binary itself), and what the
//! dataset folder holds (the manifest, and every frame's path, time and pixels). A hit skips the
//! program, and the writing of the folder.
//!
//! Where: `$EVITRACK_CACHE_DIR` (empty: no cache), else `$XDG_CACHE_HOME/evitrack`, else
//! `$HOME/.cache/evitrack`; entries are `features/<key>.csv`, the program's raw output, checked
//! again on every read.

use std::collections::hash_map::DefaultHasher;
use std::hash::Hasher;
use std::path::{Path, PathBuf};

use super::ExternalError;
use crate::dataset::Dataset;
use crate::features::ExternalFeatureConfig;

/// Where the cache lives, from the environment; `None` turns it off.
pub fn cache_dir() -> Option<PathBuf> {
    if let Some(dir) = std::env::var_os("EVITRACK_CACHE_DIR") {
        return (!dir.is_empty()).then(|| PathBuf::from(dir));
    }
    let base = match std::env::var_os("XDG_CACHE_HOME").filter(|d| !d.is_empty()) {
        Some(dir) => PathBuf::from(dir),
        None => PathBuf::from(std::env::var_os("HOME").filter(|d| !d.is_empty())?).join(".cache"),
    };
    Some(base.join("evitrack"))
}

/// A 128-bit digest: two SipHash streams told apart by a leading byte. A build of another Rust
/// version may hash differently, which only costs a miss.
#[derive(Clone)]
pub(super) struct Digest([DefaultHasher; 2]);

impl Digest {
    fn new() -> Self {
        let mut pair = [DefaultHasher::new(), DefaultHasher::new()];
        pair[0].write_u8(0);
        pair[1].write_u8(1);
        Self(pair)
    }

    /// Adds `bytes`, length first so that neighbouring parts cannot run together.
    fn add(&mut self, bytes: &[u8]) {
        for h in &mut self.0 {
            h.write_u64(bytes.len() as u64);
            h.write(bytes);
        }
    }

    fn hex(&self) -> String {
        format!("{:016x}{:016x}", self.0[0].finish(), self.0[1].finish())
    }
}

/// The digest of what a dataset folder of `dataset` holds (its ground truth already removed).
pub(super) fn frames_digest(dataset: &Dataset) -> Digest {
    let mut digest = Digest::new();
    digest.add(
        serde_json::to_string(&dataset.manifest)
            .unwrap_or_default()
            .as_bytes(),
    );
    for frame in &dataset.frames {
        digest.add(frame.file.as_bytes());
        digest.add(&frame.t.to_bits().to_le_bytes());
        digest.add(&frame.image.width().to_le_bytes());
        digest.add(&frame.image.height().to_le_bytes());
        digest.add(frame.image.as_raw());
    }
    digest
}

/// The key of `program` run on the frames of `frames` ([`frames_digest`]).
pub(super) fn key(
    program: &ExternalFeatureConfig,
    frames: &Digest,
) -> Result<String, ExternalError> {
    let mut digest = frames.clone();
    add_program(&mut digest, program)?;
    Ok(digest.hex())
}

/// The digest of `program`: its command line and the content of every argument that names a
/// file (the script or binary), so that editing the program changes it.
///
/// # Errors
/// [`ExternalError::Io`] when a file it names cannot be read.
pub fn program_digest(program: &ExternalFeatureConfig) -> Result<String, ExternalError> {
    let mut digest = Digest::new();
    add_program(&mut digest, program)?;
    Ok(digest.hex())
}

/// The digest of a file's bytes (the running program's own build, for instance).
///
/// # Errors
/// The error of reading it.
pub fn file_digest(path: &Path) -> std::io::Result<String> {
    use std::io::Read;
    // In pieces: an executable is tens of MB, which a run must not hold for a digest.
    let mut file = std::fs::File::open(path)?;
    let mut digest = Digest::new();
    let mut piece = vec![0; 1 << 16];
    loop {
        let n = file.read(&mut piece)?;
        if n == 0 {
            return Ok(digest.hex());
        }
        digest.add(&piece[..n]);
    }
}

fn add_program(digest: &mut Digest, program: &ExternalFeatureConfig) -> Result<(), ExternalError> {
    for arg in &program.command {
        digest.add(arg.as_bytes());
        let path = Path::new(arg);
        if path.is_file() {
            let bytes = std::fs::read(path).map_err(|source| ExternalError::Io {
                path: path.to_path_buf(),
                source,
            })?;
            digest.add(b"file");
            digest.add(&bytes);
        }
    }
    Ok(())
}

/// The stored output under `key`, when there is one.
pub(super) fn load(dir: Option<&Path>, key: &str) -> Option<Vec<u8>> {
    std::fs::read(entry(dir?, key)).ok()
}

/// Stores `output` under `key`. A cache that cannot be written is skipped: it only saves time.
pub(super) fn store(dir: Option<&Path>, key: &str, output: &[u8]) {
    if let Some(dir) = dir {
        let path = entry(dir, key);
        if path
            .parent()
            .is_some_and(|p| std::fs::create_dir_all(p).is_ok())
        {
            let _ = crate::atomic::write(&path, output);
        }
    }
}

fn entry(dir: &Path, key: &str) -> PathBuf {
    dir.join("features").join(format!("{key}.csv"))
}
