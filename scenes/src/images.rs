//! Image folders: listing, size checks, decoding to f32 and PNG encoding.
//!
//! Decoded images are interleaved RGB, row-major (`data[(y * width + x) * 3 + c]`), holding the
//! file's values divided by the format's maximum (255 or 65535): no sRGB decoding, so values are
//! "linear in the file". Alpha is dropped, grey is replicated to three channels.

use std::path::{Path, PathBuf};

use image::{DynamicImage, ImageBuffer, ImageFormat, Rgb};

use crate::atomic;
use crate::error::{Result, SceneError};

/// An RGB image with f32 samples in `[0, 1]`, interleaved and row-major.
#[derive(Clone, Debug, PartialEq)]
pub struct Photo {
    pub width: u32,
    pub height: u32,
    pub data: Vec<f32>,
}

impl Photo {
    pub fn pixel(&self, x: u32, y: u32) -> [f32; 3] {
        let i = (y as usize * self.width as usize + x as usize) * 3;
        [self.data[i], self.data[i + 1], self.data[i + 2]]
    }

    /// `n` times smaller on each side by the area filter (each pixel the mean of an `n × n`
    /// block), as LLFF's `images_N/` are made; a remainder of fewer than `n` rows or columns
    /// is dropped, as integer division sizes them.
    pub fn shrunk(&self, n: u32) -> Photo {
        let n = n.max(1);
        let (w, h) = (self.width / n, self.height / n);
        let mut data = Vec::with_capacity(w as usize * h as usize * 3);
        let scale = 1.0 / (n * n) as f32;
        for y in 0..h {
            for x in 0..w {
                let mut sum = [0.0f32; 3];
                for dy in 0..n {
                    for dx in 0..n {
                        let p = self.pixel(x * n + dx, y * n + dy);
                        for c in 0..3 {
                            sum[c] += p[c];
                        }
                    }
                }
                data.extend(sum.map(|v| v * scale));
            }
        }
        Photo {
            width: w,
            height: h,
            data,
        }
    }
}

/// Sample depth of written PNGs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum BitDepth {
    #[default]
    Eight,
    Sixteen,
}

const EXTENSIONS: [&str; 3] = ["png", "jpg", "jpeg"];

fn is_image(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| EXTENSIONS.iter().any(|x| e.eq_ignore_ascii_case(x)))
}

/// The images of a folder sorted by file name (byte order, as LLFF's `sorted(os.listdir)`).
/// Files with other extensions are ignored; an empty result is an error.
pub fn list_images(dir: &Path) -> Result<Vec<PathBuf>> {
    if !dir.is_dir() {
        return Err(SceneError::NotFound {
            path: dir.to_path_buf(),
            what: "image folder".into(),
        });
    }
    let entries = std::fs::read_dir(dir).map_err(|e| SceneError::io(dir, e))?;
    let mut paths = Vec::new();
    for entry in entries {
        let path = entry.map_err(|e| SceneError::io(dir, e))?.path();
        if path.is_file() && is_image(&path) {
            paths.push(path);
        }
    }
    if paths.is_empty() {
        return Err(SceneError::NoImages {
            dir: dir.to_path_buf(),
        });
    }
    paths.sort_by(|a, b| a.file_name().cmp(&b.file_name()));
    Ok(paths)
}

/// A reader of the image file `path`: a regular file alone ([`base::input`]), its format
/// read from its first bytes (PNG data in a file named `.jpg` is a PNG), else from its name.
fn reader(path: &Path) -> Result<image::ImageReader<std::io::BufReader<std::fs::File>>> {
    let file = base::input::open(path).map_err(|e| SceneError::io(path, e))?;
    let mut r = image::ImageReader::new(std::io::BufReader::new(file))
        .with_guessed_format()
        .map_err(|e| SceneError::io(path, e))?;
    if r.format().is_none()
        && let Ok(f) = image::ImageFormat::from_path(path)
    {
        r.set_format(f);
    }
    Ok(r)
}

/// The decoded image at `path`, after its header's size is checked ([`image_size`]).
fn decode(path: &Path) -> Result<image::DynamicImage> {
    image_size(path)?;
    reader(path)?.decode().map_err(|source| SceneError::Image {
        path: path.to_path_buf(),
        source,
    })
}

