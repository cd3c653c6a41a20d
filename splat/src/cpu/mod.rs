//! The CPU renderer, the numerical reference every other renderer is tested against, in its
//! stages: [`project`] (EWA projection of eight Gaussians at once), [`tiles`] (binning and the
//! depth sort), [`blend`] (per-tile alpha blending of eight-pixel blocks, forward and backward)
//! and [`render`], which runs them in parallel. [`stages`] holds the values the stages hand
//! each other. The scalar twins of the projection and blending kernels, one Gaussian and one
//! pixel at a time, live beside the float64 renderer in [`crate::reference`]: they define the
//! rules these kernels compute, and only the tests run them.

pub mod blend;
pub mod exp;
pub mod lanes;
pub mod project;
pub mod render;
pub mod stages;
pub mod tiles;
