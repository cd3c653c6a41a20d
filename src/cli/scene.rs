//! `metasplat scene info` and `metasplat scene aberrate`.

use super::progress::bar;
use anyhow::{Context, Result};
use clap::{Args, Subcommand};
use std::path::PathBuf;

#[derive(Subcommand)]
pub enum SceneCommand {
    /// Print cameras, resolution, split, bounds and points of a capture.
    Info(InfoArgs),
    /// Write an aberrated copy of a capture (LLFF layout, clean images in clean/, psf.npy).
    Aberrate(SceneAberrateArgs),
    /// Write the built-in procedural scene as a clean LLFF capture (known ground truth).
    Procedural(ProceduralArgs),
}

#[derive(Args)]
pub struct ProceduralArgs {
    /// The capture folder to write; it must not exist.
    #[arg(long)]
    pub out: PathBuf,
    /// Image width (px).
    #[arg(long, default_value_t = 160, value_parser = clap::value_parser!(u32).range(8..=4096))]
    pub width: u32,
    /// Image height (px).
    #[arg(long, default_value_t = 120, value_parser = clap::value_parser!(u32).range(8..=4096))]
    pub height: u32,
    /// Number of cameras.
    #[arg(long, default_value_t = 12, value_parser = clap::value_parser!(u64).range(1..=1000))]
    pub views: u64,
    /// Seed of the scene's layout and textures.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// An object in the middle seen from cameras all around it (no SfM points), instead of
    /// the forward-facing scene.
    #[arg(long)]
    pub around: bool,
}

pub use metasplat::jobs::scene_aberrate::SceneAberrateRequest as SceneAberrateArgs;

#[derive(Args)]
pub struct InfoArgs {
    /// Capture directory (LLFF or COLMAP).
    pub dir: PathBuf,
    /// Use images_N/, else images/ shrunk N times at load.
    #[arg(long, default_value_t = 8, value_parser = clap::value_parser!(u32).range(1..=64))]
    pub downsample: u32,
    /// Every N-th image is held out for testing (0: none).
    #[arg(long, default_value_t = 8, value_parser = metasplat::settings::values::llffhold)]
    pub llffhold: usize,
}

pub fn run(cmd: SceneCommand) -> Result<()> {
    match cmd {
        SceneCommand::Info(a) => {
            let opts = scenes::OpenOptions {
                resolution: scenes::Resolution::Downsample(a.downsample),
                llffhold: a.llffhold,
                ..Default::default()
            };
            let capture = scenes::open(&a.dir, &opts)
                .with_context(|| format!("cannot open the scene {}", a.dir.display()))?;
            // A damaged image is found here, not hours into training.
            super::decode_all(&capture)?;
            println!("{}", capture.summary());
            println!("decoded     all {} images", capture.len());
            Ok(())
        }
        SceneCommand::Aberrate(a) => aberrate(a),
        SceneCommand::Procedural(a) => {
            let o = metasplat::splats::procedural::ProceduralOptions {
                width: a.width,
                height: a.height,
                views: a.views as usize,
                seed: a.seed,
            };
            let dir = if a.around {
                metasplat::splats::procedural::write_capture_around(&a.out, &o)
            } else {
                metasplat::splats::procedural::write_capture(&a.out, &o)
            }
            .with_context(|| format!("cannot write {}", a.out.display()))?;
            println!(
                "wrote {} views {}x{} to {}",
                a.views,
                a.width,
                a.height,
                dir.display()
            );
            Ok(())
        }
    }
}

fn aberrate(a: SceneAberrateArgs) -> Result<()> {
    let prepared = metasplat::jobs::scene_aberrate::prepare(&a)?;
    let pb = bar(prepared.images() as u64, "aberrating");
    let r = prepared.run(&|| pb.inc(1));
    pb.finish_and_clear();
    let r = r?;
    let m = &r.made;
    println!(
        "{} images {}x{} through {} px PSFs ({} mode, seed {}) in {:.1} s: mean PSNR {:.2} dB vs clean; wrote {} (clean images in {}/)",
        m.images,
        m.width,
        m.height,
        m.psf_px,
        a.imaging.mode,
        a.imaging.seed,
        r.seconds,
        m.mean_psnr,
        m.dest.display(),
        scenes::aberrated::CLEAN_DIR,
    );
    if let Some(line) = r.masks {
        println!("{line}");
    }
    Ok(())
}
