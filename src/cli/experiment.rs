//! `metasplat experiment llff`: the paper's comparison on a real capture. Makes the
//! aberrated capture, trains plain, restored and aware with identical settings, and prints
//! one table (PSNR/SSIM against the clean images, minutes, splats) plus test PSNR reached
//! against training time: the speed-against-error report of the main job.

use super::psf::{print_report, simulate};
use super::train::train_run;
use aberration::optics::SimConfig;
use anyhow::{Context, Result};
use clap::{Args, Subcommand};
use metasplat::plot::{Series, line_plot};
use metasplat::run::RunRequest;
use metasplat::train::config::Mode;
use std::fmt::Write as _;
use std::path::PathBuf;

#[derive(Subcommand)]
pub enum ExperimentCommand {
    /// Plain vs restored vs aware on an LLFF capture (e.g. ../shared/data/llff/fern).
    Llff(LlffArgs),
}

#[derive(Args)]
pub struct LlffArgs {
    /// The clean capture.
    #[arg(long)]
    pub scene: PathBuf,
    #[arg(long)]
    pub out: PathBuf,
    /// PSF grid; default: simulate the paper's 9x9 grid.
    #[arg(long)]
    pub psf: Option<PathBuf>,
    #[arg(long, default_value_t = 3000, value_parser = clap::value_parser!(u64).range(1..=100_000_000))]
    pub iters: u64,
    #[arg(long, default_value_t = 8, value_parser = clap::value_parser!(u32).range(1..=64))]
    pub downsample: u32,
    /// Weight of L(render, I_ac) in aware mode (default: as `train`).
    #[arg(long, value_parser = metasplat::flags::weight, allow_negative_numbers = true)]
    pub lambda: Option<f32>,
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Modes to run, in order.
    #[arg(long, value_enum, value_delimiter = ',', default_values_t = Mode::ALL.to_vec())]
    pub modes: Vec<Mode>,
    /// Where to render: `auto` (a hardware GPU when there is one), `cpu`, or `gpu`.
    #[arg(long, value_enum, default_value_t = metasplat::device::DeviceChoice::Auto)]
    pub device: metasplat::device::DeviceChoice,
    /// Replace runs already in --out (otherwise a folder holding a run is refused).
    #[arg(long)]
    pub overwrite: bool,
}

pub fn run(cmd: ExperimentCommand) -> Result<()> {
    let ExperimentCommand::Llff(a) = cmd;
    let mut inputs = vec![("--scene", a.scene.as_path())];
    if let Some(p) = &a.psf {
        inputs.push(("--psf", p));
    }
    metasplat::guard::refuse_overwrite("--out", &a.out, &inputs)?;
    // Every input is read and checked before --out is made: the capture (unless an earlier
    // run already made the aberrated copy) and the PSF grid given.
    let aberrated = a.out.join("aberrated");
    let capture = if aberrated.join(scenes::aberrated::RECORD_FILE).exists() {
        None
    } else {
        let capture = super::open_scene(&a.scene, a.downsample)?;
        super::decode_all(&capture)?;
        Some(capture)
    };
    if let Some(p) = &a.psf {
        aberration::PsfGrid::load_npy(p)?;
    }
    std::fs::create_dir_all(&a.out)
        .with_context(|| format!("cannot create {}", a.out.display()))?;
    let psf_path = match &a.psf {
        Some(p) => p.clone(),
        None => {
            let path = a.out.join("psf.npy");
            if !path.exists() {
                let (psf, report) = simulate(&SimConfig::default())?;
                print_report(&report);
                psf.save_npy(&path)?;
            }
            path
        }
    };
    if let Some(capture) = capture {
        let options = scenes::AberrateOptions {
            seed: a.seed,
            ..Default::default()
        };
        let made = scenes::make_aberrated(&capture, &psf_path, &aberrated, &options, &|| {})?;
        println!(
            "aberrated {} images {}x{} ({} px PSFs): {:.2} dB vs clean",
            made.images, made.width, made.height, made.psf_px, made.mean_psnr
        );
    }

    let mut rows = Vec::new();
    for &mode in &a.modes {
        let run_dir = a.out.join(format!("run_{mode}"));
        let mut args = RunRequest::new(&aberrated, run_dir);
        args.data.downsample = a.downsample;
        args.data.seed = a.seed;
        args.device = a.device;
        args.overwrite = a.overwrite;
        args.training.mode = mode;
        args.training.iters = a.iters;
        args.training.lambda = a.lambda;
        args.training.eval_every = Some((a.iters / 20).max(1));
        let (summary, log) = train_run(&args, false)?;
        rows.push((mode, summary, log));
    }

    let mut table = String::new();
    let observed = rows
        .iter()
        .find_map(|r| r.1.observed_psnr)
        .unwrap_or(f64::NAN);
    writeln!(
        table,
        "| method | PSNR (dB) | SSIM | minutes | splats | SH |"
    )?;
    writeln!(table, "|---|---:|---:|---:|---:|---:|")?;
    writeln!(table, "| aberrated input | {observed:.2} | | | | |")?;
    for (mode, s, _) in &rows {
        let (p, ss) = s
            .metrics
            .as_ref()
            .map_or((f64::NAN, f64::NAN), |m| (m.mean_psnr, m.mean_ssim));
        let name = match mode {
            Mode::Plain => "3D-GS (plain)",
            Mode::Restored => "3D-GS w/ restored I_ac",
            Mode::Aware => "3D-GS + aberration-aware",
        };
        writeln!(
            table,
            "| {name} | {p:.2} | {ss:.4} | {:.1} | {} | {} |",
            s.train_seconds / 60.0,
            s.splats,
            s.sh_degree
        )?;
    }
    writeln!(
        table,
        "\nheld-out PSNR (dB) reached vs training time and splat count:"
    )?;
    for (mode, _, log) in &rows {
        let points: Vec<String> = log
            .iter()
            .filter_map(|r| {
                r.test_psnr
                    .map(|p| format!("{:.0}s/{}k: {p:.2}", r.seconds, r.splats / 1000))
            })
            .collect();
        writeln!(table, "- {mode}: {}", points.join(", "))?;
    }
    println!("\n{table}");
    if let Some(r) = rows.iter().find_map(|(_, s, _)| s.restorer.clone()) {
        println!("({r})");
    }
    let table_path = a.out.join("table.md");
    base::write_bytes_atomically(&table_path, table.as_bytes())
        .with_context(|| format!("cannot write {}", table_path.display()))?;
    let series: Vec<Series> = rows
        .iter()
        .map(|(mode, _, log)| Series {
            name: mode.to_string(),
            points: log
                .iter()
                .filter_map(|r| r.test_psnr.map(|p| (r.seconds, p)))
                .collect(),
        })
        .collect();
    line_plot(
        &a.out.join("psnr_vs_time.png"),
        "held-out PSNR vs training time",
        "training time (s)",
        "PSNR vs clean (dB)",
        &series,
    )?;
    println!("wrote {}/table.md and psnr_vs_time.png", a.out.display());
    Ok(())
}
