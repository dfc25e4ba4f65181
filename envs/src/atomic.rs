//! Atomic file replacement, the one helper every file Ess writes goes through: the
//! content is written to a temporary file beside the target, synced, and renamed over
//! it, so a reader (or a crash) never sees a half-written file.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// A temporary file beside `path` that [`AtomicFile::commit`] renames over it; dropped
/// uncommitted, it is removed. Its name, `.NAME.tmp-PID-N.EXT`, is unique within the
/// machine's processes and keeps `path`'s extension (writers such as image encoders
/// pick the format from it).
#[derive(Debug)]
pub struct AtomicFile {
    path: PathBuf,
    tmp: PathBuf,
    committed: bool,
}

impl AtomicFile {
    /// A temporary file name for replacing `path` (nothing is created yet).
    pub fn new(path: &Path) -> Self {
        static NEXT: AtomicU64 = AtomicU64::new(0);
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| "file".to_owned());
        let n = NEXT.fetch_add(1, Ordering::Relaxed);
        let ext = path
            .extension()
            .map(|e| format!(".{}", e.to_string_lossy()))
            .unwrap_or_default();
        let tmp = path.with_file_name(format!(".{name}.tmp-{}-{n}{ext}", std::process::id()));
        Self {
            path: path.to_owned(),
            tmp,
            committed: false,
        }
    }

    /// Where to write the content.
    pub fn tmp(&self) -> &Path {
        &self.tmp
    }

    /// Syncs the written temporary file and renames it over the target; on error, the
    /// path the failing operation touched and the I/O error.
    pub fn commit(mut self) -> Result<(), (PathBuf, std::io::Error)> {
        let synced = std::fs::File::open(&self.tmp).and_then(|f| f.sync_all());
        if let Err(e) = synced {
            return Err((self.tmp.clone(), e));
        }
        if let Err(e) = std::fs::rename(&self.tmp, &self.path) {
            return Err((self.path.clone(), e));
        }
        self.committed = true;
        Ok(())
    }
}

impl Drop for AtomicFile {
    fn drop(&mut self) {
        if !self.committed {
            // Best effort: the temporary file may not exist if writing failed early.
            let _ = std::fs::remove_file(&self.tmp);
        }
    }
}

/// Writes `bytes` to `path` atomically ([`AtomicFile`]). On error, returns the path the
/// failing operation touched with the I/O error.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), (PathBuf, std::io::Error)> {
    let file = AtomicFile::new(path);
    let written = std::fs::File::create(file.tmp()).and_then(|mut f| f.write_all(bytes));
    if let Err(e) = written {
        return Err((file.tmp().to_owned(), e));
    }
    file.commit()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn names(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(dir)
            .expect("dir")
            .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }

    #[test]
    fn a_committed_file_replaces_the_target_and_leaves_no_temporary() {
        let dir = tempfile::tempdir().expect("tmp");
        let path = dir.path().join("a.png");
        std::fs::write(&path, b"old").expect("old");
        let f = AtomicFile::new(&path);
        assert_eq!(f.tmp().extension().and_then(|e| e.to_str()), Some("png"));
        std::fs::write(f.tmp(), b"new").expect("write");
        f.commit().expect("commit");
        assert_eq!(std::fs::read(&path).expect("read"), b"new");
        assert_eq!(names(dir.path()), ["a.png"]);
    }

    #[test]
    fn an_uncommitted_file_is_removed_and_the_target_kept() {
        let dir = tempfile::tempdir().expect("tmp");
        let path = dir.path().join("state.json");
        write_atomic(&path, b"v1").expect("v1");
        {
            let f = AtomicFile::new(&path);
            std::fs::write(f.tmp(), b"half").expect("write");
        }
        assert_eq!(std::fs::read(&path).expect("read"), b"v1");
        assert_eq!(names(dir.path()), ["state.json"]);
        // Two at once get two temporary names.
        let (a, b) = (AtomicFile::new(&path), AtomicFile::new(&path));
        assert_ne!(a.tmp(), b.tmp());
    }

    #[test]
    fn a_write_into_a_missing_directory_names_the_temporary_file() {
        let dir = tempfile::tempdir().expect("tmp");
        let path = dir.path().join("nope").join("x.bin");
        let (p, _) = write_atomic(&path, b"x").expect_err("no dir");
        assert!(p.starts_with(dir.path().join("nope")), "{}", p.display());
    }
}
