//! Undistortion at load: a photo taken through a lens with radial-tangential distortion
//! (COLMAP's SIMPLE_RADIAL, RADIAL, OPENCV and FULL_OPENCV, nerfstudio's OPENCV) is resampled onto the
//! pinhole camera with the same intrinsics and size, the camera every renderer here draws.
//! Output pixel centre `(u, v)` looks along the normalised ray `((u - cx)/fx, (v - cy)/fy)`;
//! the lens images that ray at [`Distortion::distort`] of it, where the photo is sampled
//! bilinearly. A ray the photo does not hold (beyond its border, where barrel distortion
//! pulls the field in) keeps the nearest border pixel and is left out of the loss by
//! [`Remap::valid`].
//!
//! Order, for a metalens: the lens forms one image, distorted and blurred in the sensor
//! plane, so the PSF grid belongs to the sensor's (distorted) coordinates. Undistorting the
//! photo first and blurring renders in the pinhole frame takes the PSF as unwarped by the
//! undistortion, whose local scale differs from 1 by about `3 k1 r²`: a few percent at the
//! corners for the distortions captures have, an error the PSF-mismatch sweep measures as
//! nothing (a 5 % PSF scale error costs no held-out PSNR), and `tests/undistort.rs` bounds
//! against the blur itself.

use rayon::prelude::*;

use crate::camera::{Camera, Distortion};
use crate::images::Photo;

/// Where each output pixel samples the photo, for one camera's intrinsics.
#[derive(Clone, Debug)]
pub struct Remap {
    pub width: u32,
    pub height: u32,
    /// Source position (pixel units, centres at `+0.5`) of each output pixel, row-major.
    pub source: Vec<(f32, f32)>,
    /// Whether the source lies inside the photo, per output pixel.
    pub valid: Vec<bool>,
    /// XXH3 of the source positions: what a photo cached after this remap is keyed by.
    pub fingerprint: u64,
}

impl Remap {
    /// The remap of `camera` through `d`.
    pub fn new(camera: &Camera, d: &Distortion) -> Remap {
        let (w, h) = (camera.width, camera.height);
        let mut source = Vec::with_capacity(w as usize * h as usize);
        let mut valid = Vec::with_capacity(source.capacity());
        for y in 0..h {
            for x in 0..w {
                let (u, v) = (x as f64 + 0.5, y as f64 + 0.5);
                let (xd, yd) = d.distort((u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy);
                let (su, sv) = (xd * camera.fx + camera.cx, yd * camera.fy + camera.cy);
                let inside = su.is_finite()
                    && sv.is_finite()
                    && (0.0..=w as f64).contains(&su)
                    && (0.0..=h as f64).contains(&sv);
                source.push((su as f32, sv as f32));
                valid.push(inside);
            }
        }
        let bytes: Vec<u8> = source
            .iter()
            .flat_map(|&(u, v)| [u.to_le_bytes(), v.to_le_bytes()])
            .flatten()
            .collect();
        Remap {
            width: w,
            height: h,
            fingerprint: base::hash::xxh3(&bytes),
            source,
            valid,
        }
    }

    /// How many output pixels have no source in the photo.
    pub fn invalid_count(&self) -> usize {
        self.valid.iter().filter(|v| !**v).count()
    }

    /// `photo` resampled onto the pinhole camera (same size).
    pub fn apply(&self, photo: &Photo) -> Photo {
        let (w, h) = (photo.width as usize, photo.height as usize);
        let mut data = vec![0.0f32; w * h * 3];
        data.par_chunks_mut(w * 3).enumerate().for_each(|(y, row)| {
            for x in 0..w {
                let (su, sv) = self.source[y * w + x];
                row[3 * x..3 * x + 3].copy_from_slice(&bilinear(photo, su, sv));
            }
        });
        Photo {
            width: photo.width,
            height: photo.height,
            data,
        }
    }

    /// A per-pixel map (1, 0 or in between) resampled like [`Self::apply`], with the pixels
    /// that have no source set to 0.
    pub fn apply_mask(&self, mask: Option<&[f32]>) -> Vec<f32> {
        let (w, h) = (self.width as usize, self.height as usize);
        (0..w * h)
            .map(|i| {
                if !self.valid[i] {
                    return 0.0;
                }
                let Some(m) = mask else { return 1.0 };
                let (su, sv) = self.source[i];
                let (x, y) = (
                    (su - 0.5).round().clamp(0.0, (w - 1) as f32) as usize,
                    (sv - 0.5).round().clamp(0.0, (h - 1) as f32) as usize,
                );
                m[y * w + x]
            })
            .collect()
    }
}

/// The photo at pixel position `(u, v)` (centres at `+0.5`), bilinear, clamped at the border.
fn bilinear(photo: &Photo, u: f32, v: f32) -> [f32; 3] {
    let (w, h) = (photo.width as i64, photo.height as i64);
    let (fx, fy) = (u - 0.5, v - 0.5);
    let (x0, y0) = (fx.floor(), fy.floor());
    let (tx, ty) = (fx - x0, fy - y0);
    let at = |x: i64, y: i64| photo.pixel(x.clamp(0, w - 1) as u32, y.clamp(0, h - 1) as u32);
    let (x0, y0) = (x0 as i64, y0 as i64);
    let (a, b, c, d) = (
        at(x0, y0),
        at(x0 + 1, y0),
        at(x0, y0 + 1),
        at(x0 + 1, y0 + 1),
    );
    std::array::from_fn(|k| {
        let top = a[k] * (1.0 - tx) + b[k] * tx;
        let bottom = c[k] * (1.0 - tx) + d[k] * tx;
        top * (1.0 - ty) + bottom * ty
    })
}
