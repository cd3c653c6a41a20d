//! Conversions between the crates' image and camera types, made once per view when a capture
//! is loaded or an output is saved, never per training step: `splat` renders row-major
//! `Vec<Vec3>` (which the blur and its adjoint also take), `scenes` decodes interleaved
//! `Photo`s, and the Wiener bank and the restorer work on planar `aberration::Image`s.

use aberration::Image;
use glam::{Mat3, Vec3};
use scenes::Photo;

/// Camera-space depths the renderer accepts; LLFF bounds are not used as clip planes because
/// splats may legitimately sit in front of the nearest SfM point.
pub const NEAR: f32 = 0.01;
pub const FAR: f32 = 1e10;

/// A scene camera (OpenCV, f64) as the renderer's camera (OpenCV, f32). Distortion is not
/// applied (the scenes crate reports it).
pub fn splat_camera(c: &scenes::Camera) -> splat::Camera {
    let r = c.world_to_camera.rotation.as_mat3();
    splat::Camera {
        fx: c.fx as f32,
        fy: c.fy as f32,
        cx: c.cx as f32,
        cy: c.cy as f32,
        width: c.width,
        height: c.height,
        rotation: Mat3::from_cols(r.x_axis, r.y_axis, r.z_axis),
        translation: c.world_to_camera.translation.as_vec3(),
        near: NEAR,
        far: FAR,
    }
}

pub fn rgb_to_pixels(img: &Photo) -> Vec<Vec3> {
    img.data
        .chunks_exact(3)
        .map(|p| Vec3::new(p[0], p[1], p[2]))
        .collect()
}

pub fn pixels_to_rgb(pixels: &[Vec3], width: u32, height: u32) -> Photo {
    Photo {
        width,
        height,
        data: pixels.iter().flat_map(|p| p.to_array()).collect(),
    }
}

pub fn pixels_to_image(pixels: &[Vec3], width: u32, height: u32) -> Image {
    let mut img = Image::new(width as usize, height as usize);
    for c in 0..3 {
        for (v, p) in img.channel_mut(c).iter_mut().zip(pixels) {
            *v = p[c];
        }
    }
    img
}

pub fn image_to_pixels(img: &Image) -> Vec<Vec3> {
    let (r, g, b) = (img.channel(0), img.channel(1), img.channel(2));
    (0..img.plane_len())
        .map(|i| Vec3::new(r[i], g[i], b[i]))
        .collect()
}

/// Writes pixels as an 8-bit PNG (atomically), clamped to [0, 1].
pub fn save_pixels(
    path: &std::path::Path,
    pixels: &[Vec3],
    width: u32,
    height: u32,
) -> crate::Result<()> {
    let mut img = pixels_to_image(pixels, width, height);
    img.clamp01();
    img.save_png(path)?;
    Ok(())
}
