//! The shared atomic writer ([`base::atomic`]) with this crate's errors.

use std::fs::File;
use std::io::BufWriter;
use std::path::Path;

use crate::error::{Result, SceneError};

pub(crate) fn write_file(
    path: &Path,
    write: impl FnOnce(&mut BufWriter<&mut File>) -> Result<()>,
) -> Result<()> {
    base::write_atomically_with(path, write).map_err(|e| match e {
        base::WriteError::Io(e) => SceneError::io(path, e),
        base::WriteError::Body(e) => e,
    })
}
