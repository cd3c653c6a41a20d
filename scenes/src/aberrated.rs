//! The aberrated-capture maker: a clean capture in, an LLFF capture out whose images went
//! through a metalens PSF model and sensor noise, with the clean images kept beside them.
//!
//! Layout of the result (everything appears at once, by renaming a staging folder):
//! ```text
//! DIR2/poses_bounds.npy          same poses and bounds as the source
//! DIR2/images_N/*.png            aberrated images (what a metalens camera would record)
//! DIR2/clean/*.png               the source images at the same size, for evaluation
//! DIR2/psf.npy                   the PSF grid the images were made with (a byte copy)
//! DIR2/aberration.json           how: blur mode, sensor size, noise, seed
//! DIR2/sparse/0/{cameras,points3D}.*  copied from the source when it has them
//! DIR2/sparse/0/points3D.bin     else the points of a transforms.json's ply_file_path
//! ```

use std::path::{Path, PathBuf};

use aberration::{BlurMode, Image, ImagingModel, NoiseModel, PsfGrid};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::capture::Capture;
use crate::colmap;
use crate::error::{Result, SceneError};
use crate::images::{self, BitDepth, Photo};
use crate::llff::LlffWriter;

pub const CLEAN_DIR: &str = "clean";
pub const PSF_FILE: &str = "psf.npy";
pub const RECORD_FILE: &str = "aberration.json";

/// How an aberrated capture was made; enough to rebuild its imaging model exactly.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AberrationRecord {
    /// The PSF grid file, relative to the capture.
    pub psf: String,
    /// `tiled` or `blend` (see [`BlurMode`]).
    pub mode: String,
    /// Sensor size in pixels the grid spans; `None` means the grid's own `G·K`.
    pub sensor_px: Option<usize>,
    pub noise_gaussian_sigma: f32,
    pub noise_poisson_scale: f32,
    pub seed: u64,
    pub width: u32,
    pub height: u32,
    pub images: usize,
    /// The capture the clean images came from, as given.
    pub source: String,
    /// The PSF file's fingerprint ([`psf_checksum`]), so that a replaced `psf.npy` (which
    /// would model a blur the photos never had) is refused; `psf_fnv1a`, its bare FNV-1a hex,
    /// in records written before XXH3; absent in records written before it was kept.
    #[serde(default, alias = "psf_fnv1a", skip_serializing_if = "Option::is_none")]
    pub psf_checksum: Option<String>,
    /// Whether the source's photos were undistorted at load before they were blurred (false
    /// in records written before undistortion existed, which kept them as taken).
    #[serde(default)]
    pub undistorted: bool,
    /// When the source had masks: the colour every photo was composited over outside its mask
    /// before the blur (a consistent scene: the object alone, as a turntable capture's poses
    /// describe it), and the masks are carried beside the copy's photos. None: no masks.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub composited_over: Option<[f32; 3]>,
    /// The carried masks are only the border undistortion left without a source (the source
    /// had no masks of its own): pixels without data, not an object's outline.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub masks_from_undistortion: bool,
}

/// The colour a masked capture's photos are composited over before the blur.
pub const COMPOSITE_BACKGROUND: [f32; 3] = [0.0; 3];

impl AberrationRecord {
    pub fn blur_mode(&self, path: &Path) -> Result<BlurMode> {
        self.mode
            .parse()
            .map_err(|e| SceneError::invalid(path, format!("mode {:?}: {e}", self.mode)))
    }

    pub fn noise(&self) -> NoiseModel {
        NoiseModel {
            gaussian_sigma: self.noise_gaussian_sigma,
            poisson_scale: self.noise_poisson_scale,
        }
    }

