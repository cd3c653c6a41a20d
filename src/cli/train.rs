//! `metasplat train`: an aberrated capture in, a clean splat scene out.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use metasplat::outputs::{self, CHECKPOINT_FILE, RunSummary};
use metasplat::train::config::{Mode, Recipe, TrainConfig};
use metasplat::train::data::{self, DataOptions, RestorerChoice};
use metasplat::train::{self, Event};

#[derive(Args, Clone)]
pub struct TrainArgs {
    /// Capture directory (LLFF or COLMAP); an aberrated capture from `scene aberrate` carries
    /// its PSF grid and clean images.
    #[arg(long)]
    pub scene: PathBuf,
    /// Run folder (created; checkpoint, PLY, metrics, renders).
    #[arg(long)]
    pub out: PathBuf,
    /// PSF grid .npy; must match the capture's own psf.npy when it has one.
    #[arg(long)]
    pub psf: Option<PathBuf>,
    #[arg(long, value_enum, default_value_t = Mode::Aware)]
    pub mode: Mode,
    /// Weight of L(render, I_ac) in aware mode; default 0.75 (the paper's) with a trained
    /// restorer, 0.25 with the median-Wiener stand-in.
    #[arg(long)]
    pub lambda: Option<f32>,
    #[arg(long, default_value_t = 7000)]
    pub iters: u64,
    /// Splat budget; default: one per two pixels of a view.
    #[arg(long)]
    pub max_splats: Option<usize>,
    /// Source of I_ac: `auto` (the shipped transformer when trained for this PSF grid, else
    /// the median MAFG Wiener image), `wiener`, or a restorer weights file.
    #[arg(long, default_value = "auto")]
    pub restorer: RestorerChoice,
    /// Continue from RUN/checkpoint.bin (same settings required).
    #[arg(long)]
    pub resume: bool,
    /// Use images_N (1: images/).
    #[arg(long, default_value_t = 8)]
    pub downsample: u32,
    #[arg(long, default_value_t = 8)]
    pub llffhold: usize,
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    #[arg(long, default_value_t = 3)]
    pub max_sh_degree: u32,
    /// Reset opacities as 3DGS does (the paper turned this off for LLFF scenes).
    #[arg(long)]
    pub opacity_reset: bool,
    /// Held-out evaluation every N steps (default: 10 times per run).
    #[arg(long)]
    pub eval_every: Option<u64>,
    /// Checkpoint every N steps (default: 5 times per run).
    #[arg(long)]
    pub checkpoint_every: Option<u64>,
    /// Spiral frames to render at the end.
    #[arg(long, default_value_t = 30)]
    pub spiral: usize,
}

impl TrainArgs {
    /// The command-line defaults for one run (as `metasplat train` would use them).
    pub fn new(scene: PathBuf, out: PathBuf, mode: Mode, iters: u64, downsample: u32) -> Self {
        TrainArgs {
            scene,
            out,
            psf: None,
            mode,
            lambda: None,
            iters,
            max_splats: None,
            restorer: RestorerChoice::Auto,
            resume: false,
            downsample,
            llffhold: scenes::LLFFHOLD,
            seed: 0,
            max_sh_degree: 3,
            opacity_reset: false,
            eval_every: None,
            checkpoint_every: None,
            spiral: 30,
        }
    }
}

