//! Writes that never leave a half-written file under the final name: data goes to a temporary
//! file in the destination folder (same filesystem, so the rename is atomic) and is renamed last.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::Path;

use crate::error::{Result, SceneError};

pub(crate) fn write_file(
    path: &Path,
    write: impl FnOnce(&mut BufWriter<&mut File>) -> Result<()>,
) -> Result<()> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let mut tmp = tempfile::Builder::new()
        .prefix(".partial-")
        .tempfile_in(dir)
        .map_err(|e| SceneError::io(dir, e))?;
    {
        let mut w = BufWriter::new(tmp.as_file_mut());
        write(&mut w)?;
        w.flush().map_err(|e| SceneError::io(path, e))?;
    }
    tmp.as_file()
        .sync_all()
        .map_err(|e| SceneError::io(path, e))?;
    tmp.persist(path)
        .map_err(|e| SceneError::io(path, e.error))?;
    Ok(())
}