    /// The values a record may hold: a sensor of 1 to [`crate::limits::MAX_IMAGE_SIDE`] px,
    /// finite non-negative noise, images of a valid size, and a PSF file inside the capture.
    fn check(&self) -> std::result::Result<(), String> {
        if let Some(px) = self.sensor_px
            && !(1..=crate::limits::MAX_IMAGE_SIDE as usize).contains(&px)
        {
            return Err(format!(
                "sensor_px {px}; it must be 1 to {}",
                crate::limits::MAX_IMAGE_SIDE
            ));
        }
        for (name, v) in [
            ("noise_gaussian_sigma", self.noise_gaussian_sigma),
            ("noise_poisson_scale", self.noise_poisson_scale),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(format!("{name} {v}; it must be finite and not negative"));
            }
        }
        crate::limits::check_size(self.width as f64, self.height as f64)?;
        let psf = Path::new(&self.psf);
        if psf.is_absolute()
            || psf
                .components()
                .any(|c| !matches!(c, std::path::Component::Normal(_)))
        {
            return Err(format!(
                "psf {:?} must name a file inside the capture folder",
                self.psf
            ));
        }
        Ok(())
    }

    /// Reads `DIR/aberration.json`; `Ok(None)` when the capture has none (a clean capture).
    pub fn read(capture_dir: &Path) -> Result<Option<AberrationRecord>> {
        let path = capture_dir.join(RECORD_FILE);
        if !path.exists() {
            return Ok(None);
        }
        SceneError::check_file_size(&path, base::limits::MAX_TEXT_FILE_BYTES)?;
        let text = base::input::read_to_string(&path).map_err(|e| SceneError::io(&path, e))?;
        let value: serde_json::Value = serde_json::from_str(&text)
            .map_err(|e| SceneError::invalid(&path, format!("not a valid record: {e}")))?;
        // serde reads a number beyond f32 as infinity; say what was written instead.
        for key in ["noise_gaussian_sigma", "noise_poisson_scale"] {
            if let Some(v) = value[key].as_f64()
                && v.is_finite()
                && v.abs() > f32::MAX as f64
            {
                return Err(SceneError::invalid(
                    &path,
                    format!("{key} {v:e} is beyond single precision; it must be a noise level"),
                ));
            }
        }
        let record: AberrationRecord = serde_json::from_value(value)
            .map_err(|e| SceneError::invalid(&path, format!("not a valid record: {e}")))?;
        record.blur_mode(&path)?;
        record.check().map_err(|p| SceneError::invalid(&path, p))?;
        Ok(Some(record))
    }

    /// Loads the PSF grid named by the record, refusing a file other than the one the
    /// capture was made with.
    pub fn load_psf(&self, capture_dir: &Path) -> Result<PsfGrid> {
        let path = capture_dir.join(&self.psf);
        if let Some(want) = &self.psf_checksum {
            SceneError::check_file_size(&path, base::limits::MAX_NPY_BYTES)?;
            let bytes = base::input::read(&path).map_err(|e| SceneError::io(&path, e))?;
            if !base::hash::names(want, &bytes) {
                let got = psf_checksum(&bytes);
                return Err(SceneError::invalid(
                    &path,
                    format!(
                        "is not the PSF grid this capture was made with (checksum {got}, {RECORD_FILE} records {want}); the photos' blur would be modelled wrongly: put the original file back, or make the capture again"
                    ),
                ));
            }
        }
        PsfGrid::load_npy(&path).map_err(SceneError::Psf)
    }
}

/// The fingerprint [`AberrationRecord::psf_checksum`] holds ([`base::hash::tagged`]).
pub fn psf_checksum(bytes: &[u8]) -> String {
    base::hash::tagged(bytes)
}

/// Settings of the maker.
#[derive(Clone, Debug)]
pub struct AberrateOptions {
    pub mode: BlurMode,
    pub sensor_px: Option<usize>,
    pub noise: NoiseModel,
    pub seed: u64,
    /// 16-bit keeps the paper's tiny sensor noise, which 8-bit quantisation would swamp.
    pub depth: BitDepth,
}

impl Default for AberrateOptions {
    fn default() -> Self {
        Self {
            mode: BlurMode::Tiled,
            sensor_px: None,
            noise: NoiseModel::default(),
            seed: 0,
            depth: BitDepth::Sixteen,
        }
    }
}

/// What the maker did.
#[derive(Clone, Debug)]
pub struct AberrateReport {
    pub dest: PathBuf,
    pub images: usize,
    pub width: u32,
    pub height: u32,
    /// PSF size in pixels after mapping the grid onto the images.
    pub psf_px: usize,
    /// Mean PSNR (dB) of the aberrated images against the clean ones.
    pub mean_psnr: f64,
    /// Whether the source had masks: its photos were composited over
    /// [`COMPOSITE_BACKGROUND`] outside them before the blur, and the masks carried.
    pub masked: bool,
}

/// Interleaved RGB (scenes) to planar (aberration).
pub fn to_planar(img: &Photo) -> Image {
    let (w, h) = (img.width as usize, img.height as usize);
    Image::from_fn(w, h, |x, y| {
        let i = (y * w + x) * 3;
        [img.data[i], img.data[i + 1], img.data[i + 2]]
    })
}

/// Planar (aberration) to interleaved RGB (scenes).
pub fn from_planar(img: &Image) -> Photo {
    let n = img.plane_len();
    let mut data = vec![0.0f32; n * 3];
    for c in 0..3 {
        for (i, v) in img.channel(c).iter().enumerate() {
            data[i * 3 + c] = *v;
        }
    }
    Photo {
        width: img.width as u32,
        height: img.height as u32,
        data,
    }
}

/// Noise seed of image `index`: distinct, well-mixed streams from one user seed.
pub fn image_seed(seed: u64, index: usize) -> u64 {
    base::mix64(
        seed ^ (index as u64)
            .wrapping_add(1)
            .wrapping_mul(base::rng::GOLDEN_GAMMA),
    )
}

