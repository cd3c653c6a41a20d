//! `metasplat aberrate`: one image through the PSF model and sensor noise.

use super::progress::step;
use aberration::{Image, ImagingModel, PsfGrid, psnr};
use anyhow::{Context, Result};
use clap::Args;
use metasplat::settings::imaging::{ImagingArgs, aberrate_frames};
use std::path::PathBuf;

#[derive(Args)]
pub struct AberrateArgs {
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

pub fn run(a: AberrateArgs) -> Result<()> {
    if a.input.is_dir() {
        return run_folder(a);
    }
    metasplat::output::guard::refuse_overwrite(
        "--out",
        &a.out,
        &[("--in", &a.input), ("--psf", &a.psf)],
    )?;
    metasplat::output::guard::refuse_unwritable_image("--out", &a.out)?;
    let psf = PsfGrid::load_npy(&a.psf)?;
    let clean = Image::load(&a.input)?;
    let im = &a.imaging;
    let noise = im.noise();
    let (result, secs) = step("aberrating", || -> Result<_> {
        let model = ImagingModel::new(
            &psf,
            clean.width,
            clean.height,
            im.mode,
            im.sensor_px,
            noise,
        )
        .with_context(|| {
            format!(
                "--in {} ({}x{}) with {}: cannot plan the blur",
                a.input.display(),
                clean.width,
                clean.height,
                metasplat::settings::imaging::sensor_flag(im.sensor_px, &a.psf)
            )
        })?;
        let out = model.capture(&clean, im.seed)?;
        Ok((model, out))
    });
    let (model, out) = result?;
    out.save_png(&a.out)?;
    println!(
        "{}x{} through a {}x{} grid of {} px PSFs ({} mode) in {secs:.2} s: PSNR {:.2} dB vs input; wrote {}",
        clean.width,
        clean.height,
        model.psf().grid(),
        model.psf().grid(),
        model.psf().size(),
        im.mode,
        psnr(&out, &clean)?,
        a.out.display()
    );
    Ok(())
}

/// `aberrate --in DIR --out DIR`: every frame of a clip through one imaging model, frame `i`
/// with the sensor noise of seed `mix(seed, i)` (a video's noise changes from frame to frame),
/// so a clean clip (`render --out`) gives its aberrated twin to restore and score.
fn run_folder(a: AberrateArgs) -> Result<()> {
    let io = metasplat::jobs::frames::FrameFolders::check(
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
    let mean = aberrate_frames(&model, &io.frames, &targets, im.seed)?;
    println!(
        "{} frames {w}x{h} through {} px PSFs ({} mode), noise seeded per frame: mean PSNR {mean:.2} dB vs input; wrote {}",
        io.frames.len(),
        model.psf().size(),
        im.mode,
        a.out.display()
    );
    Ok(())
}
