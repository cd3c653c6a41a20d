//! Differentiable Gaussian-splat rasterizer. The CPU implementation here (rayon) is the
//! numerical reference for every other renderer in metasplat; all of them implement
//! [`Rasterizer`] and share the numbers in [`conventions`]. Conventions follow gsplat; see
//! each module's docs: [`camera`] (OpenCV pinhole), [`project`] (EWA projection, radius),
//! [`tiles`] (16×16 tiles, sort key), [`raster`] (blending rules), [`sh`] (basis constants).
//! [`reference`] is the brute-force float64 renderer every implementation is tested against.

pub mod camera;
pub mod conventions;
pub mod densify;
mod disjoint;
pub mod error;
pub mod files;
pub mod glb;
#[cfg(feature = "gpu")]
pub mod gpu;
#[doc(hidden)]
pub mod lanes;
pub mod loss;
pub mod mcmc;
pub mod model;
pub mod optim;
pub mod ply;
pub mod rasterizer;
#[doc(hidden)]
pub mod reference;
pub mod render;
pub mod sh;
pub mod spz;
pub mod synthetic;
pub mod trainer;

// The CPU kernels: documented for whoever ports them, but not API.
#[doc(hidden)]
pub mod blocks;
#[doc(hidden)]
pub mod project;
#[doc(hidden)]
pub mod project_lanes;
#[doc(hidden)]
pub mod raster;
#[doc(hidden)]
pub mod tiles;

pub use camera::Camera;
pub use error::SplatError;
pub use model::{Gaussians, MAX_SH_DEGREE, sh_rest_count};
pub use rasterizer::{CpuRasterizer, PixelGradients, Rasterizer};
pub use render::{
    ForwardState, Gradients, RenderOutput, RenderSettings, render, render_backward,
    render_for_backward,
};
pub use trainer::{CpuTrainer, Regularisers, SplatTrainer, StepReport};
