//! `metasplat deconvolve`: tile-wise Wiener deconvolution, single K or the MAFG bank.

use super::progress::step;
use aberration::wiener::{BANK_MEDIAN, bank_constants};
use aberration::{Image, PsfGrid, Regularizer, deconvolve, psnr, wiener_bank};
use anyhow::{Context, Result};
use clap::Args;
use std::path::PathBuf;

#[derive(Args)]
pub struct DeconvolveArgs {
    #[arg(long)]
    pub psf: PathBuf,
    #[arg(long = "in")]
    pub input: PathBuf,
    /// The deconvolved image (with --bank: the median-k filter's output).
    #[arg(long)]
    pub out: PathBuf,
    /// A single fixed Wiener constant.
    #[arg(long, conflicts_with = "bank", value_parser = metasplat::flags::positive_f32, allow_negative_numbers = true)]
    pub k: Option<f32>,
    /// Write all 13 adaptive filters of the MAFG bank into this directory.
    #[arg(long)]
    pub bank: Option<PathBuf>,
    /// Sensor size (px) the grid was made for; default G·K.
    #[arg(long, value_parser = metasplat::flags::sensor_px)]
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
    metasplat::guard::refuse_overwrite("--out", &a.out, &inputs)?;
    if let Some(bank) = &a.bank {
        metasplat::guard::refuse_overwrite("--bank", bank, &inputs)?;
    }
    let native = PsfGrid::load_npy(&a.psf)?;
    let blurred = Image::load(&a.input)?;
    let psf = native.for_image(blurred.width, blurred.height, a.sensor_px)?;
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
    match &a.bank {
        Some(dir) => {
            std::fs::create_dir_all(dir)
                .with_context(|| format!("cannot create {}", dir.display()))?;
            let (bank, secs) = step("13 Wiener filters", || wiener_bank(&blurred, &psf));
            let bank = bank?;
            for (m, (img, k)) in bank.images.iter().zip(bank_constants()).enumerate() {
                img.save_png(&dir.join(format!("wiener_{m:02}_k{k:.1e}.png")))?;
                if reference.is_some() {
                    println!("filter {m:2} k {k:.1e}{}", score(img));
                }
            }
            bank.median().save_png(&a.out)?;
            println!(
                "MAFG bank (13 adaptive filters, k 1e-2..1e-5) in {secs:.2} s: wrote {} and the median (k = {:.2e}) to {}",
                dir.display(),
                bank_constants()[BANK_MEDIAN],
                a.out.display()
            );
        }
        None => {
            let k = a.k.unwrap_or(bank_constants()[BANK_MEDIAN]);
            let (out, secs) = step("Wiener", || {
                deconvolve(&blurred, &psf, Regularizer::Fixed(k))
            });
            let out = out?;
            out.save_png(&a.out)?;
            println!(
                "Wiener K = {k:.2e} in {secs:.2} s{}: wrote {}",
                score(&out),
                a.out.display()
            );
        }
    }
    Ok(())
}
