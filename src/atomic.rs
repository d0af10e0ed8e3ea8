//! Files written so that a kill at any moment leaves each one complete or absent: the bytes go to
//! a partial file beside the target (`.NAME.partial`), which is synced and then renamed over the
//! target in one step. A kill can leave a stray partial file, never a truncated target; the next
//! run that writes the same file replaces it.

use std::io::Write;
use std::path::{Path, PathBuf};

/// The partial file `path` is written through.
pub fn partial_path(path: &Path) -> PathBuf {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    path.with_file_name(format!(".{name}.partial"))
}

/// Writes `bytes` to `path` atomically.
///
/// # Errors
/// Creating, writing, syncing or renaming the partial file (which is then removed).
pub fn write(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let partial = partial_path(path);
    let result = (|| {
        let mut file = std::fs::File::create(&partial)?;
        file.write_all(bytes)?;
        file.sync_all()?;
        std::fs::rename(&partial, path)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&partial);
    }
    result
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_write_replaces_the_file_whole_and_leaves_no_partial() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("results.json");
        write(&path, b"old").unwrap();
        write(&path, b"new contents").unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), b"new contents");
        let names: Vec<_> = std::fs::read_dir(dir.path()).unwrap().collect();
        assert_eq!(names.len(), 1);
        assert_eq!(
            partial_path(&path),
            dir.path().join(".results.json.partial")
        );
    }

    #[test]
    fn a_failed_write_keeps_the_old_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("missing-folder").join("x.csv");
        assert!(write(&path, b"data").is_err());
        assert!(!path.exists() && !partial_path(&path).exists());
    }
}