/// The path of the clean image for camera `index` of an aberrated capture, if it exists.
pub fn clean_image_path(capture: &Capture, index: usize) -> Option<PathBuf> {
    let name = capture.image_paths.get(index)?.file_name()?;
    let path = capture.root.join(CLEAN_DIR).join(name);
    path.is_file().then_some(path)
}

/// Loads the clean image of camera `index`; `Ok(None)` when the capture has no `clean/`
/// folder. A `clean/` folder that lacks this camera's image is an error naming it: scoring
/// some views against their clean images and others against their photos would mix two
/// measures in one figure.
pub fn load_clean_image(capture: &Capture, index: usize) -> Result<Option<Photo>> {
    let Some(path) = clean_image_path(capture, index) else {
        let folder = capture.root.join(CLEAN_DIR);
        return match capture.image_paths.get(index).and_then(|p| p.file_name()) {
            Some(name) if folder.is_dir() => Err(SceneError::NotFound {
                path: folder.join(name),
                what: "clean image (the capture has a clean/ folder, so every photo needs one)"
                    .into(),
            }),
            _ => Ok(None),
        };
    };
    let img = images::load_rgb(&path)?;
    let camera = &capture.cameras[index];
    if (img.width, img.height) != (camera.width, camera.height) {
        return Err(SceneError::invalid(
            &path,
            format!(
                "clean image is {}x{} but the capture's images are {}x{}",
                img.width, img.height, camera.width, camera.height
            ),
        ));
    }
    Ok(Some(img))
}

/// Writes the aberrated version of `capture` to `dest`. `psf_path` is copied byte for byte;
/// `on_image` is called once per finished image (for a progress bar). The same inputs and
/// seed give the same bytes.
pub fn make_aberrated(
    capture: &Capture,
    psf_path: &Path,
    dest: &Path,
    options: &AberrateOptions,
    on_image: &(dyn Fn() + Sync),
) -> Result<AberrateReport> {
    let psf = PsfGrid::load_npy(psf_path).map_err(SceneError::Psf)?;
    let Some(first) = capture.cameras.first() else {
        return Err(SceneError::NoImages {
            dir: capture.image_dir.clone(),
        });
    };
    let (width, height) = (first.width, first.height);
    let model = ImagingModel::new(
        &psf,
        width as usize,
        height as usize,
        options.mode,
        options.sensor_px,
        options.noise,
    )
    .map_err(|e| {
        let sensor = match options.sensor_px {
            Some(px) => format!("a {px} px sensor (--sensor-px)"),
            None => "the grid's own sensor size".into(),
        };
        SceneError::invalid(
            psf_path,
            format!("cannot plan the blur of {width}x{height} images on {sensor}: {e}"),
        )
    })?;
    let downsample = capture.downsample.round().max(1.0) as u32;
    let mut writer = LlffWriter::create(dest, downsample, options.depth)?;
    let staging = writer.staging_dir().to_path_buf();
    let clean_dir = staging.join(CLEAN_DIR);
    std::fs::create_dir(&clean_dir).map_err(|e| SceneError::io(&clean_dir, e))?;

    // Images are independent: aberrate in parallel, then hand them to the writer in order.
    // A masked photo is first composited over a constant colour outside its mask: the blur
    // then spreads the object, not a background the poses do not describe.
    type Made = (Photo, Photo, f64, Option<Vec<f32>>);
    let made: Vec<Result<Made>> = (0..capture.len())
        .into_par_iter()
        .map(|i| {
            if base::interrupt::requested() {
                return Err(SceneError::Interrupted);
            }
            let mut clean = capture.load_image(i)?;
            let mask = capture.load_mask(i)?;
            if let Some(m) = &mask {
                for (p, &k) in clean.data.chunks_exact_mut(3).zip(m) {
                    for (v, bg) in p.iter_mut().zip(COMPOSITE_BACKGROUND) {
                        *v = k * *v + (1.0 - k) * bg;
                    }
                }
            }
            let planar = to_planar(&clean);
            let bad = |e: aberration::AberrationError| {
                SceneError::invalid(&capture.image_paths[i], e.to_string())
            };
            let abr = model
                .capture(&planar, image_seed(options.seed, i))
                .map_err(bad)?;
            let psnr = aberration::psnr(&abr, &planar).map_err(bad)?;
            on_image();
            Ok((clean, from_planar(&abr), psnr, mask))
        })
        .collect();
    let mut psnr_sum = 0.0;
    // One masked photo makes every photo carry a mask (all kept where it had none), so that
    // the copy's masks folder names each of them.
    let masked = made.iter().any(|r| r.as_ref().is_ok_and(|m| m.3.is_some()));
    let mask_dir = mask_dir_of(&staging, downsample);
    if masked {
        std::fs::create_dir(&mask_dir).map_err(|e| SceneError::io(&mask_dir, e))?;
    }
    for (i, result) in made.into_iter().enumerate() {
        let (clean, abr, psnr, mask) = result?;
        let camera = &capture.cameras[i];
        let name = format!("{}.png", camera.name);
        images::write_png(&clean_dir.join(&name), &clean, options.depth)?;
        writer.add(camera, capture.bounds[i], &abr)?;
        if masked {
            let n = camera.width as usize * camera.height as usize;
            let m = mask.unwrap_or_else(|| vec![1.0; n]);
            let grey = Photo {
                width: camera.width,
                height: camera.height,
                data: m.iter().flat_map(|&k| [k; 3]).collect(),
            };
            images::write_png(&mask_dir.join(&name), &grey, options.depth)?;
        }
        psnr_sum += psnr;
    }

    let psf_dest = staging.join(PSF_FILE);
    std::fs::copy(psf_path, &psf_dest).map_err(|e| SceneError::io(&psf_dest, e))?;
    copy_sparse(capture, &staging)?;
    let record = AberrationRecord {
        psf: PSF_FILE.into(),
        mode: options.mode.to_string(),
        sensor_px: options.sensor_px,
        noise_gaussian_sigma: options.noise.gaussian_sigma,
        noise_poisson_scale: options.noise.poisson_scale,
        seed: options.seed,
        width,
        height,
        images: capture.len(),
        source: capture.root.display().to_string(),
        psf_checksum: Some(psf_checksum(
            &std::fs::read(&psf_dest).map_err(|e| SceneError::io(&psf_dest, e))?,
        )),
        undistorted: capture.undistorted(),
        composited_over: masked.then_some(COMPOSITE_BACKGROUND),
        masks_from_undistortion: masked && !capture.has_own_masks(),
    };
    let record_path = staging.join(RECORD_FILE);
    let text = serde_json::to_string_pretty(&record)
        .map_err(|e| SceneError::invalid(&record_path, e.to_string()))?;
    base::write_bytes_atomically(&record_path, (text + "\n").as_bytes())
        .map_err(|e| SceneError::io(&record_path, e))?;

    let dest = writer.finish()?;
    Ok(AberrateReport {
        dest,
        images: capture.len(),
        width,
        height,
        psf_px: model.psf().size(),
        mean_psnr: psnr_sum / capture.len() as f64,
        masked,
    })
}

