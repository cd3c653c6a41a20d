//! Projection of one Gaussian at a time and its backward pass: the rules of
//! [`crate::cpu::project`], written for one Gaussian, which the lane kernels
//! ([`crate::cpu::project::lanes`]) are tested against.

use glam::{Mat3, Vec2, Vec3};

use crate::camera::Camera;
use crate::conventions::{ALPHA_THRESHOLD, COV2D_BLUR, MAX_EXTENT_SIGMAS};
use crate::cpu::project::{clamp_limits, quat_to_rotmat, rotation_backward};
use crate::cpu::stages::{ParamGrad, Projected, ScreenGrad};
use crate::model::{Gaussians, sigmoid};
use crate::sh;

/// Gradient of `quat_to_rotmat` with respect to the raw quaternion, given `v_r` = dL/dR.
fn quat_to_rotmat_backward(qn: [f32; 4], len: f32, v_r: Mat3) -> [f32; 4] {
    if len.is_nan() || len <= 0.0 {
        return [0.0; 4];
    }
    // dL/dR[row][col]; glam is column-major.
    let rows: [[f32; 3]; 3] = std::array::from_fn(|i| std::array::from_fn(|j| v_r.col(j)[i]));
    rotation_backward(qn, len, &rows)
}

/// Quantities shared by the forward and the backward pass (recomputed in the backward rather
/// than stored, which is cheap next to rasterization and saves memory).
struct Geometry {
    rot: Mat3,
    qn: [f32; 4],
    qlen: f32,
    scale: Vec3,
    /// `R diag(s)`.
    m: Mat3,
    cov_cam: Mat3,
    p_cam: Vec3,
    j0: Vec3,
    j1: Vec3,
    /// Jacobian evaluation point `(tx, ty)` (the clamped `x`, `y`).
    txy: [f32; 2],
    clamped: [bool; 2],
    /// Screen covariance before the low-pass.
    cov: [f32; 3],
}

#[inline]
fn geometry(g: &Gaussians, i: usize, cam: &Camera, lim: &[f32; 4]) -> Option<Geometry> {
    let p_cam = cam.rotation * g.means[i] + cam.translation;
    let z = p_cam.z;
    if !(p_cam.is_finite() && (cam.near..=cam.far).contains(&z)) {
        return None;
    }
    let (rot, qn, qlen) = quat_to_rotmat(g.rotations[i]);
    let scale = g.log_scales[i].exp();
    let m = rot * Mat3::from_diagonal(scale);
    let cov_world = m * m.transpose();
    let cov_cam = cam.rotation * cov_world * cam.rotation.transpose();
    let (rx, ry) = (p_cam.x / z, p_cam.y / z);
    let cx = rx.clamp(-lim[0], lim[1]);
    let cy = ry.clamp(-lim[2], lim[3]);
    let (tx, ty) = (z * cx, z * cy);
    let rz = 1.0 / z;
    let rz2 = rz * rz;
    let j0 = Vec3::new(cam.fx * rz, 0.0, -cam.fx * tx * rz2);
    let j1 = Vec3::new(0.0, cam.fy * rz, -cam.fy * ty * rz2);
    let s0 = cov_cam * j0;
    let s1 = cov_cam * j1;
    let cov = [j0.dot(s0), j0.dot(s1), j1.dot(s1)];
    if !cov.iter().all(|v| v.is_finite()) {
        return None;
    }
    Some(Geometry {
        rot,
        qn,
        qlen,
        scale,
        m,
        cov_cam,
        p_cam,
        j0,
        j1,
        txy: [tx, ty],
        clamped: [cx != rx, cy != ry],
        cov,
    })
}

