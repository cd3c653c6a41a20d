//! The one way metasplat writes a file: into a temporary file in the target folder (same
//! filesystem, so the rename is atomic), flushed and fsynced, then renamed over the final name.
//! An interrupted run never leaves half a file under the final name, and an output is created
//! with the ordinary mode (`0666` less the umask), so a result handed to a colleague or a web
//! server can be read like any other file.

use std::fs::File;
use std::io::{self, BufWriter, Write};
use std::path::Path;

/// Prefix of our temporary files, so a later run can recognise and remove orphans.
pub const TEMP_PREFIX: &str = ".metasplat-";

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
    let mut builder = tempfile::Builder::new();
    builder.prefix(TEMP_PREFIX).suffix(".tmp");
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
