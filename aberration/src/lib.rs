//! The metalens imaging model of metasplat.
//!
//! - [`optics`]: PSFs simulated from the metalens phase profile (Tseng et al. 2021).
//! - [`PsfGrid`]: the G×G grid of RGB PSFs, its `.npy` file and resolution mapping.
//! - [`blur`]: the spatially varying blur (`tiled` as the paper, or seamless `blend`) and
//!   its exact adjoint.
//! - [`noise`]: Poisson + Gaussian sensor noise.
//! - [`refine`]: a PSF grid refined from the photos it blurred, kept non-negative and unit-sum.
//! - [`wiener`]: tile-wise Wiener deconvolution and the 13-filter MAFG bank.

pub mod blur;
pub mod capture;
pub mod error;
pub mod fft2;
pub mod image;
pub mod noise;
pub mod optics;
pub mod picture;
pub mod psf_grid;
pub mod refine;
pub mod resample;
pub mod wiener;

pub use blur::{BlurMode, BlurPlan};
pub use capture::ImagingModel;
pub use error::{AberrationError, Result};
pub use image::{Image, compare, psnr};
pub use noise::NoiseModel;
pub use psf_grid::PsfGrid;
pub use wiener::{Regularizer, WienerBank, deconvolve, wiener_bank};