/// Projects Gaussian `i`; returns `None` when it is culled.
#[inline]
pub fn project_one(
    g: &Gaussians,
    i: usize,
    cam: &Camera,
    sh_degree: u32,
    antialiased: bool,
    cam_pos: Vec3,
) -> Option<Projected> {
    let lim = clamp_limits(cam);
    let geo = geometry(g, i, cam, &lim)?;
    let [a, b, c] = geo.cov;
    let (ab, cb) = (a + COV2D_BLUR, c + COV2D_BLUR);
    let det_b = ab * cb - b * b;
    if !(det_b.is_finite() && det_b > 0.0) {
        return None;
    }
    let mut opacity = sigmoid(g.logit_opacities[i]);
    if antialiased {
        let det = a * c - b * b;
        opacity *= (det / det_b).max(0.0).sqrt();
    }
    if opacity.is_nan() || opacity < ALPHA_THRESHOLD {
        return None;
    }
    let extent = MAX_EXTENT_SIGMAS.min((2.0 * (opacity / ALPHA_THRESHOLD).ln()).sqrt());
    let rad_x = (extent * ab.sqrt()).ceil();
    let rad_y = (extent * cb.sqrt()).ceil();
    let z = geo.p_cam.z;
    let mean2d = Vec2::new(
        cam.fx * geo.p_cam.x / z + cam.cx,
        cam.fy * geo.p_cam.y / z + cam.cy,
    );
    if !(mean2d.x + rad_x > 0.0
        && mean2d.x - rad_x < cam.width as f32
        && mean2d.y + rad_y > 0.0
        && mean2d.y - rad_y < cam.height as f32)
    {
        return None;
    }
    let inv = 1.0 / det_b;
    let conic = [cb * inv, -b * inv, ab * inv];
    if !conic.iter().all(|v| v.is_finite()) {
        return None;
    }
    let color = if sh_degree == 0 {
        sh::sh_dc_to_rgb(g.sh_dc[i]).max(Vec3::ZERO)
    } else {
        let dir = (g.means[i] - cam_pos).normalize_or_zero();
        sh::eval(sh_degree, g.sh_dc[i], g.sh_rest_of(i), dir).max(Vec3::ZERO)
    };
    if !color.is_finite() {
        return None;
    }
    // Clamped only so the radius stays representable as i32 (far beyond any image).
    let big = (1u32 << 30) as f32;
    Some(Projected {
        mean2d,
        conic,
        depth: z,
        opacity,
        color,
        radius: [rad_x.min(big) as i32, rad_y.min(big) as i32],
    })
}

