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
        let reader = || {
            // A regular file alone: a FIFO or a device is refused before it is opened.
            let file = base::input::open(path).map_err(|e| bad(e.to_string()))?;
            image::ImageReader::new(std::io::BufReader::new(file))
                .with_guessed_format()
                .map_err(|e| bad(e.to_string()))
        };
        let (w, h) = reader()?
            .into_dimensions()
            .map_err(|e| bad(e.to_string()))?;
        base::limits::check_image_pixels(w, h).map_err(bad)?;
        let dynimg = reader()?.decode().map_err(|e| bad(e.to_string()))?;
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
    base::write_atomically(path, |w| {
        img.write_to(w, image::ImageFormat::Png)
            .map_err(|e| std::io::Error::other(e.to_string()))
    })
    .map_err(|e| err(e.to_string()))
}

fn same_size(a: &Image, b: &Image) -> Result<()> {
    if (a.width, a.height) != (b.width, b.height) {
        return Err(AberrationError::BadParameter(format!(
            "cannot compare a {}x{} image with a {}x{} one",
            a.width, a.height, b.width, b.height
        )));
    }
    Ok(())
}

/// PSNR in dB of `a` against `b` (the one convention of [`base::metrics`]).
pub fn psnr(a: &Image, b: &Image) -> Result<f64> {
    same_size(a, b)?;
    base::psnr(&a.data, &b.data).map_err(|e| AberrationError::BadParameter(e.to_string()))
}

/// PSNR and SSIM of `image`, clamped to [0, 1] as a saved picture would be, against
/// `reference` ([`base::metrics`]' conventions, as every evaluation in metasplat).
pub fn compare(image: &Image, reference: &Image) -> Result<(f64, f64)> {
    same_size(image, reference)?;
    let mut clamped = image.clone();
    clamped.clamp01();
    let (w, h) = (image.width as u32, image.height as u32);
    let bad = |e: base::BaseError| AberrationError::BadParameter(e.to_string());
    Ok((
        base::psnr(&clamped.data, &reference.data).map_err(bad)?,
        base::ssim_planar(&clamped.data, &reference.data, w, h).map_err(bad)?,
    ))
}
