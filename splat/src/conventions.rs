//! The numbers every implementation of the rasterizer must share, in one place: the CPU kernels
//! use them, and the GPU kernels and any port must use the same values to agree with the
//! CPU reference. The rules they take part in are documented in `cpu::project`, `cpu::tiles` and
//! `reference::scalar_blend`, and in the crate README.

/// Low-pass added to the screen-space covariance diagonal (pixels²).
pub const COV2D_BLUR: f32 = 0.3;
/// Smallest alpha that contributes to a pixel; also the opacity below which a splat is culled.
pub const ALPHA_THRESHOLD: f32 = 1.0 / 255.0;
/// Cap on a splat's alpha at any pixel.
pub const MAX_ALPHA: f32 = 0.99;
/// A pixel stops before blending a splat that would bring its transmittance to this or below.
pub const TRANSMITTANCE_MIN: f32 = 1e-4;
/// Cap on the screen extent in standard deviations (≥ `sqrt(2 ln 255)`, so never the binding
/// limit for opacities ≤ 1).
pub const MAX_EXTENT_SIGMAS: f32 = 3.33;
/// Side of a square raster tile in pixels.
pub const TILE_SIZE: u32 = 16;
/// The EWA Jacobian is evaluated at `x/z` clamped to the image's extent plus this fraction of
/// `tan(fov/2)` on each side (`1.3 · tan(fov/2)` for a centred principal point).
pub const JACOBIAN_CLAMP_MARGIN: f32 = 0.3;
/// Added to the SH sum before the colour is clamped at 0.
pub const SH_COLOR_OFFSET: f32 = 0.5;

pub use crate::sh::{
    SH_C0, SH_C1, SH_C2_XX, SH_C2_XY, SH_C2_ZZ, SH_C2_ZZ0, SH_C3_A, SH_C3_B, SH_C3_C, SH_C3_C0,
    SH_C3_D, SH_C3_D0,
};
