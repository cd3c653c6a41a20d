//! The library's error type: what went wrong and, where there is one, the file at fault.

use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    #[error(transparent)]
    Scene(#[from] scenes::SceneError),
    #[error(transparent)]
    Aberration(#[from] aberration::AberrationError),
    #[error(transparent)]
    Restore(#[from] restore::RestoreError),
    #[error(transparent)]
    Splat(#[from] splat::SplatError),
    #[error(transparent)]
    Metric(#[from] base::BaseError),
    #[error(transparent)]
    Lock(#[from] base::LockError),
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{}: {problem}", path.display())]
    File { path: PathBuf, problem: String },
    #[error("{0}")]
    Invalid(String),
    /// Stopped on request (Ctrl-C, SIGTERM) at a safe point; says what was kept.
    #[error("interrupted: {0}")]
    Interrupted(String),
    #[error(transparent)]
    Plot(#[from] crate::output::plot::PlotError),
    /// What was being done when `source` went wrong.
    #[error("{what}")]
    Context {
        what: String,
        #[source]
        source: Box<TrainError>,
    },
}

pub type Result<T> = std::result::Result<T, TrainError>;

impl TrainError {
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        TrainError::Io {
            path: path.into(),
            source,
        }
    }

    /// Wraps the error in what was being done.
    pub fn context(self, what: impl Into<String>) -> Self {
        TrainError::Context {
            what: what.into(),
            source: Box::new(self),
        }
    }

    pub fn file(path: impl Into<PathBuf>, problem: impl Into<String>) -> Self {
        TrainError::File {
            path: path.into(),
            problem: problem.into(),
        }
    }
}
