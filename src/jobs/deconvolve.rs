//! `deconvolve` as a job: tile-wise Wiener deconvolution of one photo with a single K, and
//! optionally MAFG's bank of 13 adaptive filters into a folder. [`run`] checks every name and
//! reads the grid, the photo and the reference before anything is written.

use aberration::wiener::{DEFAULT_K, bank_constants};
use aberration::{Image, PsfGrid, Regularizer, deconvolve, psnr, wiener_bank};
use clap::Args;
use std::path::PathBuf;
use std::time::Instant;

use super::refused;
use crate::error::{Result, TrainError};
use crate::output::guard;
use crate::settings::imaging::sensor_flag;

/// What `deconvolve` is asked to do (its flags).
#[derive(Args, Clone, Debug)]
pub struct DeconvolveRequest {
    /// The PSF grid (.npy) the photo was blurred with.
    #[arg(long)]
    pub psf: PathBuf,
    /// The aberrated photo (PNG or JPEG).
    #[arg(long = "in")]
    pub input: PathBuf,
    /// The deconvolved image (one Wiener filter, K from --k or the default).
    #[arg(long)]
    pub out: PathBuf,
    /// A single fixed Wiener constant (default: the bank's largest, which improves typical
    /// photos at the paper's noise; the bank's median often makes them worse).
    #[arg(long, value_parser = crate::settings::values::wiener_k, allow_negative_numbers = true)]
    pub k: Option<f32>,
    /// Also write all 13 adaptive filters of the MAFG bank into this directory.
    #[arg(long)]
    pub bank: Option<PathBuf>,
    /// Sensor size (px) the grid was made for; default G·K.
    #[arg(long, value_parser = crate::settings::values::sensor_px)]
    pub sensor_px: Option<usize>,
    /// A clean image to report PSNR against (input and every output).
    #[arg(long)]
    pub reference: Option<PathBuf>,
}

/// What was written, with PSNR against `--reference` where one was given.
#[derive(Clone, Debug)]
pub struct DeconvolveReport {
    pub k: f32,
    pub seconds: f64,
    pub input_psnr: Option<f64>,
    pub psnr: Option<f64>,
    /// With `--bank`.
    pub bank: Option<BankReport>,
}

/// MAFG's bank as written: each filter's K and PSNR (with a reference), and its seconds.
#[derive(Clone, Debug)]
pub struct BankReport {
    pub filters: Vec<(f32, Option<f64>)>,
    pub seconds: f64,
}

/// Deconvolves the photo `a` names.
pub fn run(a: &DeconvolveRequest) -> Result<DeconvolveReport> {
    let mut inputs = vec![("--in", a.input.as_path()), ("--psf", a.psf.as_path())];
    if let Some(r) = &a.reference {
        inputs.push(("--reference", r));
    }
    guard::refuse_overwrite("--out", &a.out, &inputs)?;
    guard::refuse_unwritable_image("--out", &a.out)?;
    if let Some(bank) = &a.bank {
        guard::refuse_overwrite("--bank", bank, &inputs)?;
        guard::refuse_file_as_folder("--bank", bank)?;
    }
    let native = PsfGrid::load_npy(&a.psf)?;
    let blurred = Image::load(&a.input)?;
    let psf = native
        .for_image(blurred.width, blurred.height, a.sensor_px)
        .map_err(|e| TrainError::from(e).context(sensor_flag(a.sensor_px, &a.psf)))?;
    let reference = a.reference.as_deref().map(Image::load).transpose()?;
    if let Some(r) = &reference
        && (r.width, r.height) != (blurred.width, blurred.height)
    {
        return refused(format!(
            "{}: reference is {}x{} but the input is {}x{}",
            a.reference.as_ref().expect("loaded").display(),
            r.width,
            r.height,
            blurred.width,
            blurred.height
        ));
    }
    let score = |img: &Image| reference.as_ref().map(|r| psnr(img, r).unwrap_or(f64::NAN));
    let bank = match &a.bank {
        Some(dir) => {
            std::fs::create_dir_all(dir).map_err(|e| TrainError::io(dir, e))?;
            let start = Instant::now();
            let bank = wiener_bank(&blurred, &psf)?;
            let seconds = start.elapsed().as_secs_f64();
            let mut rows = Vec::new();
            for (m, (img, k)) in bank.images.iter().zip(bank_constants()).enumerate() {
                img.save_png(&dir.join(format!("wiener_{m:02}_k{k:.1e}.png")))?;
                rows.push((k, score(img)));
            }
            Some(BankReport {
                filters: rows,
                seconds,
            })
        }
        None => None,
    };
    let k = a.k.unwrap_or(DEFAULT_K);
    let start = Instant::now();
    let out = deconvolve(&blurred, &psf, Regularizer::Fixed(k))?;
    let seconds = start.elapsed().as_secs_f64();
    out.save_png(&a.out)?;
    Ok(DeconvolveReport {
        k,
        seconds,
        input_psnr: score(&blurred),
        psnr: score(&out),
        bank,
    })
}
