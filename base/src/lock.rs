//! One writer per output folder: an exclusive OS lock on a small file, taken before a command
//! writes anything there and released when the holder ends, however it ends (the kernel drops
//! the lock of a killed process).
//!
//! The lock file names its holder (process id and command), so that a refused second writer
//! can say who is writing. It is removed when the holder releases it; a writer that opened the
//! file just before it was removed would hold a lock on a file no longer there, so every
//! acquisition checks that the locked file is still the one at the path and retries if not.

use std::fs::{File, OpenOptions, TryLockError};
use std::io::{Read, Seek, Write};
use std::path::{Path, PathBuf};

/// The lock file inside a locked folder.
pub const LOCK_FILE: &str = ".metasplat.lock";

/// Why a lock was not taken.
#[derive(Debug, thiserror::Error)]
pub enum LockError {
    #[error("{} is being written by another metasplat ({holder}): wait for it to finish or choose another folder", .folder.display())]
    Busy { folder: PathBuf, holder: String },
    #[error("cannot lock {}: {source}", .path.display())]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
}

/// An exclusive lock on one output, held until dropped.
#[derive(Debug)]
pub struct FolderLock {
    file: File,
    path: PathBuf,
}

impl FolderLock {
    /// Locks the existing folder `dir` through `dir/`[`LOCK_FILE`]; `command` says what holds
    /// it (e.g. `train`), for the message a second writer gets.
    pub fn folder(dir: &Path, command: &str) -> Result<FolderLock, LockError> {
        Self::acquire(dir.join(LOCK_FILE), dir, command)
    }

    /// Locks an output that must not exist yet (a capture made by renaming a staging folder
    /// into place) through a lock file beside it, `.<name>.metasplat.lock` in its parent.
    pub fn beside(dest: &Path, command: &str) -> Result<FolderLock, LockError> {
        let parent = match dest.parent() {
            Some(p) if !p.as_os_str().is_empty() => p,
            _ => Path::new("."),
        };
        let name = dest
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        std::fs::create_dir_all(parent).map_err(|source| LockError::Io {
            path: parent.to_path_buf(),
            source,
        })?;
        Self::acquire(parent.join(format!(".{name}{LOCK_FILE}")), dest, command)
    }

    fn acquire(path: PathBuf, folder: &Path, command: &str) -> Result<FolderLock, LockError> {
        let io = |source| LockError::Io {
            path: path.clone(),
            source,
        };
        // A holder releasing between our open and our lock removes the file we locked: retry on
        // the new one. Each retry needs a release by another process, so a few suffice.
        for _ in 0..16 {
            let mut file = OpenOptions::new()
                .read(true)
                .write(true)
                .create(true)
                .truncate(false)
                .open(&path)
                .map_err(io)?;
            match file.try_lock() {
                Ok(()) => {}
                Err(TryLockError::WouldBlock) => {
                    let mut text = String::new();
                    let _ = file.read_to_string(&mut text);
                    let holder = match text.trim() {
                        "" => "a process that is starting".to_string(),
                        t => t.to_string(),
                    };
                    return Err(LockError::Busy {
                        folder: folder.to_path_buf(),
                        holder,
                    });
                }
                Err(TryLockError::Error(e)) => return Err(io(e)),
            }
            if !same_file(&file, &path) {
                continue;
            }
            file.set_len(0).map_err(io)?;
            file.rewind().map_err(io)?;
            let note = format!("process {}, `{command}`", std::process::id());
            file.write_all(note.as_bytes()).map_err(io)?;
            file.flush().map_err(io)?;
            return Ok(FolderLock { file, path });
        }
        Err(io(std::io::Error::other(
            "the lock file kept being replaced while it was taken",
        )))
    }

    /// The lock file.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

#[cfg(unix)]
fn same_file(file: &File, path: &Path) -> bool {
    use std::os::unix::fs::MetadataExt;
    match (file.metadata(), std::fs::metadata(path)) {
        (Ok(a), Ok(b)) => a.dev() == b.dev() && a.ino() == b.ino(),
        _ => false,
    }
}

#[cfg(not(unix))]
fn same_file(_file: &File, path: &Path) -> bool {
    path.exists()
}

impl Drop for FolderLock {
    fn drop(&mut self) {
        // Removed while still locked, so no one can lock this file after we let go of it.
        let _ = std::fs::remove_file(&self.path);
        let _ = self.file.unlock();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_second_writer_is_refused_with_the_holder_named_until_the_first_lets_go() {
        let dir = tempfile::tempdir().unwrap();
        let first = FolderLock::folder(dir.path(), "train").unwrap();
        let err = FolderLock::folder(dir.path(), "train").unwrap_err();
        let msg = err.to_string();
        assert!(matches!(err, LockError::Busy { .. }), "{msg}");
        assert!(
            msg.contains(&format!("process {}", std::process::id())) && msg.contains("`train`"),
            "{msg}"
        );
        drop(first);
        assert!(!dir.path().join(LOCK_FILE).exists(), "the lock file stays");
        let again = FolderLock::folder(dir.path(), "render").unwrap();
        drop(again);
    }

    #[test]
    fn a_lock_beside_a_missing_output_keeps_the_output_absent() {
        let dir = tempfile::tempdir().unwrap();
        let dest = dir.path().join("scene");
        let lock = FolderLock::beside(&dest, "scene aberrate").unwrap();
        assert!(!dest.exists());
        assert!(FolderLock::beside(&dest, "scene aberrate").is_err());
        // Another output in the same parent is not blocked.
        FolderLock::beside(&dir.path().join("other"), "scene aberrate").unwrap();
        drop(lock);
        FolderLock::beside(&dest, "scene aberrate").unwrap();
    }

    #[test]
    fn a_lock_file_left_by_a_killed_holder_does_not_block() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join(LOCK_FILE), b"process 1, `train`").unwrap();
        let lock = FolderLock::folder(dir.path(), "train").unwrap();
        let text = std::fs::read_to_string(lock.path()).unwrap();
        assert_eq!(text, format!("process {}, `train`", std::process::id()));
    }
}
