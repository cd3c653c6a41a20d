//! `metasplat demo`: the built-in default run, needing no data. Simulates the paper's PSF
//! grid, aberrates a test chart both ways, runs the Wiener bank, and reports PSNRs.

use super::progress::step;
use super::psf::{print_report, simulate};
use aberration::optics::SimConfig;
use aberration::picture::psf_grid_picture;
use aberration::testchart::test_chart;
use aberration::{
    BlurMode, Image, ImagingModel, NoiseModel, image::save_rgb8_png, psnr, wiener_bank,
};
use anyhow::{Context, Result};
use clap::Args;
use std::path::PathBuf;

#[derive(Args)]
pub struct DemoArgs {
    /// Output directory.
    #[arg(long, default_value = "demo_out")]
    pub out: PathBuf,
    /// A small lens and grid that run in seconds (for tests), instead of the paper's.
    #[arg(long)]
    pub quick: bool,
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
}

/// Images side by side with a white gutter.
fn side_by_side(images: &[&Image]) -> image::RgbImage {
    let gap = 8;
    let (w, h) = (images[0].width, images[0].height);
    let mut out = image::RgbImage::from_pixel(
        (images.len() * (w + gap) - gap) as u32,
        h as u32,
        image::Rgb([255, 255, 255]),
    );
    for (i, img) in images.iter().enumerate() {
        image::imageops::replace(&mut out, &img.to_rgb8(), (i * (w + gap)) as i64, 0);
    }
    out
}

pub fn run(a: DemoArgs) -> Result<()> {
    std::fs::create_dir_all(&a.out)
        .with_context(|| format!("cannot create {}", a.out.display()))?;
    let cfg = if a.quick {
        SimConfig::small(45)
    } else {
        SimConfig::default()
    };
    println!(
        "simulating the {}x{} PSF grid of the Tseng et al. metalens ({} px PSFs, {}x{} propagation grid)",
        cfg.grid, cfg.grid, cfg.psf_size, cfg.fft_size, cfg.fft_size
    );
    let (psf, report) = simulate(&cfg)?;
    print_report(&report);
    let psf_path = a.out.join("psf.npy");
    psf.save_npy(&psf_path)?;
    save_rgb8_png(&psf_grid_picture(&psf), &a.out.join("psf.png"))?;

    let side = psf.native_sensor_px();
    let clean = test_chart(side, side);
    clean.save_png(&a.out.join("chart_clean.png"))?;
    let mut rows = Vec::new();
    let mut tiled = None;
    for mode in [BlurMode::Tiled, BlurMode::Blend] {
        let (res, secs) = step(&format!("aberrating ({mode})"), || -> Result<_> {
            let model = ImagingModel::new(&psf, side, side, mode, None, NoiseModel::default())?;
            Ok(model.capture(&clean, a.seed)?)
        });
        let img = res?;
        img.save_png(&a.out.join(format!("chart_{mode}.png")))?;
        rows.push((format!("aberrated, {mode}"), psnr(&img, &clean), secs));
        if mode == BlurMode::Tiled {
            tiled = Some(img);
        }
    }
    let tiled = tiled.expect("tiled mode ran");
    let (bank, secs) = step("Wiener bank", || wiener_bank(&tiled, &psf));
    let bank = bank?;
    bank.median()
        .save_png(&a.out.join("chart_wiener_median.png"))?;
    rows.push((
        "Wiener, median MAFG filter".into(),
        psnr(bank.median(), &clean),
        secs,
    ));
    let best = bank
        .images
        .iter()
        .map(|img| psnr(img, &clean))
        .fold(f64::NEG_INFINITY, f64::max);
    rows.push(("Wiener, best of the 13 filters".into(), best, 0.0));
    save_rgb8_png(
        &side_by_side(&[&clean, &tiled, bank.median()]),
        &a.out.join("comparison.png"),
    )?;

    println!(
        "\n{side}x{side} test chart through the simulated metalens (noise seed {}):",
        a.seed
    );
    println!("{:<32} {:>9} {:>9}", "image", "PSNR dB", "seconds");
    for (name, db, secs) in &rows {
        println!("{name:<32} {db:>9.2} {secs:>9.2}");
    }
    println!(
        "\nwrote {}: psf.npy, psf.png (PSF grid), chart_*.png, comparison.png (clean | aberrated | Wiener)",
        a.out.display()
    );
    Ok(())
}
