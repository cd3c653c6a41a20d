//! Pinhole camera.
//!
//! Convention (OpenCV, same as gsplat): camera space has +x right, +y down, +z forward (the
//! camera looks along +z). `rotation`/`translation` map world to camera:
//! `p_cam = rotation * p_world + translation`. A camera-space point projects to pixel
//! coordinates `(fx * x / z + cx, fy * y / z + cy)`, where pixel `(i, j)` covers
//! `[i, i+1) x [j, j+1)` and has its centre at `(i + 0.5, j + 0.5)`; so `cx = width / 2` puts
//! the principal point at the image centre.

use glam::{Mat3, Vec3};

use crate::error::SplatError;

#[derive(Clone, Debug, PartialEq)]
pub struct Camera {
    pub fx: f32,
    pub fy: f32,
    pub cx: f32,
    pub cy: f32,
    pub width: u32,
    pub height: u32,
    /// World-to-camera rotation (orthonormal, det +1).
    pub rotation: Mat3,
    /// World-to-camera translation.
    pub translation: Vec3,
    /// Gaussians with camera-space depth `z < near` or `z > far` are culled (`z == near` is kept,
    /// as in gsplat); `near` must be positive so the projection never divides by zero.
    pub near: f32,
    pub far: f32,
}

impl Camera {
    /// Camera at `eye` looking at `target`; `up` is the world direction that appears up in the
    /// image (so camera +y, which points down, is `-up` made orthogonal to the view direction).
    #[allow(clippy::too_many_arguments)]
    pub fn look_at(
        eye: Vec3,
        target: Vec3,
        up: Vec3,
        fx: f32,
        fy: f32,
        width: u32,
        height: u32,
    ) -> Self {
        let forward = (target - eye).normalize();
        let right = forward.cross(up).normalize();
        let down = forward.cross(right);
        let rotation = Mat3::from_cols(right, down, forward).transpose();
        Self {
            fx,
            fy,
            cx: width as f32 * 0.5,
            cy: height as f32 * 0.5,
            width,
            height,
            rotation,
            translation: -(rotation * eye),
            near: 0.01,
            far: 1e10,
        }
    }

    /// The same pose seeing the same vertical field of view at another image size (a resized
    /// window, a lower-resolution render): focal lengths scale with the height, so pixels stay
    /// the shape they were, and the principal point keeps its relative position. For the
    /// same aspect ratio this is a plain rescale of the image.
    pub fn resized(&self, width: u32, height: u32) -> Self {
        let s = height as f32 / self.height as f32;
        Self {
            fx: self.fx * s,
            fy: self.fy * s,
            cx: self.cx * width as f32 / self.width as f32,
            cy: self.cy * s,
            width,
            height,
            ..self.clone()
        }
    }

    /// A camera circling `center` at `distance`: `angle` radians around the vertical axis and
    /// `elevation` radians above the horizon, looking at the centre with a vertical field of
    /// view of `fov_y` radians. Up is −y, as in captures (OpenCV frames have +y down).
    #[allow(clippy::too_many_arguments)]
    pub fn orbit(
        center: Vec3,
        distance: f32,
        angle: f32,
        elevation: f32,
        fov_y: f32,
        width: u32,
        height: u32,
    ) -> Self {
        let dir = Vec3::new(
            elevation.cos() * angle.sin(),
            -elevation.sin(),
            -elevation.cos() * angle.cos(),
        );
        let f = 0.5 * height as f32 / (0.5 * fov_y).tan();
        Self::look_at(
            center + dir * distance,
            center,
            Vec3::NEG_Y,
            f,
            f,
            width,
            height,
        )
    }

    /// Camera centre in world space.
    pub fn position(&self) -> Vec3 {
        -(self.rotation.transpose() * self.translation)
    }

    pub fn num_pixels(&self) -> usize {
        self.width as usize * self.height as usize
    }

    pub fn validate(&self) -> Result<(), SplatError> {
        let bad = |m: String| Err(SplatError::InvalidCamera(m));
        if self.width == 0 || self.height == 0 {
            return bad(format!(
                "image size {}x{} is empty",
                self.width, self.height
            ));
        }
        for (name, v) in [("fx", self.fx), ("fy", self.fy)] {
            if !(v.is_finite() && v > 0.0) {
                return bad(format!("{name} = {v} must be finite and positive"));
            }
        }
        if !(self.cx.is_finite() && self.cy.is_finite()) {
            return bad(format!(
                "principal point ({}, {}) is not finite",
                self.cx, self.cy
            ));
        }
        if !(self.near.is_finite() && self.near > 0.0 && self.far > self.near) {
            return bad(format!(
                "near = {}, far = {}: need 0 < near < far",
                self.near, self.far
            ));
        }
        if !self.translation.is_finite() || !self.rotation.is_finite() {
            return bad("pose is not finite".into());
        }
        let err = (self.rotation.transpose() * self.rotation - Mat3::IDENTITY)
            .to_cols_array()
            .iter()
            .fold(0.0f32, |m, v| m.max(v.abs()));
        if err > 1e-3 || self.rotation.determinant() < 0.0 {
            return bad(format!(
                "rotation is not a proper rotation (|RᵀR - I| = {err})"
            ));
        }
        Ok(())
    }
}

/// Centre and radius of the region most splats occupy: the box between the 2nd and 98th
/// percentiles of their means per axis, so a few stray splats do not push a framing camera
/// away. `None` when there are no finite means.
pub fn scene_bounds(means: &[Vec3]) -> Option<(Vec3, f32)> {
    let finite: Vec<Vec3> = means.iter().copied().filter(|m| m.is_finite()).collect();
    if finite.is_empty() {
        return None;
    }
    let pick = |axis: usize, q: f64| {
        let mut v: Vec<f32> = finite.iter().map(|m| m[axis]).collect();
        let i = ((v.len() - 1) as f64 * q).round() as usize;
        *v.select_nth_unstable_by(i, f32::total_cmp).1
    };
    let lo = Vec3::new(pick(0, 0.02), pick(1, 0.02), pick(2, 0.02));
    let hi = Vec3::new(pick(0, 0.98), pick(1, 0.98), pick(2, 0.98));
    Some(((lo + hi) * 0.5, ((hi - lo) * 0.5).length().max(1e-3)))
}
