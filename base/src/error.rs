//! Typed errors of the shared helpers.

#[derive(Debug, thiserror::Error)]
pub enum BaseError {
    #[error("{what}: expected length {expected}, got {got}")]
    SizeMismatch {
        what: &'static str,
        expected: usize,
        got: usize,
    },
    #[error("{0} is empty")]
    Empty(&'static str),
}
