//! metasplat: clean Gaussian-splat scenes from metalens-aberrated photos.
//!
//! The library behind the `metasplat` binary: the aberration-aware training loop
//! ([`train`]), one run assembled from a request ([`run`]), the initial splats ([`init`]), and the
//! conversions between the member crates' types ([`convert`]).

pub mod bench;
pub mod convert;
pub mod device;
pub mod error;
pub mod flags;
pub mod guard;
pub mod init;
pub mod outputs;
pub mod plot;
pub mod procedural;
pub mod run;
pub mod settings;
pub mod spiral;
pub mod train;
pub mod view;

pub use error::{Result, TrainError};
