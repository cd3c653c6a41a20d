//! The one way metasplat writes a file: into a temporary file in the target folder (same
//! filesystem, so the rename is atomic), flushed and fsynced, then renamed over the final name.
//! An interrupted run never leaves half a file under the final name, and an output is created
//! with the ordinary mode (`0666` less the umask), so a result handed to a colleague or a web
//! server can be read like any other file.

use std::fs::File;
use std::io::{self, BufWriter, Write};
use std::path::Path;

/// Prefix of our temporary files and staging folders, so a later run can recognise and
/// remove orphans; the writing process's id follows it (see [`temp_prefix`]).
pub const TEMP_PREFIX: &str = ".metasplat-";

/// The prefix of a temporary file or staging folder made by this process:
/// `.metasplat-<pid>-`, so [`remove_orphans`] can tell a killed run's leftovers from those
/// of a run still writing.
pub fn temp_prefix() -> String {
    format!("{TEMP_PREFIX}{}-", std::process::id())
}

/// Whether the process that made a temporary named `name` can no longer be writing it: the
/// process id in the name is not running (Linux: no `/proc/<pid>`), or the name holds no
/// process id (an older naming). Elsewhere than Linux only names without an id count.
fn is_orphan(name: &str) -> bool {
    let Some(rest) = name.strip_prefix(TEMP_PREFIX) else {
        return false;
    };
    // Staging folders carry a kind before the id (`.metasplat-frames-<pid>-`).
    let pid = rest.split('-').find_map(|part| part.parse::<u32>().ok());
    match pid {
        None => true,
        Some(pid) if pid == std::process::id() => false,
        Some(pid) => {
            if cfg!(target_os = "linux") {
                !Path::new("/proc").join(pid.to_string()).exists()
            } else {
                false
            }
        }
    }
}

/// Removes our orphaned temporary files and staging folders (names starting with
/// [`TEMP_PREFIX`] whose writer is gone) directly inside `dir`: what a killed run left. Called
/// whenever a folder is about to be written into; returns what it removed. A folder that
/// cannot be listed has nothing to clean, and an entry that cannot be removed (another user's,
/// in a shared sticky folder like `/tmp`) is not ours to clean: it is left, never a reason to
/// refuse the write.
pub fn remove_orphans(dir: &Path) -> Vec<std::path::PathBuf> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    let mut removed = Vec::new();
    for entry in entries.flatten() {
        let name = entry.file_name();
        let Some(name) = name.to_str() else {
            continue;
        };
        if !is_orphan(name) {
            continue;
        }
        let path = entry.path();
        // Never follow a link out of the folder.
        let Ok(kind) = entry.file_type() else {
            continue;
        };
        let gone = if kind.is_dir() {
            std::fs::remove_dir_all(&path)
        } else {
            std::fs::remove_file(&path)
        };
        if gone.is_ok() {
            removed.push(path);
        }
    }
    removed
}

/// Why [`write_atomically_with`] failed: the file system, or the caller's own writer.
#[derive(Debug)]
pub enum WriteError<E> {
    Io(io::Error),
    Body(E),
}

/// [`write_atomically`] for a writer with its own error type, returned as it was.
pub fn write_atomically_with<E>(
    path: &Path,
    write: impl FnOnce(&mut BufWriter<&mut File>) -> Result<(), E>,
) -> Result<(), WriteError<E>> {
    let mut failure = None;
    let written = write_atomically(path, |w| {
        write(w).map_err(|e| {
            failure = Some(e);
            io::Error::other("the writer failed")
        })
    });
    match (written, failure) {
        (_, Some(e)) => Err(WriteError::Body(e)),
        (r, None) => r.map_err(WriteError::Io),
    }
}

/// Whether this process writes into `dir` for the first time.
fn first_write_to(dir: &Path) -> bool {
    static SEEN: std::sync::Mutex<Option<std::collections::HashSet<std::path::PathBuf>>> =
        std::sync::Mutex::new(None);
    let mut seen = SEEN.lock().unwrap_or_else(|e| e.into_inner());
    seen.get_or_insert_with(Default::default)
        .insert(dir.to_path_buf())
}

/// Runs `write` on a buffered temporary file beside `path` and renames it onto `path` only
/// when `write` succeeded; on failure the temporary is removed and `path` is untouched.
pub fn write_atomically(
    path: &Path,
    write: impl FnOnce(&mut BufWriter<&mut File>) -> io::Result<()>,
) -> io::Result<()> {
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    // A killed writer's temporary files in this folder go first, once per folder and process
    // (a frame sequence would otherwise list its folder once per frame).
    if first_write_to(dir) {
        remove_orphans(dir);
    }
    let mut builder = tempfile::Builder::new();
    let prefix = temp_prefix();
    builder.prefix(&prefix).suffix(".tmp");
    // tempfile creates private (0600) files by default; the mode given here is filtered by
    // the umask at creation, as for any ordinary file.
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        builder.permissions(std::fs::Permissions::from_mode(0o666));
    }
    let mut tmp = builder.tempfile_in(dir)?;
    {
        let mut w = BufWriter::with_capacity(1 << 16, tmp.as_file_mut());
        write(&mut w)?;
        w.flush()?;
    }
    tmp.as_file().sync_all()?;
    tmp.persist(path).map_err(|e| e.error)?;
    Ok(())
}

/// [`write_atomically`] for bytes already in memory.
pub fn write_bytes_atomically(path: &Path, bytes: &[u8]) -> io::Result<()> {
    write_atomically(path, |w| w.write_all(bytes))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn orphans_are_ours_from_gone_processes_only() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        // A process id far above any Linux pid_max, so never running.
        let gone = [
            ".metasplat-4294967290-abc.tmp",
            ".metasplat-frames-4294967290-xyz",
            ".metasplat-old.tmp",
        ];
        let ours = format!("{}keep.tmp", temp_prefix());
        let others = ["keep.png", ".hidden", "metasplat-1-x.tmp"];
        for name in gone.iter().chain(others.iter()).chain([&ours.as_str()]) {
            if name.contains("frames") {
                std::fs::create_dir(d.join(name)).unwrap();
                std::fs::write(d.join(name).join("f.png"), b"x").unwrap();
            } else {
                std::fs::write(d.join(name), b"x").unwrap();
            }
        }
        let mut removed = remove_orphans(d);
        removed.sort();
        let mut expected: Vec<_> = gone.iter().map(|n| d.join(n)).collect();
        expected.sort();
        assert_eq!(removed, expected);
        for name in others.iter().chain([&ours.as_str()]) {
            assert!(d.join(name).exists(), "{name} was removed");
        }
        assert!(remove_orphans(&d.join("missing")).is_empty());
    }
}
