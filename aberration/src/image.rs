//! Planar linear RGB images in f32, the currency of the whole imaging model.

use crate::error::{AberrationError, Result};
use std::path::Path;

/// An RGB image stored planar (all red, then green, then blue), row-major within a plane.
/// Planar storage keeps each channel contiguous for the per-channel FFT convolutions.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    pub width: usize,
    pub height: usize,
    /// `3 * width * height` values, channel-major.
    pub data: Vec<f32>,
}

impl Image {
    pub fn new(width: usize, height: usize) -> Self {
        Self {
            width,
            height,
            data: vec![0.0; 3 * width * height],
        }
    }

    pub fn filled(width: usize, height: usize, rgb: [f32; 3]) -> Self {
        let mut img = Self::new(width, height);
        for (c, v) in rgb.iter().enumerate() {
            img.channel_mut(c).fill(*v);
        }
        img
    }

    /// Builds an image from a function of (x, y) returning RGB.
    pub fn from_fn(width: usize, height: usize, f: impl Fn(usize, usize) -> [f32; 3]) -> Self {
        let mut img = Self::new(width, height);
        let plane = width * height;
        for y in 0..height {
            for x in 0..width {
                let v = f(x, y);
                for (c, value) in v.iter().enumerate() {
                    img.data[c * plane + y * width + x] = *value;
                }
            }
        }
        img
    }

    pub fn plane_len(&self) -> usize {
        self.width * self.height
    }

    pub fn channel(&self, c: usize) -> &[f32] {
        let n = self.plane_len();
        &self.data[c * n..(c + 1) * n]
    }

    pub fn channel_mut(&mut self, c: usize) -> &mut [f32] {
        let n = self.plane_len();
        &mut self.data[c * n..(c + 1) * n]
    }

    pub fn get(&self, x: usize, y: usize, c: usize) -> f32 {
        self.data[c * self.plane_len() + y * self.width + x]
    }

    pub fn is_finite(&self) -> bool {
        self.data.iter().all(|v| v.is_finite())
    }

    pub fn clamp01(&mut self) {
        for v in &mut self.data {
            // NaN would survive `clamp`; map it to 0 so nothing non-finite reaches a file.
            *v = if v.is_nan() { 0.0 } else { v.clamp(0.0, 1.0) };
        }
    }

    /// Reads a PNG/JPEG into linear-in-file RGB in [0,1]. Alpha is dropped, 16-bit and
    /// grey images are converted; the error names the file.
    pub fn load(path: &Path) -> Result<Self> {
        let bad = |problem: String| AberrationError::BadImage {
            path: path.to_path_buf(),
            problem,
        };
        if !path.exists() {
            return Err(bad("file not found".into()));
        }
        let dynimg = image::ImageReader::open(path)
            .map_err(|e| bad(e.to_string()))?
            .with_guessed_format()
            .map_err(|e| bad(e.to_string()))?
            .decode()
            .map_err(|e| bad(e.to_string()))?;
        let rgb = dynimg.to_rgb32f();
        let (w, h) = (rgb.width() as usize, rgb.height() as usize);
        if w == 0 || h == 0 {
            return Err(bad("image has zero size".into()));
        }
        let mut img = Self::new(w, h);
        let plane = w * h;
        for (i, px) in rgb.pixels().enumerate() {
            for c in 0..3 {
                img.data[c * plane + i] = px.0[c];
            }
        }
        Ok(img)
    }

    /// Converts to 8-bit RGB, clamping to [0,1] (NaN becomes 0).
    pub fn to_rgb8(&self) -> image::RgbImage {
        let plane = self.plane_len();
        image::RgbImage::from_fn(self.width as u32, self.height as u32, |x, y| {
            let i = y as usize * self.width + x as usize;
            let q = |c: usize| {
                let v = self.data[c * plane + i];
                let v = if v.is_nan() { 0.0 } else { v.clamp(0.0, 1.0) };
                (v * 255.0 + 0.5) as u8
            };
            image::Rgb([q(0), q(1), q(2)])
        })
    }

    /// Writes an 8-bit PNG through a temporary file renamed into place, so an interrupted
    /// write never leaves a truncated image behind.
    pub fn save_png(&self, path: &Path) -> Result<()> {
        save_rgb8_png(&self.to_rgb8(), path)
    }
}

/// Atomic PNG write of an 8-bit image (used by the pictures as well as by [`Image::save_png`]).
pub fn save_rgb8_png(img: &image::RgbImage, path: &Path) -> Result<()> {
    let err = |problem: String| AberrationError::ImageWrite {
        path: path.to_path_buf(),
        problem,
    };
    crate::atomic::write_atomically(path, |file| {
        let mut buf = std::io::BufWriter::new(file);
        img.write_to(&mut buf, image::ImageFormat::Png)
            .map_err(|e| std::io::Error::other(e.to_string()))?;
        use std::io::Write;
        buf.flush()
    })
    .map_err(|e| err(e.to_string()))
}

/// Peak signal-to-noise ratio in dB for signals in [0,1]; identical images give +inf is
/// avoided by flooring the MSE at 1e-20 (200 dB).
pub fn psnr(a: &Image, b: &Image) -> f64 {
    assert_eq!(
        a.data.len(),
        b.data.len(),
        "psnr of images of different sizes"
    );
    let mse = a
        .data
        .iter()
        .zip(&b.data)
        .map(|(x, y)| {
            let d = *x as f64 - *y as f64;
            d * d
        })
        .sum::<f64>()
        / a.data.len().max(1) as f64;
    -10.0 * mse.max(1e-20).log10()
}
