//! `metasplat deconvolve`: tile-wise Wiener deconvolution, single K or the MAFG bank.

use super::progress::step;
use aberration::wiener::bank_constants;
use aberration::{Image, PsfGrid, Regularizer, deconvolve, psnr, wiener_bank};
use anyhow::{Context, Result};
use clap::Args;
use std::path::PathBuf;

#[derive(Args)]
pub struct DeconvolveArgs {
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
    #[arg(long, value_parser = metasplat::settings::values::wiener_k, allow_negative_numbers = true)]
    pub k: Option<f32>,
    /// Also write all 13 adaptive filters of the MAFG bank into this directory.
    #[arg(long)]
    pub bank: Option<PathBuf>,
    /// Sensor size (px) the grid was made for; default G·K.
    #[arg(long, value_parser = metasplat::settings::values::sensor_px)]
    pub sensor_px: Option<usize>,
    /// A clean image to report PSNR against (input and every output).
    #[arg(long)]
    pub reference: Option<PathBuf>,
}

pub fn run(a: DeconvolveArgs) -> Result<()> {
    let mut inputs = vec![("--in", a.input.as_path()), ("--psf", a.psf.as_path())];
    if let Some(r) = &a.reference {
        inputs.push(("--reference", r));
    }
    metasplat::output::guard::refuse_overwrite("--out", &a.out, &inputs)?;
    metasplat::output::guard::refuse_unwritable_image("--out", &a.out)?;
    if let Some(bank) = &a.bank {
        metasplat::output::guard::refuse_overwrite("--bank", bank, &inputs)?;
        metasplat::output::guard::refuse_file_as_folder("--bank", bank)?;
    }
    let native = PsfGrid::load_npy(&a.psf)?;
    let blurred = Image::load(&a.input)?;
    let psf = native
        .for_image(blurred.width, blurred.height, a.sensor_px)
        .with_context(|| metasplat::settings::imaging::sensor_flag(a.sensor_px, &a.psf))?;
    let reference = a.reference.as_deref().map(Image::load).transpose()?;
    if let Some(r) = &reference
        && (r.width, r.height) != (blurred.width, blurred.height)
    {
        anyhow::bail!(
            "{}: reference is {}x{} but the input is {}x{}",
            a.reference.as_ref().expect("loaded").display(),
            r.width,
            r.height,
            blurred.width,
            blurred.height
        );
    }
    let score = |img: &Image| {
        reference.as_ref().map_or(String::new(), |r| {
            format!(" ({:.2} dB)", psnr(img, r).unwrap_or(f64::NAN))
        })
    };
    if reference.is_some() {
        println!("input{}", score(&blurred));
    }
    if let Some(dir) = &a.bank {
        write_bank(dir, &blurred, &psf, reference.is_some(), &score)?;
    }
    let k = a.k.unwrap_or(aberration::wiener::DEFAULT_K);
    let (out, secs) = step("Wiener", || {
        deconvolve(&blurred, &psf, Regularizer::Fixed(k))
    });
    let out = out?;
    out.save_png(&a.out)?;
    println!(
        "Wiener K = {k:.2e}{} in {secs:.2} s{}: wrote {}",
        if a.k.is_none() { " (the default)" } else { "" },
        score(&out),
        a.out.display()
    );
    Ok(())
}

/// `--bank DIR`: MAFG's 13 Wiener images of `blurred` into `dir`, each scored by `score`
/// when there is a reference.
fn write_bank(
    dir: &std::path::Path,
    blurred: &Image,
    psf: &PsfGrid,
    scored: bool,
    score: &dyn Fn(&Image) -> String,
) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let (bank, secs) = step("13 Wiener filters", || wiener_bank(blurred, psf));
    let bank = bank?;
    for (m, (img, k)) in bank.images.iter().zip(bank_constants()).enumerate() {
        img.save_png(&dir.join(format!("wiener_{m:02}_k{k:.1e}.png")))?;
        if scored {
            println!("filter {m:2} k {k:.1e}{}", score(img));
        }
    }
    println!(
        "MAFG bank (13 adaptive filters, k 1e-2..1e-5) in {secs:.2} s: wrote {}",
        dir.display()
    );
    Ok(())
}
