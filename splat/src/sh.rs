//! Real spherical harmonics, degree 0..=3, in the basis and sign convention of the INRIA 3DGS
//! code and gsplat (`sh_coeffs_to_color_fast`). Basis `k` for a unit direction `(x, y, z)`:
//!
//! | k | function | k | function |
//! |---|---|---|---|
//! | 0 | `C0` | 8 | `0.546274 (x²−y²)` |
//! | 1 | `−C1 y` | 9 | `−0.590044 (3x²y − y³)` |
//! | 2 | `C1 z` | 10 | `1.445306 z·2xy` |
//! | 3 | `−C1 x` | 11 | `(−2.285229 z² + 0.457046) y` |
//! | 4 | `1.092548 xy` | 12 | `z (1.865882 z² − 1.119529)` |
//! | 5 | `−1.092548 yz` | 13 | `(−2.285229 z² + 0.457046) x` |
//! | 6 | `0.946175 z² − 0.315392` | 14 | `1.445306 z (x²−y²)` |
//! | 7 | `−1.092548 xz` | 15 | `−0.590044 (x³ − 3xy²)` |
//!
//! with `C0 = 0.2820948`, `C1 = 0.4886025`. The view direction is
//! `normalize(mean − camera_centre)` and the colour is `max(Σ c_k B_k + 0.5, 0)` per channel.

use std::ops::Mul;

use glam::Vec3;

use crate::cpu::lanes::Lane;

pub const SH_C0: f32 = 0.282_094_8;
pub const SH_C1: f32 = 0.488_602_52;
pub const SH_C2_XY: f32 = 1.092_548_4;
pub const SH_C2_ZZ: f32 = 0.946_174_7;
pub const SH_C2_ZZ0: f32 = 0.315_391_57;
pub const SH_C2_XX: f32 = 0.546_274_2;
pub const SH_C3_A: f32 = -0.590_043_6;
pub const SH_C3_B: f32 = 1.445_305_7;
pub const SH_C3_C: f32 = -2.285_229;
pub const SH_C3_C0: f32 = 0.457_045_8;
pub const SH_C3_D: f32 = 1.865_881_7;
pub const SH_C3_D0: f32 = 1.119_529;

/// The DC coefficient whose view-independent colour is `rgb` (the inverse of
/// [`sh_dc_to_rgb`] where that does not clamp).
pub fn rgb_to_sh_dc(rgb: Vec3) -> Vec3 {
    (rgb - Vec3::splat(crate::conventions::SH_COLOR_OFFSET)) / SH_C0
}

/// The colour a splat with only its DC coefficient shows, before the clamp at 0.
pub fn sh_dc_to_rgb(dc: Vec3) -> Vec3 {
    dc * SH_C0 + Vec3::splat(crate::conventions::SH_COLOR_OFFSET)
}

/// Number of basis functions for `degree`.
pub const fn num_bases(degree: u32) -> usize {
    ((degree + 1) * (degree + 1)) as usize
}

/// Basis values for unit `d`; entries past `num_bases(degree)` are zero, and bands above the
/// active degree cost nothing.
#[inline]
pub fn basis(degree: u32, d: Vec3, out: &mut [f32; 16]) {
    *out = basis_of(degree, d.to_array());
}

/// [`basis`] on any [`Lane`] type (the scalar path and eight Gaussians at once share it).
#[inline(always)]
pub(crate) fn basis_of<T: Lane>(degree: u32, [x, y, z]: [T; 3]) -> [T; 16]
where
    f32: Mul<T, Output = T>,
{
    let mut out = [T::splat(0.0); 16];
    out[0] = T::splat(SH_C0);
    if degree < 1 {
        return out;
    }
    out[1] = -SH_C1 * y;
    out[2] = SH_C1 * z;
    out[3] = -SH_C1 * x;
    if degree < 2 {
        return out;
    }
    let (xx, yy, zz) = (x * x, y * y, z * z);
    out[4] = SH_C2_XY * x * y;
    out[5] = -SH_C2_XY * y * z;
    out[6] = SH_C2_ZZ * zz - SH_C2_ZZ0;
    out[7] = -SH_C2_XY * x * z;
    out[8] = SH_C2_XX * (xx - yy);
    if degree < 3 {
        return out;
    }
    let a = SH_C3_C * zz + SH_C3_C0;
    out[9] = SH_C3_A * (3.0 * xx * y - yy * y);
    out[10] = SH_C3_B * z * 2.0 * x * y;
    out[11] = a * y;
    out[12] = z * (SH_C3_D * zz - SH_C3_D0);
    out[13] = a * x;
    out[14] = SH_C3_B * z * (xx - yy);
    out[15] = SH_C3_A * (xx * x - 3.0 * x * yy);
    out
}

