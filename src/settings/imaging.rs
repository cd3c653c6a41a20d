//! How images go through the PSF model: the flags `aberrate`, `scene aberrate` and
//! `render --aberrate` share, and the frames of a clip through one model.

use aberration::{BlurMode, Image, ImagingModel, NoiseModel, PsfGrid, psnr};
use clap::Args;
use std::path::PathBuf;

use crate::error::{Result, TrainError};

/// How images go through the PSF model (shared by `aberrate` and `scene aberrate`).
#[derive(Args, Clone, Debug)]
pub struct ImagingArgs {
    /// tiled (the paper's patch-wise blur) or blend (seamless).
    #[arg(long, default_value = "tiled")]
    pub mode: BlurMode,
    /// Seed of the sensor noise: the same seed gives the same bytes.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Blur only, no sensor noise.
    #[arg(long)]
    pub no_noise: bool,
    /// Sensor size (px) the grid spans; default G·K.
    #[arg(long, value_parser = crate::settings::values::sensor_px)]
    pub sensor_px: Option<usize>,
}

impl ImagingArgs {
    /// Whether any setting differs from its default (`render` refuses them without
    /// `--aberrate`, which they would not change).
    pub fn any_given(&self) -> bool {
        self.mode != BlurMode::Tiled || self.seed != 0 || self.no_noise || self.sensor_px.is_some()
    }

    /// The imaging model of `psf` (read from `psf_path`) for `width × height` frames; the
    /// error names the flag and the size.
    pub fn model_for(
        &self,
        psf: &PsfGrid,
        psf_path: &std::path::Path,
        what: &str,
        (width, height): (u32, u32),
    ) -> Result<ImagingModel> {
        ImagingModel::new(
            psf,
            width as usize,
            height as usize,
            self.mode,
            self.sensor_px,
            self.noise(),
        )
        .map_err(|e| {
            TrainError::from(e).context(format!(
                "{what} ({width}x{height}) with {}: cannot plan the blur",
                sensor_flag(self.sensor_px, psf_path)
            ))
        })
    }

    pub fn noise(&self) -> NoiseModel {
        if self.no_noise {
            NoiseModel::none()
        } else {
            NoiseModel::default()
        }
    }
}

/// What a PSF grid's mapping onto an image failed with: the `--sensor-px` given, or the
/// grid's own sensor size when none was.
pub fn sensor_flag(sensor_px: Option<usize>, psf: &std::path::Path) -> String {
    match sensor_px {
        Some(px) => format!("--sensor-px {px}"),
        None => format!(
            "the sensor size of --psf {} (set another with --sensor-px)",
            psf.display()
        ),
    }
}

/// Frame `i` of `frames` through `model` into `targets[i]`, with the sensor noise of seed
/// `mix(seed, i)` (a video's noise changes from frame to frame); the mean PSNR against the
/// clean frames.
pub fn aberrate_frames(
    model: &ImagingModel,
    frames: &[PathBuf],
    targets: &[PathBuf],
    seed: u64,
) -> Result<f64> {
    let mut sum = 0.0;
    for (i, (f, to)) in frames.iter().zip(targets).enumerate() {
        let clean = Image::load(f)?;
        let out = model.capture(&clean, base::mix64(seed ^ i as u64))?;
        out.save_png(to)?;
        sum += psnr(&out, &clean)?;
    }
    Ok(sum / frames.len().max(1) as f64)
}