/// Reads only the headers, so checking a folder costs no decoding; a header claiming more
/// than [`base::limits::MAX_IMAGE_PIXELS`] is refused.
pub fn image_size(path: &Path) -> Result<(u32, u32)> {
    let (w, h) = reader(path)?
        .into_dimensions()
        .map_err(|source| SceneError::Image {
            path: path.to_path_buf(),
            source,
        })?;
    base::limits::check_image_pixels(w, h).map_err(|p| SceneError::invalid(path, p))?;
    Ok((w, h))
}

/// The common size of all images, or an error naming the first one that differs.
pub fn common_size(paths: &[PathBuf]) -> Result<(u32, u32)> {
    let Some(first) = paths.first() else {
        return Err(SceneError::invalid(".", "no image paths given"));
    };
    let expected = image_size(first)?;
    for path in &paths[1..] {
        let found = image_size(path)?;
        if found != expected {
            return Err(SceneError::ImageSizeMismatch {
                path: path.clone(),
                first: first.clone(),
                expected,
                found,
            });
        }
    }
    Ok(expected)
}

pub fn load_rgb(path: &Path) -> Result<Photo> {
    let decoded = decode(path)?;
    let rgb = decoded.to_rgb32f();
    Ok(Photo {
        width: rgb.width(),
        height: rgb.height(),
        data: rgb.into_raw(),
    })
}

/// A grey image (a mask) as a [`Photo`] with three equal channels (a colour image's
/// luminance).
pub fn load_grey(path: &Path) -> Result<Photo> {
    let decoded = decode(path)?;
    let grey = decoded.to_luma32f();
    Ok(Photo {
        width: grey.width(),
        height: grey.height(),
        data: grey.into_raw().into_iter().flat_map(|v| [v; 3]).collect(),
    })
}

/// The alpha channel of a photo as a [`Photo`] of three equal channels, None when the photo
/// has no alpha.
pub fn load_alpha(path: &Path) -> Result<Option<Photo>> {
    let decoded = decode(path)?;
    if !decoded.color().has_alpha() {
        return Ok(None);
    }
    let rgba = decoded.to_rgba32f();
    Ok(Some(Photo {
        width: rgba.width(),
        height: rgba.height(),
        data: rgba.pixels().flat_map(|p| [p.0[3]; 3]).collect(),
    }))
}

/// Writes a PNG under a temporary name and renames it; samples are clamped to `[0, 1]` and
/// rounded to the nearest code.
pub fn write_png(path: &Path, image: &Photo, depth: BitDepth) -> Result<()> {
    let expected = image.width as usize * image.height as usize * 3;
    if image.data.len() != expected {
        return Err(SceneError::invalid(
            path,
            format!(
                "image buffer holds {} samples, {}x{} RGB needs {expected}",
                image.data.len(),
                image.width,
                image.height
            ),
        ));
    }
    let dynamic = match depth {
        BitDepth::Eight => {
            let raw = image
                .data
                .iter()
                .map(|&v| quantise(v, 255.0) as u8)
                .collect();
            DynamicImage::ImageRgb8(
                ImageBuffer::<Rgb<u8>, _>::from_raw(image.width, image.height, raw)
                    .expect("length checked above"),
            )
        }
        BitDepth::Sixteen => {
            let raw = image
                .data
                .iter()
                .map(|&v| quantise(v, 65535.0) as u16)
                .collect();
            DynamicImage::ImageRgb16(
                ImageBuffer::<Rgb<u16>, _>::from_raw(image.width, image.height, raw)
                    .expect("length checked above"),
            )
        }
    };
    atomic::write_file(path, |w| {
        dynamic
            .write_to(w, ImageFormat::Png)
            .map_err(|source| SceneError::Image {
                path: path.to_path_buf(),
                source,
            })
    })
}

fn quantise(v: f32, max: f32) -> f32 {
    // NaN maps to 0 rather than poisoning the file.
    let v = if v.is_nan() { 0.0 } else { v.clamp(0.0, 1.0) };
    (v * max).round()
}
