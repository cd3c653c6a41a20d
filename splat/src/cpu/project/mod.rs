//! Per-Gaussian projection to screen space (EWA splatting, gsplat conventions) and its
//! hand-written backward pass.
//!
//! Forward, for a Gaussian with mean `p`, log-scale `l`, quaternion `q`, logit opacity `o`:
//! 1. `Σ = R(q̂) diag(e^l)² R(q̂)ᵀ`, `p_c = W p + t` (camera pose `W, t`).
//! 2. Cull if `z < near` or `z > far`.
//! 3. EWA Jacobian at `(tx, ty, z)`, with `tx = z · clamp(x/z, −(cx/fx + 0.3 tan_fovx),
//!    (width−cx)/fx + 0.3 tan_fovx)` (and likewise for y), `tan_fovx = width / (2 fx)`; for a
//!    centred principal point the limit is gsplat's `1.3 · tan(fov/2)`. The clamp keeps
//!    Gaussians far outside the frustum from producing huge footprints.
//! 4. `cov = J W Σ Wᵀ Jᵀ + 0.3 I` (the 0.3 px² low-pass); `conic = cov⁻¹`.
//!    With `antialiased` the opacity is multiplied by Mip-Splatting's compensation
//!    `sqrt(det(cov − 0.3 I) / det(cov))`.
//! 5. Radius: the opacity-dependent extent `k = min(3.33, sqrt(2 ln(255 · opacity)))` — the
//!    level set where `opacity · e^(−σ)` reaches 1/255 — gives the per-axis half-size of the
//!    pixel bounding box, `ceil(k · sqrt(cov_xx))` and `ceil(k · sqrt(cov_yy))`. Cull if the
//!    opacity is below 1/255 or the box misses the image. A culled Gaussian has radius `[0, 0]`.
//! 6. Colour from SH (see [`crate::sh`]).

use std::ops::{Mul, Sub};

use glam::{Mat3, Vec3};

use crate::camera::Camera;
use crate::conventions::JACOBIAN_CLAMP_MARGIN;
use crate::cpu::lanes::Lane;

pub mod lanes;

/// Rotation matrix of a quaternion `(w, x, y, z)` of any length, and the normalised quaternion.
/// Scaling by the largest component first keeps huge quaternions from overflowing; the zero
/// quaternion maps to the identity.
#[inline]
pub fn quat_to_rotmat(q: [f32; 4]) -> (Mat3, [f32; 4], f32) {
    let m = q.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    if !(m.is_finite() && m > 0.0) {
        return (Mat3::IDENTITY, [1.0, 0.0, 0.0, 0.0], 0.0);
    }
    let s = [q[0] / m, q[1] / m, q[2] / m, q[3] / m];
    let len_s = (s[0] * s[0] + s[1] * s[1] + s[2] * s[2] + s[3] * s[3]).sqrt();
    let qn = [s[0] / len_s, s[1] / len_s, s[2] / len_s, s[3] / len_s];
    let r = rotation_rows(qn);
    let col = |j: usize| Vec3::new(r[0][j], r[1][j], r[2][j]);
    (Mat3::from_cols(col(0), col(1), col(2)), qn, m * len_s)
}

/// The rotation matrix of a unit quaternion `(w, x, y, z)`, `[row][col]`: the formulas the
/// scalar projection and the lane one ([`crate::cpu::project::lanes`]) share.
#[inline(always)]
pub(crate) fn rotation_rows<T: Lane>([w, x, y, z]: [T; 4]) -> [[T; 3]; 3]
where
    f32: Mul<T, Output = T> + Sub<T, Output = T>,
{
    [
        [
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y - w * z),
            2.0 * (x * z + w * y),
        ],
        [
            2.0 * (x * y + w * z),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z - w * x),
        ],
        [
            2.0 * (x * z - w * y),
            2.0 * (y * z + w * x),
            1.0 - 2.0 * (x * x + y * y),
        ],
    ]
}

/// The gradient of [`rotation_rows`] with respect to the raw quaternion of length `len > 0`
/// whose normalised form is `qn`, given `v_r` = dL/dR `[row][col]` (shared with the lanes).
#[inline(always)]
pub(crate) fn rotation_backward<T: Lane>(qn: [T; 4], len: T, v_r: &[[T; 3]; 3]) -> [T; 4]
where
    f32: Mul<T, Output = T>,
{
    let [w, x, y, z] = qn;
    let g = |i: usize, j: usize| v_r[i][j];
    let vw = 2.0 * (x * (g(2, 1) - g(1, 2)) + y * (g(0, 2) - g(2, 0)) + z * (g(1, 0) - g(0, 1)));
    let vx = 2.0 * (y * (g(0, 1) + g(1, 0)) + z * (g(0, 2) + g(2, 0)) + w * (g(2, 1) - g(1, 2)))
        - 4.0 * x * (g(1, 1) + g(2, 2));
    let vy = 2.0 * (x * (g(0, 1) + g(1, 0)) + w * (g(0, 2) - g(2, 0)) + z * (g(1, 2) + g(2, 1)))
        - 4.0 * y * (g(0, 0) + g(2, 2));
    let vz = 2.0 * (w * (g(1, 0) - g(0, 1)) + x * (g(0, 2) + g(2, 0)) + y * (g(1, 2) + g(2, 1)))
        - 4.0 * z * (g(0, 0) + g(1, 1));
    // Through the normalisation: remove the radial part, divide by the length.
    let dot = vw * w + vx * x + vy * y + vz * z;
    [
        (vw - w * dot) / len,
        (vx - x * dot) / len,
        (vy - y * dot) / len,
        (vz - z * dot) / len,
    ]
}

/// Frustum limits of `x/z` and `y/z` used by the Jacobian clamp: `(neg_x, pos_x, neg_y, pos_y)`.
#[inline]
pub(crate) fn clamp_limits(cam: &Camera) -> [f32; 4] {
    let tan_fovx = 0.5 * cam.width as f32 / cam.fx;
    let tan_fovy = 0.5 * cam.height as f32 / cam.fy;
    [
        cam.cx / cam.fx + JACOBIAN_CLAMP_MARGIN * tan_fovx,
        (cam.width as f32 - cam.cx) / cam.fx + JACOBIAN_CLAMP_MARGIN * tan_fovx,
        cam.cy / cam.fy + JACOBIAN_CLAMP_MARGIN * tan_fovy,
        (cam.height as f32 - cam.cy) / cam.fy + JACOBIAN_CLAMP_MARGIN * tan_fovy,
    ]
}