/// Gradients of each basis function with respect to the (treated as free) components of `d`.
#[inline]
pub fn basis_grad(degree: u32, d: Vec3, out: &mut [Vec3; 16]) {
    *out = basis_grad_of(degree, d.to_array()).map(Vec3::from_array);
}

/// A product of two constants, as the scalar formulas first form it (inside the generic
/// functions `f32 * f32` would be read as `f32 * T`).
#[inline(always)]
fn k(a: f32, b: f32) -> f32 {
    a * b
}

/// [`basis_grad`] on any [`Lane`] type: `[basis][component of d]`.
#[inline(always)]
pub(crate) fn basis_grad_of<T: Lane>(degree: u32, [x, y, z]: [T; 3]) -> [[T; 3]; 16]
where
    f32: Mul<T, Output = T>,
{
    let zero = T::splat(0.0);
    let c = T::splat;
    let mut out = [[zero; 3]; 16];
    if degree < 1 {
        return out;
    }
    out[1] = [zero, c(-SH_C1), zero];
    out[2] = [zero, zero, c(SH_C1)];
    out[3] = [c(-SH_C1), zero, zero];
    if degree < 2 {
        return out;
    }
    out[4] = [SH_C2_XY * y, SH_C2_XY * x, zero];
    out[5] = [zero, -SH_C2_XY * z, -SH_C2_XY * y];
    out[6] = [zero, zero, k(2.0, SH_C2_ZZ) * z];
    out[7] = [-SH_C2_XY * z, zero, -SH_C2_XY * x];
    out[8] = [k(2.0, SH_C2_XX) * x, k(-2.0, SH_C2_XX) * y, zero];
    if degree < 3 {
        return out;
    }
    let (xx, yy, zz) = (x * x, y * y, z * z);
    let a = SH_C3_C * zz + SH_C3_C0;
    out[9] = [
        k(SH_C3_A, 6.0) * x * y,
        SH_C3_A * (3.0 * xx - 3.0 * yy),
        zero,
    ];
    out[10] = [
        k(SH_C3_B, 2.0) * z * y,
        k(SH_C3_B, 2.0) * z * x,
        k(SH_C3_B, 2.0) * x * y,
    ];
    out[11] = [zero, a, k(2.0, SH_C3_C) * z * y];
    out[12] = [zero, zero, k(3.0, SH_C3_D) * zz - SH_C3_D0];
    out[13] = [a, zero, k(2.0, SH_C3_C) * z * x];
    out[14] = [
        k(2.0, SH_C3_B) * z * x,
        k(-2.0, SH_C3_B) * z * y,
        SH_C3_B * (xx - yy),
    ];
    out[15] = [
        SH_C3_A * (3.0 * xx - 3.0 * yy),
        k(-SH_C3_A, 6.0) * x * y,
        zero,
    ];
    out
}

/// `Σ_k c_k B_k(d) + 0.5` before the clamp (callers clamp and remember which channels clamped).
#[inline]
pub fn eval(degree: u32, dc: Vec3, rest: &[Vec3], d: Vec3) -> Vec3 {
    let mut b = [0.0f32; 16];
    basis(degree, d, &mut b);
    let mut c = dc * b[0];
    for k in 1..num_bases(degree) {
        c += rest[k - 1] * b[k];
    }
    c + Vec3::splat(crate::conventions::SH_COLOR_OFFSET)
}

/// Backward of [`eval`]: accumulates coefficient gradients into `v_dc`/`v_rest` and returns the
/// gradient with respect to the unit direction `d`.
#[inline]
pub fn eval_backward(
    degree: u32,
    rest: &[Vec3],
    d: Vec3,
    v_color: Vec3,
    v_dc: &mut Vec3,
    v_rest: &mut [Vec3],
) -> Vec3 {
    let mut b = [0.0f32; 16];
    basis(degree, d, &mut b);
    *v_dc += v_color * b[0];
    if degree == 0 {
        return Vec3::ZERO;
    }
    let mut g = [Vec3::ZERO; 16];
    basis_grad(degree, d, &mut g);
    let mut v_d = Vec3::ZERO;
    for k in 1..num_bases(degree) {
        v_rest[k - 1] += v_color * b[k];
        v_d += g[k] * rest[k - 1].dot(v_color);
    }
    v_d
}
