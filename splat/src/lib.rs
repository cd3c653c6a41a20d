//! Differentiable Gaussian-splat rasterizer. The CPU implementation ([`cpu`], rayon) is the
//! numerical reference for every other renderer in metasplat; all of them implement
//! [`Rasterizer`] and share the numbers in [`conventions`]. Conventions follow gsplat; see
//! each module's docs: [`camera`] (OpenCV pinhole), [`cpu::project`] (EWA projection, radius),
//! [`cpu::tiles`] (16×16 tiles, sort key), [`reference::scalar_blend`] (blending rules), [`sh`]
//! (basis constants). [`reference`] holds the brute-force float64 renderer every
//! implementation is tested against and the scalar twins of the CPU kernels. Splat files
//! (PLY, glTF, SPZ) are in [`formats`].

pub mod camera;
pub mod conventions;
// The CPU kernels: documented for whoever ports them, but not API.
#[doc(hidden)]
pub mod cpu;
pub mod densify;
mod disjoint;
pub mod error;
pub mod formats;
#[cfg(feature = "gpu")]
pub mod gpu;
pub mod loss;
pub mod mcmc;
pub mod model;
pub mod optim;
pub mod rasterizer;
#[doc(hidden)]
pub mod reference;
pub mod sh;
pub mod synthetic;
pub mod trainer;

pub use camera::Camera;
pub use cpu::render::{
    BlendKernels, ForwardState, Gradients, RenderOutput, RenderSettings, render, render_backward,
    render_for_backward,
};
pub use error::SplatError;
pub use model::{Gaussians, MAX_SH_DEGREE, sh_rest_count};
pub use rasterizer::{CpuRasterizer, PixelGradients, Rasterizer};
pub use trainer::{CpuTrainer, Regularisers, SplatTrainer, StepReport};
