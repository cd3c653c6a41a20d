//! `scene aberrate` as a job: an aberrated copy of a capture (LLFF layout, the clean images in
//! `clean/`, the grid beside them). [`prepare`] checks every name, opens the capture and reads
//! the grid, writing nothing; [`PreparedSceneAberrate::run`] takes the lock beside `--out`,
//! makes the copy in a staging folder and renames it into place.

use clap::Args;
use scenes::BitDepth;
use std::path::PathBuf;
use std::time::Instant;

use super::refused;
use crate::error::{Result, TrainError};
use crate::output::guard;
use crate::settings::imaging::ImagingArgs;

/// What `scene aberrate` is asked to do (its flags).
#[derive(Args, Clone, Debug)]
pub struct SceneAberrateRequest {
    /// Clean capture directory (LLFF or COLMAP).
    #[arg(long)]
    pub scene: PathBuf,
    /// PSF grid .npy (the paper's layout).
    #[arg(long)]
    pub psf: PathBuf,
    /// Destination; must not exist.
    #[arg(long)]
    pub out: PathBuf,
    /// Read images_N/ of the source, else its images/ shrunk N times at load.
    #[arg(long, default_value_t = 8, value_parser = clap::value_parser!(u32).range(1..=64))]
    pub downsample: u32,
    #[command(flatten)]
    pub imaging: ImagingArgs,
    /// Blur the photos as taken even when the cameras have lens distortion (by default they
    /// are undistorted at load first, and the copy's cameras are pinhole).
    #[arg(long)]
    pub keep_distortion: bool,
    /// PNG sample depth of the written images (8 or 16); 16 keeps the sensor noise.
    #[arg(long, default_value_t = 16, value_parser = clap::value_parser!(u8).range(8..=16))]
    pub bit_depth: u8,
}

/// The capture opened and every input checked, to be aberrated.
pub struct PreparedSceneAberrate {
    request: SceneAberrateRequest,
    capture: scenes::Capture,
    options: scenes::AberrateOptions,
}

/// What was written.
#[derive(Clone, Debug)]
pub struct SceneAberrateReport {
    pub made: scenes::AberrateReport,
    pub seconds: f64,
    /// Why the copy carries masks, when it does (a sentence).
    pub masks: Option<String>,
}

/// Every name checked (no input overwritten, not an aberrated copy as the source), the
/// capture opened and the grid read; nothing written.
pub fn prepare(a: &SceneAberrateRequest) -> Result<PreparedSceneAberrate> {
    guard::refuse_overwrite("--out", &a.out, &[("--scene", &a.scene), ("--psf", &a.psf)])?;
    guard::refuse_aberrated_source("--scene", &a.scene)?;
    let capture = crate::settings::open_scene(&a.scene, a.downsample, a.keep_distortion)?;
    let mut inputs = guard::Inputs::of(&[("--scene", &a.scene), ("--psf", &a.psf)]);
    inputs.add_capture(&capture);
    inputs.refuse("--out", &a.out)?;
    let depth = match a.bit_depth {
        8 => BitDepth::Eight,
        16 => BitDepth::Sixteen,
        other => return refused(format!("--bit-depth must be 8 or 16, not {other}")),
    };
    // A bad PSF file is the flag's error, found before the lock and the staging.
    aberration::PsfGrid::load_npy(&a.psf)
        .map_err(|e| TrainError::from(e).context(format!("--psf {}", a.psf.display())))?;
    let options = scenes::AberrateOptions {
        mode: a.imaging.mode,
        sensor_px: a.imaging.sensor_px,
        noise: a.imaging.noise(),
        seed: a.imaging.seed,
        depth,
    };
    Ok(PreparedSceneAberrate {
        request: a.clone(),
        capture,
        options,
    })
}

impl PreparedSceneAberrate {
    /// Images the copy will hold.
    pub fn images(&self) -> usize {
        self.capture.len()
    }

    /// Makes the copy; `on_image` is called as each image is written (from worker threads).
    pub fn run(self, on_image: &(dyn Fn() + Sync)) -> Result<SceneAberrateReport> {
        let a = &self.request;
        // The copy appears by renaming its staging folder into place; the lock beside it
        // keeps a second maker from doing the work only to fail at the end (or to win a race).
        let _lock = base::FolderLock::beside(&a.out, "scene aberrate")?;
        let start = Instant::now();
        let made = scenes::make_aberrated(&self.capture, &a.psf, &a.out, &self.options, on_image)
            .map_err(|e| {
            TrainError::from(e).context(format!(
                "cannot write the aberrated capture {}",
                a.out.display()
            ))
        })?;
        let masks = if made.masked && !self.capture.has_own_masks() {
            Some("Undistortion leaves border pixels without a source: each photo was composited over black there before the blur, and the border is carried as masks beside the copy's photos (they leave its pixels out of the loss; the record says they are not an object's).".to_string())
        } else if made.masked {
            Some(format!(
                "The capture has masks ({}): each photo was composited over black outside its mask before the blur, so the copy is the object alone, and the masks are carried beside the copy's photos.",
                self.capture.mask_source()
            ))
        } else {
            None
        };
        Ok(SceneAberrateReport {
            made,
            seconds: start.elapsed().as_secs_f64(),
            masks,
        })
    }
}
