//! The single error type of the crate: every variant names the file or folder at fault.

use std::path::PathBuf;

/// Everything that can go wrong reading or writing a capture.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    /// Stopped on request (Ctrl-C, SIGTERM): nothing was written.
    #[error("interrupted: stopped before the capture was complete; nothing was written")]
    Interrupted,
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{}: {what} not found", path.display())]
    NotFound { path: PathBuf, what: String },
    #[error("{}: no images (.png, .jpg, .jpeg) in folder", dir.display())]
    NoImages { dir: PathBuf },
    #[error(
        "{}: image is {}x{} but {} is {}x{}; all images of a folder must share one size",
        path.display(), found.0, found.1, first.display(), expected.0, expected.1
    )]
    ImageSizeMismatch {
        path: PathBuf,
        first: PathBuf,
        expected: (u32, u32),
        found: (u32, u32),
    },
    #[error(
        "{} has {poses} poses but {} has {images} images",
        poses_file.display(), image_dir.display()
    )]
    CountMismatch {
        poses_file: PathBuf,
        poses: usize,
        image_dir: PathBuf,
        images: usize,
    },
    #[error("{}: cannot decode or encode image: {source}", path.display())]
    Image {
        path: PathBuf,
        #[source]
        source: image::ImageError,
    },
    #[error("{}: non-finite value (NaN or infinity) in row {row}, column {column}", path.display())]
    NonFinite {
        path: PathBuf,
        row: usize,
        column: usize,
    },
    #[error("{}: file ends early while reading {what}", path.display())]
    Truncated { path: PathBuf, what: String },
    #[error("{}: unsupported camera model {model}", path.display())]
    UnknownCameraModel { path: PathBuf, model: String },
    #[error("{}:{line}: {problem}", path.display())]
    Parse {
        path: PathBuf,
        line: usize,
        problem: String,
    },
    #[error(transparent)]
    Psf(aberration::AberrationError),
    #[error(transparent)]
    Npy(base::npy::NpyError),
    #[error("{}: {problem}", path.display())]
    Invalid { path: PathBuf, problem: String },
}

pub type Result<T> = std::result::Result<T, SceneError>;

impl SceneError {
    /// Refuses a file larger than `limit` before it is read whole.
    pub(crate) fn check_file_size(path: &std::path::Path, limit: u64) -> Result<()> {
        let len = std::fs::metadata(path)
            .map_err(|e| match e.kind() {
                std::io::ErrorKind::NotFound => SceneError::NotFound {
                    path: path.to_path_buf(),
                    what: "file".into(),
                },
                _ => SceneError::io(path, e),
            })?
            .len();
        if len > limit {
            return Err(SceneError::invalid(
                path,
                format!(
                    "{len} bytes, more than the {} this reader accepts",
                    base::limits::describe_bytes(limit)
                ),
            ));
        }
        Ok(())
    }

    pub(crate) fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        SceneError::Io {
            path: path.into(),
            source,
        }
    }

    pub(crate) fn invalid(path: impl Into<PathBuf>, problem: impl Into<String>) -> Self {
        SceneError::Invalid {
            path: path.into(),
            problem: problem.into(),
        }
    }
}
