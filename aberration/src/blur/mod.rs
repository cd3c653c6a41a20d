//! The spatially varying blur `y = A x` of the imaging model and its exact adjoint `Aᵀ`.
//!
//! Two modes:
//! - [`BlurMode::Tiled`], exactly as the paper: the image is cut into G×G tiles and each
//!   tile is the convolution of the (reflect-padded) image with that tile's PSF; tile
//!   borders are hard.
//! - [`BlurMode::Blend`]: `y = Σ_r h_r ∗ (w_r ⊙ x)` with bilinear hat weights `w_r` between
//!   neighbouring grid centres, which is seamless.
//!
//! Convolution convention (ifftshift-correct): `y[p] = Σ_k h[k] · x[p + c − k]` with
//! `c = K/2` the PSF centre pixel, so a delta at the centre is the identity. The image is
//! extended beyond its border by half-sample symmetric reflection; the adjoint folds that
//! padding back, so `⟨A x, y⟩ = ⟨x, Aᵀ y⟩` holds exactly (up to f32 rounding).

pub mod layout;
mod plan;

pub use plan::{BlurMode, BlurPlan};
