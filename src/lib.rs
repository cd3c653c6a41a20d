//! metasplat: clean Gaussian-splat scenes from metalens-aberrated photos.
//!
//! The library behind the `metasplat` binary: the aberration-aware training loop
//! ([`train`]), one run assembled from a request ([`run`]) with its settings ([`settings`]),
//! the splat side of a run ([`splats`]: initial splats, the procedural scenes, the renderer
//! it runs on), what a run writes and shows ([`output`]), the experiments ([`lab`]) and the
//! other commands as jobs ([`jobs`]: the restorer's training and evaluation, restoring,
//! rendering, export).

pub mod error;
pub mod jobs;
pub mod lab;
pub mod output;
pub mod run;
pub mod settings;
pub mod splats;
pub mod train;

pub use error::{Result, TrainError};
