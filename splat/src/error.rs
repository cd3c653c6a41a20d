//! Typed errors for every fallible entry point of the crate.

use std::path::PathBuf;

/// Everything that can go wrong in `splat`. File errors always name the file.
#[derive(Debug, thiserror::Error)]
pub enum SplatError {
    #[error("invalid camera: {0}")]
    InvalidCamera(String),
    #[error("invalid model: {0}")]
    InvalidModel(String),
    #[error("invalid input: {0}")]
    InvalidInput(String),
    #[error("GPU: {0}")]
    Gpu(String),
    #[error("{what}: expected length {expected}, got {got}")]
    SizeMismatch {
        what: &'static str,
        expected: usize,
        got: usize,
    },
    #[error(transparent)]
    Image(#[from] base::BaseError),
    #[error("{}: {problem}", path.display())]
    Ply { path: PathBuf, problem: String },
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
}
