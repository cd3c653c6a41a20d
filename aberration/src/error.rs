use std::path::PathBuf;

/// Everything that can go wrong in the imaging model. File errors carry the path so the
/// binary can tell the user which file is bad and why.
#[derive(Debug, thiserror::Error)]
pub enum AberrationError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error(transparent)]
    BadNpy(base::npy::NpyError),
    #[error("{path}: not a valid PSF grid: {problem}")]
    BadPsfFile { path: PathBuf, problem: String },
    #[error("invalid PSF grid: {0}")]
    BadPsf(String),
    #[error("{path}: cannot read image: {problem}")]
    BadImage { path: PathBuf, problem: String },
    #[error("{path}: cannot write image: {problem}")]
    ImageWrite { path: PathBuf, problem: String },
    #[error("invalid parameter: {0}")]
    BadParameter(String),
    #[error(
        "image of {width}x{height} does not match the plan made for {plan_width}x{plan_height}"
    )]
    SizeMismatch {
        width: usize,
        height: usize,
        plan_width: usize,
        plan_height: usize,
    },
}

pub type Result<T, E = AberrationError> = std::result::Result<T, E>;

impl AberrationError {
    pub(crate) fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Self::Io {
            path: path.into(),
            source,
        }
    }
}
