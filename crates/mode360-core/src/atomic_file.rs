//! Outputs written beside their target and renamed into place only when complete, so that a
//! failed or killed run never touches an existing file: the target is either the old file or
//! the whole new one (`rename` within a directory is atomic on POSIX file systems).
//!
//! The temporary file is `.NAME.partial-PID-N` in the target's directory, `N` counting this
//! process's writers (threads writing the same target at once, as parallel tests unpacking one
//! shipped file do, each get their own); a killed run leaves it behind (with what was written
//! so far), a failed one removes it.

use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// Suffix of a temporary output before its process id.
pub const PARTIAL_SUFFIX: &str = "partial";

/// Writers this process has started (the `N` of the temporary names).
static WRITERS: AtomicU64 = AtomicU64::new(0);

/// A new temporary path for `target`: `.NAME.partial-PID-N` beside it, unique in this process.
fn partial_path(target: &Path) -> PathBuf {
    let name = target
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let n = WRITERS.fetch_add(1, Ordering::Relaxed);
    let temp = format!(".{name}.{PARTIAL_SUFFIX}-{}-{n}", std::process::id());
    match target.parent() {
        Some(dir) if !dir.as_os_str().is_empty() => dir.join(temp),
        _ => PathBuf::from(temp),
    }
}

/// A file being written for `target`; [`Self::commit`] puts it in place, dropping it without a
/// commit removes it.
#[derive(Debug)]
pub struct AtomicFile {
    target: PathBuf,
    temp: PathBuf,
    committed: bool,
}

impl AtomicFile {
    /// Creates the temporary file for `target` (the target itself is not touched).
    pub fn create(target: impl AsRef<Path>) -> std::io::Result<(Self, File)> {
        let target = target.as_ref().to_path_buf();
        let temp = partial_path(&target);
        let file = File::create(&temp)?;
        Ok((
            Self {
                target,
                temp,
                committed: false,
            },
            file,
        ))
    }

    pub fn target(&self) -> &Path {
        &self.target
    }

    /// Syncs `file` (the one [`Self::create`] returned, fully written) and renames it onto the
    /// target.
    pub fn commit(mut self, file: File) -> std::io::Result<()> {
        file.sync_all()?;
        drop(file);
        std::fs::rename(&self.temp, &self.target)?;
        self.committed = true;
        Ok(())
    }
}

impl Drop for AtomicFile {
    fn drop(&mut self) {
        if !self.committed {
            let _ = std::fs::remove_file(&self.temp);
        }
    }
}

/// Writes `bytes` to `target` through a temporary file (see the module docs).
pub fn write_atomic(target: impl AsRef<Path>, bytes: impl AsRef<[u8]>) -> std::io::Result<()> {
    let (atomic, mut file) = AtomicFile::create(target)?;
    file.write_all(bytes.as_ref())?;
    atomic.commit(file)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_target_changes_only_on_commit() {
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("out.json");
        std::fs::write(&target, "old").unwrap();
        {
            let (atomic, mut file) = AtomicFile::create(&target).unwrap();
            file.write_all(b"half").unwrap();
            assert_eq!(std::fs::read_to_string(&target).unwrap(), "old");
            drop((atomic, file)); // a failed run: no commit
        }
        assert_eq!(std::fs::read_to_string(&target).unwrap(), "old");
        let names: Vec<_> = std::fs::read_dir(dir.path()).unwrap().collect();
        assert_eq!(names.len(), 1, "temporary file left behind");
        write_atomic(&target, "new").unwrap();
        assert_eq!(std::fs::read_to_string(&target).unwrap(), "new");
        let names: Vec<_> = std::fs::read_dir(dir.path()).unwrap().collect();
        assert_eq!(names.len(), 1, "only the target remains");
    }

    #[test]
    fn threads_writing_one_target_at_once_all_succeed() {
        // One temporary file per writer: with one per process, a writer's rename took another's
        // half-written file, and the other's rename then failed (parallel tests unpacking the
        // same shipped weights fell back to a second folder).
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("w.bin");
        let bytes: Vec<u8> = (0..1 << 20).map(|i| (i % 251) as u8).collect();
        std::thread::scope(|s| {
            let writers: Vec<_> = (0..8)
                .map(|_| s.spawn(|| write_atomic(&target, &bytes)))
                .collect();
            for w in writers {
                w.join().unwrap().unwrap();
            }
        });
        assert!(std::fs::read(&target).unwrap() == bytes, "target not whole");
        let names: Vec<_> = std::fs::read_dir(dir.path()).unwrap().collect();
        assert_eq!(names.len(), 1, "temporary files left behind");
    }
}
