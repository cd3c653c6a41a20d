//! `metasplat demo`: the main job on built-in data. Simulates the paper's metalens PSF grid,
//! renders a procedural forward-facing scene with known ground truth, aberrates it, trains
//! `plain` and `aware` splats on the aberrated views, and compares both with the clean ones.

use aberration::image::save_rgb8_png;
use aberration::optics::SimConfig;
use clap::Args;
use std::path::{Path, PathBuf};

use super::Runner;
use crate::error::{Result, TrainError};
use crate::output::RunSummary;
use crate::settings::RunRequest;
use crate::splats::procedural::{ProceduralOptions, write_capture};
use crate::train::config::Mode;

/// The demo's plot of both modes' held-out PSNR over training.
pub const DEMO_PLOT: &str = "plain_vs_aware.png";

#[derive(Args)]
pub struct DemoArgs {
    /// Output directory.
    #[arg(long, default_value = "demo_out")]
    pub out: PathBuf,
    /// A small lens, a 64x48 scene and a short run (seconds; for tests).
    #[arg(long)]
    pub quick: bool,
    /// Training steps per mode (default 1500; 300 with --quick).
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=100_000_000))]
    pub iters: Option<u64>,
    /// Seed of the scene, the noise and training.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
}

/// A scene folder the demo made earlier is replaced; anything else is left alone.
fn clear_previous(dir: &Path) -> Result<()> {
    if dir.join("poses_bounds.npy").is_file() {
        std::fs::remove_dir_all(dir).map_err(|e| {
            TrainError::io(dir, e).context(format!("cannot replace {}", dir.display()))
        })?;
    } else if dir.exists() {
        return Err(TrainError::Invalid(format!(
            "{} exists and is not a scene the demo wrote; move it away",
            dir.display()
        )));
    }
    Ok(())
}

/// The file that marks a folder as the demo's: a later demo may replace what is in it.
const MARKER: &str = "demo.txt";

/// Refuses an --out that holds anything the demo did not write: the demo replaces its PSF
/// grid, scenes and runs, and must not replace a user's files of the same names.
fn refuse_foreign_folder(out: &Path) -> Result<()> {
    if !out.exists() {
        return Ok(());
    }
    crate::output::guard::refuse_file_as_folder("--out", out)?;
    let empty = std::fs::read_dir(out)
        .map_err(|e| TrainError::io(out, e).context("--out"))?
        .next()
        .is_none();
    // Folders of demos from before the marker have its layout.
    let demo_made = out.join(MARKER).is_file()
        || (out.join("scene_clean/poses_bounds.npy").is_file()
            && out
                .join("scene_aberrated")
                .join(scenes::aberrated::RECORD_FILE)
                .is_file());
    if empty || demo_made {
        return Ok(());
    }
    Err(TrainError::Invalid(format!(
        "--out {} holds files the demo did not write (it has no {MARKER}): the demo replaces its PSF grid, scenes and runs in its folder, so name a new or empty one",
        out.display()
    )))
}

/// What [`run`] made: each mode's summary and run folder (plain, then aware), the plot of
/// both, and the picture of the PSF grid.
pub struct DemoReport {
    pub runs: Vec<(Mode, RunSummary, PathBuf)>,
    pub plot: PathBuf,
    pub psf_picture: PathBuf,
}