/// Backward of [`project_one`] for a visible Gaussian whose forward colour was `color` (after
/// the clamp at zero; it tells which channels the clamp stopped, so the SH need not be
/// evaluated again). Writes SH rest gradients into `v_rest` (which must be zeroed,
/// `rest_count` long).
#[allow(clippy::too_many_arguments)]
pub fn project_backward_one(
    g: &Gaussians,
    i: usize,
    cam: &Camera,
    sh_degree: u32,
    antialiased: bool,
    cam_pos: Vec3,
    color: Vec3,
    v: &ScreenGrad,
    v_rest: &mut [Vec3],
) -> ParamGrad {
    let mut out = ParamGrad::default();
    let lim = clamp_limits(cam);
    let Some(geo) = geometry(g, i, cam, &lim) else {
        return out;
    };
    let [a, b, c] = geo.cov;
    let (ab, cb) = (a + COV2D_BLUR, c + COV2D_BLUR);
    let det_b = ab * cb - b * b;
    let inv = 1.0 / det_b;
    let (qa, qb, qc) = (cb * inv, -b * inv, ab * inv);

    // Conic -> blurred covariance: dCov = -Q V Q with V = [[va, vb/2], [vb/2, vc]].
    let (va, vb, vc) = (v.conic[0], 0.5 * v.conic[1], v.conic[2]);
    let (qv00, qv01, qv10, qv11) = (
        qa * va + qb * vb,
        qa * vb + qb * vc,
        qb * va + qc * vb,
        qb * vb + qc * vc,
    );
    let h00 = -(qv00 * qa + qv01 * qb);
    let h01 = -(qv00 * qb + qv01 * qc);
    let h11 = -(qv10 * qb + qv11 * qc);
    // Gradient w.r.t. (a, b, c) where b is the single off-diagonal value.
    let mut g_cov = [h00, 2.0 * h01, h11];

    // Opacity (and antialiasing compensation).
    let sig = sigmoid(g.logit_opacities[i]);
    let mut v_sig = v.opacity;
    if antialiased {
        let det = a * c - b * b;
        let r = det / det_b;
        if r > 0.0 {
            let comp = r.sqrt();
            v_sig = v.opacity * comp;
            let v_r = v.opacity * sig * 0.5 / comp;
            // r = det/det_b: dr = ddet/det_b - det ddet_b/det_b².
            let k = det / (det_b * det_b);
            g_cov[0] += v_r * (c / det_b - k * cb);
            g_cov[1] += v_r * (-2.0 * b / det_b + k * 2.0 * b);
            g_cov[2] += v_r * (a / det_b - k * ab);
        } else {
            v_sig = 0.0;
        }
    }
    out.logit_opacity = v_sig * sig * (1.0 - sig);

    // cov = [j0·Σc j0, j0·Σc j1, j1·Σc j1].
    let (ga, gb, gc) = (g_cov[0], g_cov[1], g_cov[2]);
    let (j0, j1) = (geo.j0, geo.j1);
    let s0 = geo.cov_cam * j0;
    let s1 = geo.cov_cam * j1;
    let v_j0 = 2.0 * ga * s0 + gb * s1;
    let v_j1 = gb * s0 + 2.0 * gc * s1;
    let outer = |u: Vec3, w: Vec3| Mat3::from_cols(u * w.x, u * w.y, u * w.z);
    let v_cov_cam = outer(j0, j0) * ga + outer(j0, j1) * gb + outer(j1, j1) * gc;
    let v_cov_world = cam.rotation.transpose() * v_cov_cam * cam.rotation;
    let v_m = (v_cov_world + v_cov_world.transpose()) * geo.m;
    let v_rot = Mat3::from_cols(
        v_m.x_axis * geo.scale.x,
        v_m.y_axis * geo.scale.y,
        v_m.z_axis * geo.scale.z,
    );
    let v_scale = Vec3::new(
        geo.rot.x_axis.dot(v_m.x_axis),
        geo.rot.y_axis.dot(v_m.y_axis),
        geo.rot.z_axis.dot(v_m.z_axis),
    );
    out.log_scale = v_scale * geo.scale;
    out.rotation = quat_to_rotmat_backward(geo.qn, geo.qlen, v_rot);

    // Camera-space mean: through the mean projection and the Jacobian.
    let (x, y, z) = (geo.p_cam.x, geo.p_cam.y, geo.p_cam.z);
    let (fx, fy) = (cam.fx, cam.fy);
    let rz = 1.0 / z;
    let rz2 = rz * rz;
    let rz3 = rz2 * rz;
    let mut v_pc = Vec3::new(
        v.mean2d.x * fx * rz,
        v.mean2d.y * fy * rz,
        -(v.mean2d.x * fx * x + v.mean2d.y * fy * y) * rz2 + v.depth,
    );
    let [tx, ty] = geo.txy;
    v_pc.z += -fx * rz2 * v_j0.x - fy * rz2 * v_j1.y;
    if geo.clamped[0] {
        v_pc.z += fx * tx * rz3 * v_j0.z;
    } else {
        v_pc.x += -fx * rz2 * v_j0.z;
        v_pc.z += 2.0 * fx * tx * rz3 * v_j0.z;
    }
    if geo.clamped[1] {
        v_pc.z += fy * ty * rz3 * v_j1.z;
    } else {
        v_pc.y += -fy * rz2 * v_j1.z;
        v_pc.z += 2.0 * fy * ty * rz3 * v_j1.z;
    }
    out.mean = cam.rotation.transpose() * v_pc;

    // Colour: the clamp at zero passes gradient only where it did not clamp, i.e. where the
    // clamped colour `max(pre, 0)` is positive, which is where `pre` is.
    let raw = g.means[i] - cam_pos;
    let len = raw.length();
    let dir = if len > 0.0 { raw / len } else { Vec3::ZERO };
    let v_color = Vec3::select(color.cmpgt(Vec3::ZERO), v.color, Vec3::ZERO);
    let v_dir = sh::eval_backward(
        sh_degree,
        g.sh_rest_of(i),
        dir,
        v_color,
        &mut out.sh_dc,
        v_rest,
    );
    if len > 0.0 && sh_degree > 0 {
        out.mean += (v_dir - dir * dir.dot(v_dir)) / len;
    }

    // Degenerate inputs (e.g. overflowing scales) must not leak NaN/Inf into the optimiser.
    let finite = out.mean.is_finite()
        && out.log_scale.is_finite()
        && out.rotation.iter().all(|v| v.is_finite())
        && out.logit_opacity.is_finite()
        && out.sh_dc.is_finite()
        && v_rest.iter().all(|v| v.is_finite());
    if !finite {
        v_rest.fill(Vec3::ZERO);
        return ParamGrad::default();
    }
    out
}