/// Where an aberrated copy's masks go: beside its photos, at their size (`masks_N/` beside
/// `images_N/`).
fn mask_dir_of(staging: &Path, downsample: u32) -> PathBuf {
    staging.join(match downsample {
        1 => crate::capture::MASK_DIR.to_string(),
        n => format!("{}_{n}", crate::capture::MASK_DIR),
    })
}

/// Copies the sparse model's cameras and points so the new capture keeps its initial point
/// cloud and distortion report.
fn copy_sparse(capture: &Capture, staging: &Path) -> Result<()> {
    let Some(sparse) = colmap::sparse_dir(&capture.root) else {
        // Points read from a file that is not a COLMAP model: the LLFF copy keeps them in
        // COLMAP's binary points file, which it reads back.
        if let crate::capture::PointSource::Sparse(_) = &capture.point_source {
            let out = staging.join("sparse").join("0");
            std::fs::create_dir_all(&out).map_err(|e| SceneError::io(&out, e))?;
            let points: Vec<colmap::ColmapPoint> = capture
                .points
                .positions
                .iter()
                .zip(&capture.points.colors)
                .enumerate()
                .map(|(i, (xyz, c))| colmap::ColmapPoint {
                    id: i as u64 + 1,
                    xyz: *xyz,
                    rgb: c.map(|v| (v * 255.0).round().clamp(0.0, 255.0) as u8),
                    error: 0.0,
                    track: Vec::new(),
                })
                .collect();
            colmap::binary::write_points3d(&out.join("points3D.bin"), &points)?;
        }
        return Ok(());
    };
    let out = staging.join("sparse").join("0");
    // Undistorted photos are pinhole photos: the copy keeps no distortion to apply again.
    let stems: &[&str] = if capture.undistorted() {
        &["points3D"]
    } else {
        &["cameras", "points3D"]
    };
    for &stem in stems {
        if let Some((src, _)) = colmap::find_file(&sparse, stem) {
            std::fs::create_dir_all(&out).map_err(|e| SceneError::io(&out, e))?;
            let name = src.file_name().expect("find_file returns file paths");
            std::fs::copy(&src, out.join(name)).map_err(|e| SceneError::io(&src, e))?;
        }
    }
    Ok(())
}