/// Runs the demo `a` asks for into its folder, training each mode through `train`; `say`
/// hears each stage.
pub fn run(a: &DemoArgs, train: &mut Runner, say: &mut dyn FnMut(String)) -> Result<DemoReport> {
    refuse_foreign_folder(&a.out)?;
    std::fs::create_dir_all(&a.out).map_err(|e| TrainError::io(&a.out, e))?;
    base::write_bytes_atomically(
        &a.out.join(MARKER),
        b"Written by `metasplat demo`: a later demo into this folder replaces its contents.\n",
    )
    .map_err(|e| TrainError::io(a.out.join(MARKER), e))?;
    let cfg = if a.quick {
        SimConfig::small(21)
    } else {
        SimConfig::default()
    };
    say(format!(
        "1/4 simulating the {}x{} PSF grid of the Tseng et al. metalens ({} px PSFs, {}x{} propagation grid)",
        cfg.grid, cfg.grid, cfg.psf_size, cfg.fft_size, cfg.fft_size
    ));
    let (psf, report) = aberration::optics::simulate_grid(&cfg, &|_, _| {})?;
    say(format!(
        "simulated {} field angles x 3 wavelengths in {:.1} s",
        report.angles_deg.len(),
        report.seconds
    ));
    let psf_path = a.out.join("psf.npy");
    psf.save_npy(&psf_path)?;
    save_rgb8_png(
        &crate::output::plot::psf_figure(&psf, Some(cfg.wavelengths_nm), Some(cfg.max_field_deg)),
        &a.out.join("psf.png"),
    )?;

    let scene = ProceduralOptions {
        width: if a.quick { 64 } else { 160 },
        height: if a.quick { 48 } else { 120 },
        views: if a.quick { 10 } else { 12 },
        seed: a.seed,
    };
    let clean_dir = a.out.join("scene_clean");
    let aberrated_dir = a.out.join("scene_aberrated");
    clear_previous(&clean_dir)?;
    clear_previous(&aberrated_dir)?;
    say(format!(
        "2/4 rendering the procedural scene: {} views {}x{}",
        scene.views, scene.width, scene.height
    ));
    write_capture(&clean_dir, &scene)?;
    let capture = scenes::open(
        &clean_dir,
        &scenes::OpenOptions {
            resolution: scenes::Resolution::Downsample(1),
            ..Default::default()
        },
    )?;
    let options = scenes::AberrateOptions {
        seed: a.seed,
        ..Default::default()
    };
    let made = scenes::make_aberrated(&capture, &psf_path, &aberrated_dir, &options, &|| {})?;
    say(format!(
        "3/4 aberrated through {} px PSFs with sensor noise: {:.2} dB vs clean",
        made.psf_px, made.mean_psnr
    ));

    let iters = a.iters.unwrap_or(if a.quick { 300 } else { 1500 });
    let mut results: Vec<(Mode, RunSummary, PathBuf)> = Vec::new();
    let mut curves = Vec::new();
    for mode in [Mode::Plain, Mode::Aware] {
        say(format!("4/4 training {mode} ({iters} steps)"));
        let run_dir = a.out.join(format!("run_{mode}"));
        let mut args = RunRequest::new(&aberrated_dir, &run_dir);
        args.data.downsample = 1;
        args.data.seed = a.seed;
        args.training.mode = mode;
        args.training.iters = crate::settings::Iters::Steps(iters);
        args.training.checkpoint_every = Some(0);
        // The demo's own folders under --out: a second demo replaces them.
        args.overwrite = true;
        if a.quick {
            args.spiral = 4;
        }
        let (summary, log) = train(&args)?;
        curves.push(crate::output::plot::Series {
            name: format!("3DGS {mode}"),
            points: log
                .iter()
                .filter_map(|r| Some((r.step as f64, r.test_psnr?)))
                .collect(),
        });
        results.push((mode, summary, run_dir));
    }
    // Both modes on one plot, with the level of the photos they learn from.
    if let Some(observed) = results.first().and_then(|r| r.1.observed_psnr) {
        curves.push(crate::output::plot::Series {
            name: "aberrated input".into(),
            points: vec![(0.0, observed), (iters as f64, observed)],
        });
    }
    let plot = a.out.join(DEMO_PLOT);
    crate::output::plot::line_plot(
        &plot,
        "held-out PSNR: plain against aberration-aware 3DGS",
        "training step",
        "PSNR vs clean (dB)",
        &curves,
    )?;
    Ok(DemoReport {
        runs: results,
        plot,
        psf_picture: a.out.join("psf.png"),
    })
}
