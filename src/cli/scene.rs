//! `metasplat scene info` and `metasplat scene aberrate`.

use super::progress::bar;
use anyhow::{Context, Result};
use clap::{Args, Subcommand};
use scenes::BitDepth;
use std::path::PathBuf;
use std::time::Instant;

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

#[derive(Args)]
pub struct SceneAberrateArgs {
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
    pub imaging: metasplat::settings::imaging::ImagingArgs,
    /// Blur the photos as taken even when the cameras have lens distortion (by default they
    /// are undistorted at load first, and the copy's cameras are pinhole).
    #[arg(long)]
    pub keep_distortion: bool,
    /// PNG sample depth of the written images (8 or 16); 16 keeps the sensor noise.
    #[arg(long, default_value_t = 16, value_parser = clap::value_parser!(u8).range(8..=16))]
    pub bit_depth: u8,
}

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
    metasplat::output::guard::refuse_overwrite(
        "--out",
        &a.out,
        &[("--scene", &a.scene), ("--psf", &a.psf)],
    )?;
    metasplat::output::guard::refuse_aberrated_source("--scene", &a.scene)?;
    let capture = metasplat::settings::open_scene(&a.scene, a.downsample, a.keep_distortion)?;
    let mut inputs =
        metasplat::output::guard::Inputs::of(&[("--scene", &a.scene), ("--psf", &a.psf)]);
    inputs.add_capture(&capture);
    inputs.refuse("--out", &a.out)?;
    let options = scenes::AberrateOptions {
        mode: a.imaging.mode,
        sensor_px: a.imaging.sensor_px,
        noise: a.imaging.noise(),
        seed: a.imaging.seed,
        depth: match a.bit_depth {
            8 => BitDepth::Eight,
            16 => BitDepth::Sixteen,
            other => anyhow::bail!("--bit-depth must be 8 or 16, not {other}"),
        },
    };
    // A bad PSF file is the flag's error, found before the lock, the bar and the staging.
    aberration::PsfGrid::load_npy(&a.psf).with_context(|| format!("--psf {}", a.psf.display()))?;
    // The capture appears by renaming its staging folder into place; the lock beside it keeps
    // a second maker from doing the work only to fail at the end (or to win a race).
    let _lock = base::FolderLock::beside(&a.out, "scene aberrate")?;
    let pb = bar(capture.len() as u64, "aberrating");
    let start = Instant::now();
    let report = scenes::make_aberrated(&capture, &a.psf, &a.out, &options, &|| pb.inc(1))
        .with_context(|| format!("cannot write the aberrated capture {}", a.out.display()))?;
    pb.finish_and_clear();
    println!(
        "{} images {}x{} through {} px PSFs ({} mode, seed {}) in {:.1} s: mean PSNR {:.2} dB vs clean; wrote {} (clean images in {}/)",
        report.images,
        report.width,
        report.height,
        report.psf_px,
        a.imaging.mode,
        a.imaging.seed,
        start.elapsed().as_secs_f64(),
        report.mean_psnr,
        report.dest.display(),
        scenes::aberrated::CLEAN_DIR,
    );
    if report.masked && !capture.has_own_masks() {
        println!(
            "Undistortion leaves border pixels without a source: each photo was composited over black there before the blur, and the border is carried as masks beside the copy's photos (they leave its pixels out of the loss; the record says they are not an object's)."
        );
    } else if report.masked {
        println!(
            "The capture has masks ({}): each photo was composited over black outside its mask before the blur, so the copy is the object alone, and the masks are carried beside the copy's photos.",
            capture.mask_source()
        );
    }
    Ok(())
}
