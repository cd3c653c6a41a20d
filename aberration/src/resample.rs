//! Resolution mapping: using a PSF grid defined for one sensor on an image of another size.
//!
//! The rule: a grid of G×G PSFs of K px is defined for a square sensor of `G·K` px (the
//! paper's 9 × 135 = 1215). An image of W×H px is taken to span that sensor along its
//! longer side, so one sensor pixel is `s = max(W, H) / (G·K)` image pixels. Every PSF is area-resampled by `s` about its centre
//! pixel to `K'` = the smallest odd size covering `K·s` pixels, so no energy is lost and each
//! channel keeps unit sum. The G×G grid is then laid over the whole image (stretched along
//! the shorter side), exactly as the paper tiles its images.

use crate::error::{AberrationError, Result};
use crate::psf_grid::PsfGrid;
use rayon::prelude::*;

/// Output size for resampling `k` pixels by `scale`: odd, and covering all of the input.
/// Largest PSF side (px) a grid may be mapped to on an image.
pub const MAX_MAPPED_PSF_PX: usize = 1024;

pub fn resampled_size(k: usize, scale: f64) -> usize {
    let mut n = (k as f64 * scale - 1e-9).ceil().max(1.0) as usize;
    if n.is_multiple_of(2) {
        n += 1;
    }
    n
}

/// Separable area-overlap weights `w[i * k + j]`: how much of input pixel `j` falls into
/// output pixel `i`, when output pixels are `1/scale` input pixels wide and both centre
/// pixels (`k/2`, `n/2`) share one centre.
pub fn area_weights(k: usize, n: usize, scale: f64) -> Vec<f64> {
    let (ci, co) = ((k / 2) as f64, (n / 2) as f64);
    let mut w = vec![0.0; n * k];
    for i in 0..n {
        let lo = (i as f64 - co - 0.5) / scale;
        let hi = (i as f64 - co + 0.5) / scale;
        for j in 0..k {
            let a = j as f64 - ci - 0.5;
            let b = a + 1.0;
            w[i * k + j] = (hi.min(b) - lo.max(a)).max(0.0);
        }
    }
    w
}

impl PsfGrid {
    /// Every PSF area-resampled by `scale` output pixels per input pixel.
    pub fn resampled(&self, scale: f64) -> PsfGrid {
        let k = self.size();
        if (scale - 1.0).abs() < 1e-12 {
            return self.clone();
        }
        let n = resampled_size(k, scale);
        let w = area_weights(k, n, scale);
        // Each output pixel overlaps only a few input pixels: keep those ranges.
        let spans: Vec<std::ops::Range<usize>> = (0..n)
            .map(|i| {
                let row = &w[i * k..(i + 1) * k];
                let a = row.iter().position(|v| *v > 0.0).unwrap_or(0);
                let b = row.iter().rposition(|v| *v > 0.0).map_or(a, |b| b + 1);
                a..b
            })
            .collect();
        let data: Vec<f32> = (0..self.grid() * self.grid() * 3)
            .into_par_iter()
            .flat_map_iter(|idx| {
                let src = self.kernel(idx / 3, idx % 3);
                // Rows first (n x k), then columns (n x n).
                let mut tmp = vec![0.0f64; n * k];
                for (i, span) in spans.iter().enumerate() {
                    for y in span.clone() {
                        let wy = w[i * k + y];
                        for x in 0..k {
                            tmp[i * k + x] += wy * src[y * k + x] as f64;
                        }
                    }
                }
                let mut out = vec![0.0f32; n * n];
                for i in 0..n {
                    for (j, span) in spans.iter().enumerate() {
                        let v: f64 = span.clone().map(|x| w[j * k + x] * tmp[i * k + x]).sum();
                        out[i * n + j] = v as f32;
                    }
                }
                out
            })
            .collect();
        PsfGrid::from_planar(self.grid(), n, data).expect("area resampling keeps PSFs valid")
    }

    /// The sensor size (px) that maps this grid's PSFs to about `psf_px` pixels on a
    /// `width × height` image: the `sensor_px` of [`Self::for_image`] for a chosen blur scale
    /// (`restorer eval --psf-px`, training pairs drawn over scales). A mapped side is odd, so
    /// an even `psf_px` lands on a neighbour.
    pub fn sensor_for_psf_px(&self, width: usize, height: usize, psf_px: usize) -> usize {
        let (side, k) = (width.max(height) as f64, self.size() as f64);
        let exact = side * k / psf_px.max(1) as f64;
        // Of the whole sensors about the exact one, the one whose mapped side is nearest,
        // then whose blur scale is nearest.
        let miss = |sensor: usize| {
            let n = self.mapped_size(width, height, Some(sensor)) as f64;
            let scale = side / sensor as f64;
            ((n - psf_px as f64).abs(), (k * scale - psf_px as f64).abs())
        };
        let lo = (exact.floor() as usize).max(2) - 1;
        (lo..lo + 3)
            .min_by(|a, b| miss(*a).partial_cmp(&miss(*b)).expect("finite"))
            .expect("three candidates")
    }

    /// The PSF side [`Self::for_image`] maps this grid to on a `width × height` image, without
    /// resampling a kernel (a sensor of 0 px counts as 1).
    pub fn mapped_size(&self, width: usize, height: usize, sensor_px: Option<usize>) -> usize {
        let sensor = sensor_px.unwrap_or(self.native_sensor_px()).max(1);
        resampled_size(self.size(), width.max(height) as f64 / sensor as f64)
    }

    /// The grid mapped onto a `width × height` image by the module's rule; `sensor_px`
    /// overrides the native sensor size `G·K`. Refused, before anything is allocated, when the
    /// mapped PSFs would be larger than [`MAX_MAPPED_PSF_PX`] or than twice the image (a sensor
    /// size far below the image's is a mistake, not an optical system).
    pub fn for_image(
        &self,
        width: usize,
        height: usize,
        sensor_px: Option<usize>,
    ) -> Result<PsfGrid> {
        let sensor = sensor_px.unwrap_or(self.native_sensor_px());
        if sensor == 0 {
            return Err(AberrationError::BadParameter("a sensor of 0 px".into()));
        }
        let scale = width.max(height) as f64 / sensor as f64;
        let n = self.mapped_size(width, height, Some(sensor));
        let limit = MAX_MAPPED_PSF_PX.min(2 * width.max(height)).max(1);
        if n > limit {
            return Err(AberrationError::BadParameter(format!(
                "a {}x{} image on a sensor of {sensor} px maps the grid's {} px PSFs to {n} px \
                 (at most {limit}): check the sensor size",
                width,
                height,
                self.size()
            )));
        }
        Ok(self.resampled(scale))
    }
}
