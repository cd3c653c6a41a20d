//! Differentiable Gaussian-splat rasterizer (CPU, rayon), the numerical reference for every
//! other renderer in metasplat. Conventions follow gsplat; see each module's docs:
//! [`camera`] (OpenCV pinhole), [`project`] (EWA projection, radius), [`tiles`] (16×16 tiles,
//! sort key), [`raster`] (blending rules), [`sh`] (basis constants).

pub mod camera;
pub mod densify;
pub mod error;
pub mod loss;
pub mod model;
pub mod optim;
pub mod ply;
pub mod project;
pub mod raster;
pub mod render;
pub mod rng;
pub mod sh;
pub mod synthetic;
pub mod tiles;

pub use camera::Camera;
pub use error::SplatError;
pub use model::{Gaussians, MAX_SH_DEGREE, sh_rest_count};
pub use render::{Gradients, RenderOutput, RenderSettings, render, render_backward};
