//! Train/test split as 3DGS's eval mode makes it.

/// Indices of training and held-out images, both ascending.
#[derive(Clone, Debug, PartialEq, Eq, Default)]
pub struct Split {
    pub train: Vec<usize>,
    pub test: Vec<usize>,
    /// Every `llffhold`-th image is held out; 0 holds none out.
    pub llffhold: usize,
}

/// LLFF's conventional hold-out interval.
pub const LLFFHOLD: usize = 8;

/// Holds out images `0, llffhold, 2*llffhold, ...` of `n` (3DGS: `idx % llffhold == 0`).
/// `llffhold == 0` keeps every image for training.
pub fn split(n: usize, llffhold: usize) -> Split {
    let (test, train) = (0..n).partition(|&i| llffhold != 0 && i.is_multiple_of(llffhold));
    Split {
        train,
        test,
        llffhold,
    }
}
