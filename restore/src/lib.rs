//! The MAFG + STAF aberration-correcting transformer of Lee et al. (ICCV 2025), on burn.
//!
//! - [`config`]: sizes (`paper`, `small`, `tiny`), ablation switches, analytic parameter count.
//! - [`net`]: the network and its attention modules.
//! - [`data`]: training pairs made on the fly by the imaging model of [`aberration`].
//! - [`train`]: the training loop, resumable from [`train_state`]; [`weights`]: the weights
//!   file; [`infer`]: restoring images (tiled, see [`tiles`]).

pub mod average;
pub mod compute;
pub mod config;
pub mod coverage;
pub mod data;
pub mod ensemble;
pub mod error;
pub mod family;
pub mod infer;
pub mod net;
pub mod provenance;
pub mod shipped;
pub mod speed;
pub mod steady;
pub mod tiles;
pub mod train;
pub mod train_state;
pub mod video;
pub mod weights;

pub use burn::tensor::Device;
pub use compute::Compute;
pub use config::{Guidance, Preset, RestorerConfig};
pub use error::{RestoreError, Result};
pub use infer::Restorer;
pub use net::RestorerNet;
