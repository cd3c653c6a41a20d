//! `aberrate` as a job: one photo, or every frame of a folder, through the PSF model and sensor
//! noise. [`run`] checks both names and reads the grid and the input before anything is
//! written; a folder's frame `i` gets the noise of seed `mix(seed, i)` (a video's noise changes
//! from frame to frame), so a clean clip (`render --out`) gives its aberrated twin.

use aberration::{Image, PsfGrid, psnr};
use clap::Args;
use std::path::PathBuf;
use std::time::Instant;

use super::frames::FrameFolders;
use crate::error::{Result, TrainError};
use crate::output::guard;
use crate::settings::imaging::{ImagingArgs, aberrate_frames};

/// What `aberrate` is asked to do (its flags).
#[derive(Args, Clone, Debug)]
pub struct AberrateRequest {
    /// PSF grid .npy (the paper's layout).
    #[arg(long)]
    pub psf: PathBuf,
    /// The clean photo to blur (PNG or JPEG), or a folder of them (a clip's frames, one size):
    /// each goes into --out, a folder, under its own name, with noise of its own.
    #[arg(long = "in")]
    pub input: PathBuf,
    /// Where the aberrated photo goes (PNG), or the folder the aberrated frames go to.
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub imaging: ImagingArgs,
}

/// What was written.
#[derive(Clone, Debug)]
pub struct AberrateReport {
    /// Frames written (1 for a photo).
    pub frames: usize,
    pub size: (usize, usize),
    /// The grid's side and its PSFs' size at the images' scale.
    pub grid: usize,
    pub psf_px: usize,
    /// PSNR of the aberrated image against the clean one (a folder: the mean over frames).
    pub psnr: f64,
    pub seconds: f64,
    pub out: PathBuf,
}

/// Aberrates the photo or the folder `a` names.
pub fn run(a: &AberrateRequest) -> Result<AberrateReport> {
    if a.input.is_dir() {
        return run_folder(a);
    }
    guard::refuse_overwrite("--out", &a.out, &[("--in", &a.input), ("--psf", &a.psf)])?;
    guard::refuse_unwritable_image("--out", &a.out)?;
    let psf = PsfGrid::load_npy(&a.psf)?;
    let clean = Image::load(&a.input)?;
    let im = &a.imaging;
    let what = format!("--in {}", a.input.display());
    let size = (clean.width, clean.height);
    let model = im.model_for(&psf, &a.psf, &what, (size.0 as u32, size.1 as u32))?;
    let start = Instant::now();
    let out = model.capture(&clean, im.seed).map_err(TrainError::from)?;
    let seconds = start.elapsed().as_secs_f64();
    out.save_png(&a.out)?;
    Ok(AberrateReport {
        frames: 1,
        size,
        grid: model.psf().grid(),
        psf_px: model.psf().size(),
        psnr: psnr(&out, &clean)?,
        seconds,
        out: a.out.clone(),
    })
}

fn run_folder(a: &AberrateRequest) -> Result<AberrateReport> {
    let io = FrameFolders::check(
        &a.input,
        &a.out,
        Some("give an empty or new folder"),
        &[("--psf", &a.psf)],
    )?;
    let (w, h) = io.size;
    let psf = PsfGrid::load_npy(&a.psf)?;
    let im = &a.imaging;
    let what = format!("--in {}", a.input.display());
    let model = im.model_for(&psf, &a.psf, &what, (w, h))?;
    io.make_out()?;
    let targets: Vec<PathBuf> = io.frames.iter().map(|f| io.target(f)).collect();
    let start = Instant::now();
    let mean = aberrate_frames(&model, &io.frames, &targets, im.seed)?;
    Ok(AberrateReport {
        frames: io.frames.len(),
        size: (w as usize, h as usize),
        grid: model.psf().grid(),
        psf_px: model.psf().size(),
        psnr: mean,
        seconds: start.elapsed().as_secs_f64(),
        out: a.out.clone(),
    })
}