/// Trains one run and writes its folder; shared by `train`, `experiment` and `demo`.
/// Returns what went into `metrics.json` and the training log.
pub fn train_run(a: &TrainArgs, quiet: bool) -> Result<(RunSummary, Vec<train::LogRow>)> {
    outputs::prepare_run_dir(&a.out)
        .with_context(|| format!("cannot use {} as the run folder", a.out.display()))?;
    let options = DataOptions {
        downsample: a.downsample,
        llffhold: a.llffhold,
        psf: a.psf.clone(),
        restorer: a.restorer.clone(),
        seed: a.seed,
    };
    let data = data::load(&a.scene, a.mode, &options)
        .with_context(|| format!("cannot load the scene {}", a.scene.display()))?;
    let mut config = TrainConfig::new(a.mode, a.iters, data.width, data.height);
    config.lambda = a
        .lambda
        .unwrap_or_else(|| data.restorer.as_ref().map_or(0.75, |r| r.default_lambda()));
    config.i_ac = data.restorer.as_ref().map(|r| r.identity());
    config.seed = a.seed;
    config.max_sh_degree = a.max_sh_degree;
    config.recipe = Recipe::for_iters(a.iters, a.opacity_reset);
    if let Some(m) = a.max_splats {
        config.max_splats = m;
    }
    if let Some(e) = a.eval_every {
        config.eval_every = e;
    }
    if let Some(c) = a.checkpoint_every {
        config.checkpoint_every = c;
    }
    if !quiet {
        println!(
            "{} views {}x{} ({} train, {} test), {} initial points, mode {}, {} steps, budget {} splats",
            data.capture.len(),
            data.width,
            data.height,
            data.train.len(),
            data.test.len(),
            data.points.len(),
            a.mode,
            a.iters,
            config.max_splats
        );
        if let Some(note) = &data.restorer_note {
            println!("{note}");
        }
        if let Some(r) = &data.restorer {
            println!("{}", r.describe());
            if a.mode == Mode::Aware {
                println!("lambda {} for L(render, I_ac)", config.lambda);
            }
        }
        if !data.can_evaluate() {
            println!(
                "no clean images for the held-out views: training runs, but cannot be compared with ground truth"
            );
        }
    }
    outputs::write_json(&a.out.join("config.json"), &config)?;

    let pb = if quiet {
        ProgressBar::hidden()
    } else {
        ProgressBar::new(a.iters)
    };
    pb.set_style(
        ProgressStyle::with_template(
            "{prefix:>8} [{bar:30}] {pos}/{len} {msg} {per_sec} ETA {eta}",
        )
        .expect("static template")
        .progress_chars("=> "),
    );
    pb.set_prefix(a.mode.to_string());
    let mut last_test = None;
    // Frequent events go into the bar's message; rare ones get a line of their own.
    let mut last_edit = String::new();
    let mut on_event = |e: Event| match e {
        Event::Step {
            step,
            loss,
            splats,
            sh_degree,
            ..
        } => {
            pb.set_position(step);
            if step % 10 == 0 {
                let parts = match loss.restored {
                    Some(r) => format!("L_abr {:.4} L_ac {r:.4}", loss.main),
                    None => format!("loss {:.4}", loss.total),
                };
                let test = last_test.map_or(String::new(), |p: f64| format!(" test {p:.2} dB"));
                pb.set_message(format!(
                    "{parts} train {:.2} dB{test} | {splats} splats SH{sh_degree}{last_edit}",
                    loss.psnr
                ));
            }
        }
        Event::Evaluated { metrics, .. } => last_test = Some(metrics.mean_psnr),
        // A band that stays is routine; one raised or dropped changes the model.
        Event::Sh {
            step,
            event: event @ train::sh::ShEvent::Kept { .. },
        } => last_edit = format!(" | step {step}: {event}"),
        Event::Sh { step, event } => {
            super::progress::say(&pb, format!("Step {step}: {event}."));
        }
        Event::Densified { step, edit, .. } => {
            last_edit = format!(" | step {step}: {edit}");
        }
        Event::Unseen { step, pruned } => {
            last_edit = format!(" | step {step}: {pruned} splats no view saw were pruned");
        }
        Event::Checkpoint { .. } => {}
    };
    let ckpt = a.out.join(CHECKPOINT_FILE);
    // A fresh run must not leave an older run's checkpoint for a later --resume to pick up.
    if !a.resume && ckpt.exists() {
        std::fs::remove_file(&ckpt)
            .with_context(|| format!("cannot replace {}", ckpt.display()))?;
    }
    let outcome = train::train(&config, &data, Some(&ckpt), a.resume, &mut on_event)?;
    pb.finish_and_clear();
    let summary = outputs::write_run(&a.out, &data, &config, &outcome, a.spiral)
        .with_context(|| format!("cannot write the run folder {}", a.out.display()))?;
    if let Some(plot) = plot_log(&a.out, &outcome.log) {
        plot?;
    }
    if !quiet {
        print_summary(&a.out, &summary, &outcome);
    }
    Ok((summary, outcome.log))
}

/// The PSNR-vs-time picture, when there are test PSNRs to plot.
fn plot_log(dir: &Path, log: &[train::LogRow]) -> Option<Result<()>> {
    let points: Vec<(f64, f64)> = log
        .iter()
        .filter_map(|r| r.test_psnr.map(|p| (r.seconds, p)))
        .collect();
    if points.is_empty() {
        return None;
    }
    let series = [metasplat::plot::Series {
        name: "held-out PSNR".into(),
        points,
    }];
    Some(
        metasplat::plot::line_plot(
            &dir.join(PSNR_PLOT),
            "held-out PSNR vs training time",
            "training time (s)",
            "PSNR vs clean (dB)",
            &series,
        )
        .map_err(Into::into),
    )
}

pub const PSNR_PLOT: &str = "psnr_vs_time.png";

fn print_summary(dir: &Path, s: &RunSummary, outcome: &train::Outcome) {
    if let Some(from) = outcome.resumed_from {
        println!("resumed from step {from}");
    }
    match &s.metrics {
        Some(m) => {
            println!("{:<16} {:>8} {:>7}", "test view", "PSNR", "SSIM");
            for v in &m.views {
                println!("{:<16} {:>8.2} {:>7.4}", v.name, v.psnr, v.ssim);
            }
            println!("{:<16} {:>8.2} {:>7.4}", "mean", m.mean_psnr, m.mean_ssim);
            if let Some(o) = s.observed_psnr {
                println!("(observed images vs clean: {o:.2} dB)");
            }
        }
        None => println!(
            "not evaluated: {}",
            s.not_evaluated.as_deref().unwrap_or("no metrics")
        ),
    }
    println!(
        "{} steps in {:.1} s; {} splats ({:.1} MB, SH degree {}); {} never-visible splats dropped at the end; wrote {}",
        s.iters,
        s.train_seconds,
        s.splats,
        s.model_bytes as f64 / 1e6,
        s.sh_degree,
        outcome.final_pruned,
        dir.join(outputs::PLY_FILE).display()
    );
}

pub fn run(a: TrainArgs) -> Result<()> {
    train_run(&a, false).map(|_| ())
}
