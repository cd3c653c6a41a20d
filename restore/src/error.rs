use std::path::PathBuf;
use thiserror::Error;

#[derive(Debug, Error)]
pub enum RestoreError {
    #[error(transparent)]
    Aberration(#[from] aberration::AberrationError),
    #[error("{0}: {1}")]
    Io(PathBuf, std::io::Error),
    #[error("{0}")]
    BadInput(String),
    #[error("{path}: {message}")]
    Weights { path: PathBuf, message: String },
}

pub type Result<T> = std::result::Result<T, RestoreError>;
