//! `metasplat bench step`: the time of each phase of the training loop's own step on a
//! capture, at one or more thread counts, on the device training would use.
//! `metasplat bench restorer`: the restorer's forward passes and training steps with its fast
//! kernels and with the reference ones, alternated in one run.

use anyhow::{Context, Result, bail};
use clap::{Args, Subcommand};
use metasplat::settings::DataOptions;
use metasplat::settings::TrainSettings;
use metasplat::splats::device::{Device, DeviceChoice};
use metasplat::train::config::{Mode, TrainConfig};
use metasplat::train::data;
use metasplat::train::timing::{StepTimes, time_steps};
use restore::net::kernels::Kernels;
use restore::speed::{Sample, Workload, time_workload};
use restore::{Preset, RestorerConfig};
use std::path::PathBuf;

#[derive(Subcommand)]
pub enum BenchCommand {
    /// Time the phases of the training loop's step (render, blur, loss, adjoint, backward,
    /// Adam, densification statistics) for a few steps from the start of a run.
    Step(StepArgs),
    /// Time the restorer's forward passes and training steps (forward, backward, AdamW) with
    /// its fast kernels and with the reference kernels they replaced, alternated round by
    /// round, at each thread count: seconds, CPU seconds, the fast path's speed-up and its
    /// arithmetic rate.
    Restorer(RestorerBenchArgs),
}

#[derive(Args)]
pub struct RestorerBenchArgs {
    /// Network sizes to time (random weights: the time does not depend on them).
    #[arg(long, value_enum, value_delimiter = ',', default_values_t = [Preset::Tiny, Preset::Small])]
    pub configs: Vec<Preset>,
    /// Tile sides of the forward passes, in px (multiples of each config's padding unit).
    #[arg(long, value_delimiter = ',', default_values_t = [256usize, 512])]
    pub sides: Vec<usize>,
    /// Crops per training step (of each config's training crop size); 0 leaves training out.
    #[arg(long, default_value_t = 4)]
    pub batch: usize,
    /// Side of the training crops, in px (a multiple of each config's padding unit); default:
    /// each config's training crop.
    #[arg(long)]
    pub crop: Option<usize>,
    /// Time training steps only, no forward passes.
    #[arg(long, conflicts_with = "sides")]
    pub train_only: bool,
    /// Thread counts to time, in order.
    #[arg(long, value_delimiter = ',', default_values_t = [1usize, 2])]
    pub threads: Vec<usize>,
    /// Rounds: each times the reference kernels, then the fast ones; the median is reported.
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u64).range(1..=100))]
    pub rounds: u64,
    /// Where to run: `cpu` (burn flex), or `libtorch` / `vulkan` in a build with that
    /// feature (libtorch's threads: `OMP_NUM_THREADS`, not --threads).
    #[arg(long, default_value = "cpu")]
    pub backend: restore::Compute,
    /// Time only the fast kernels (e.g. under `perf record`, so that a profile holds one
    /// path); the reference columns are left empty.
    #[arg(long)]
    pub fast_only: bool,
}

#[derive(Args)]
pub struct StepArgs {
    /// The capture to train on (an aberrated one for `aware`).
    #[arg(long)]
    pub scene: PathBuf,
    /// Which loss the timed steps train with.
    #[arg(long, value_enum, default_value_t = Mode::Aware)]
    pub mode: Mode,
    /// A splat scene to start from (e.g. a trained run's PLY); default: the capture's points.
    #[arg(long)]
    pub ply: Option<PathBuf>,
    /// Training steps timed at each thread count.
    #[arg(long, default_value_t = 20, value_parser = clap::value_parser!(u64).range(1..=100_000))]
    pub steps: u64,
    /// Thread counts to time, in order.
    #[arg(long, value_delimiter = ',', default_values_t = [1usize, 2], value_parser = clap::value_parser!(usize))]
    pub threads: Vec<usize>,
    /// Where to train: as `train --device` (`auto`, `cpu`, `gpu`).
    #[arg(long, value_enum, default_value_t = DeviceChoice::Auto)]
    pub device: DeviceChoice,
    /// Also time the same steps with `--refine-psf` updating the PSF grid on every step (aware
    /// mode), side by side: what refining the PSF adds to a step.
    #[arg(long)]
    pub refine_psf: bool,
    #[command(flatten)]
    pub data: DataOptions,
}

pub fn run(cmd: BenchCommand) -> Result<()> {
    match cmd {
        BenchCommand::Step(a) => step(a),
        BenchCommand::Restorer(a) => restorer(a),
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// The workloads `bench restorer` times, every size checked first.
fn restorer_cases(
    a: &RestorerBenchArgs,
    configs: &[RestorerConfig],
) -> Result<Vec<(RestorerConfig, Workload)>> {
    if a.train_only && a.batch == 0 {
        bail!("--train-only with --batch 0 leaves nothing to time");
    }
    for cfg in configs.iter().filter(|_| !a.train_only) {
        let m = cfg.multiple();
        if let Some(s) = a.sides.iter().find(|&&s| s == 0 || !s.is_multiple_of(m)) {
            bail!(
                "--sides: {s} px is not a positive multiple of {m} px, the padding unit of '{}'",
                cfg.name
            );
        }
    }
    let mut cases: Vec<(RestorerConfig, Workload)> = Vec::new();
    for cfg in configs {
        if !a.train_only {
            for &side in &a.sides {
                cases.push((cfg.clone(), Workload::Forward { side }));
            }
        }
        if a.batch > 0 {
            let side = a.crop.unwrap_or(cfg.crop);
            if side == 0 || !side.is_multiple_of(cfg.multiple()) {
                bail!(
                    "--crop: {side} px is not a positive multiple of {} px, the padding unit of '{}'",
                    cfg.multiple(),
                    cfg.name
                );
            }
            let w = Workload::TrainStep {
                batch: a.batch,
                side,
            };
            cases.push((cfg.clone(), w));
        }
    }
    Ok(cases)
}

fn restorer(a: RestorerBenchArgs) -> Result<()> {
    if a.threads.iter().any(|&t| t == 0 || t > 1024) {
        bail!("--threads: thread counts are 1 to 1024");
    }
    let configs: Vec<RestorerConfig> = a
        .configs
        .iter()
        .map(|&p| RestorerConfig::preset(p))
        .collect();
    let device = a.backend.device().context("--backend")?;
    let cases = restorer_cases(&a, &configs)?;
    println!(
        "The restorer's reference and fast kernels, alternated over {} round{}; medians. \
         s/MP is wall seconds per megapixel; GFLOP/s counts the analytic operations (a \
         training step as three forward passes).",
        a.rounds,
        if a.rounds == 1 { "" } else { "s" }
    );
    println!(
        "{:<6} {:<20} {:>7} {:>12} {:>12} {:>8} {:>12} {:>10} {:>10}",
        "config",
        "workload",
        "threads",
        "reference s",
        "fast s",
        "speed-up",
        "fast CPU s",
        "fast s/MP",
        "GFLOP/s"
    );
    for (cfg, workload) in &cases {
        for &threads in &a.threads {
            let mut runs: [Vec<Sample>; 2] = [Vec::new(), Vec::new()];
            for round in 0..a.rounds {
                for (i, kernels) in [Kernels::Reference, Kernels::Fast].into_iter().enumerate() {
                    if a.fast_only && kernels == Kernels::Reference {
                        continue;
                    }
                    let s = time_workload(cfg, *workload, kernels, threads, 1, round, &device)
                        .with_context(|| format!("timing {} {}", cfg.name, workload.describe()))?;
                    runs[i].extend(s);
                }
            }
            print_restorer_row(cfg, *workload, threads, &runs);
        }
    }
    Ok(())
}

/// One row of `bench restorer`'s table: medians of the reference and fast runs.
fn print_restorer_row(
    cfg: &RestorerConfig,
    workload: Workload,
    threads: usize,
    runs: &[Vec<Sample>; 2],
) {
    let wall = |r: &[Sample]| median(r.iter().map(|s| s.wall_s).collect());
    let cpu = |r: &[Sample]| median(r.iter().map(|s| s.cpu_s).collect());
    let fast = wall(&runs[1]);
    // With --fast-only the reference was not run: its columns say so.
    let (reference, speed_up) = if runs[0].is_empty() {
        ("-".to_string(), "-".to_string())
    } else {
        let r = wall(&runs[0]);
        (format!("{r:.3}"), format!("{:.2}x", r / fast))
    };
    let mp = workload.pixels() as f64 / 1e6;
    let passes = match workload {
        Workload::Forward { .. } => 1.0,
        Workload::TrainStep { .. } => 3.0,
    };
    let gflop = cfg.analytic_flops_per_pixel() * workload.pixels() as f64 * passes / 1e9;
    println!(
        "{:<6} {:<20} {:>7} {:>12} {:>12.3} {:>8} {:>12.3} {:>10.2} {:>10.2}",
        cfg.name,
        workload.describe(),
        threads,
        reference,
        fast,
        speed_up,
        cpu(&runs[1]),
        fast / mp,
        gflop / fast
    );
}

fn step(a: StepArgs) -> Result<()> {
    if a.threads.iter().any(|&t| t == 0 || t > 1024) {
        bail!("--threads: thread counts are 1 to 1024");
    }
    if a.refine_psf && a.mode != Mode::Aware {
        bail!("--refine-psf: only aware steps blur through the PSF grid");
    }
    let initial = a
        .ply
        .as_ref()
        .map(|p| {
            splat::formats::files::read_splats(p)
                .with_context(|| format!("--ply {}", p.display()))
                .and_then(|g| {
                    if g.is_empty() {
                        bail!("--ply {}: the scene has no splats", p.display())
                    }
                    Ok(g)
                })
        })
        .transpose()?;
    let (device, device_note) = Device::choose(a.device)?;
    let mut data = data::load(&a.scene, a.mode, &a.data)
        .with_context(|| format!("cannot load the scene {}", a.scene.display()))?;
    data.initial = initial;
    let settings = TrainSettings {
        mode: a.mode,
        iters: metasplat::settings::Iters::Steps(a.steps),
        eval_every: Some(0),
        checkpoint_every: Some(0),
        // The step at the capture's size: coarse to fine would make the first tenth of the
        // measured steps smaller ones.
        coarse_to_fine: metasplat::settings::CoarseToFine::Off,
        ..TrainSettings::default()
    };
    let config = TrainConfig::build(&settings, a.data.seed, &data);
    println!(
        "{} training steps of mode {} (λ {}) at {}x{} ({} views), the training loop's own step. {device_note}",
        a.steps,
        a.mode,
        config.lambda,
        data.width,
        data.height,
        data.train.len()
    );
    // One untimed step first: page faults and lazy set-up are not a phase.
    let warm = TrainConfig {
        iters: 1,
        ..config.clone()
    };
    time_steps(&data, &warm, &device, a.threads[0])?;
    let runs = a
        .threads
        .iter()
        .map(|&t| time_steps(&data, &config, &device, t))
        .collect::<Result<Vec<_>, _>>()?;
    print_step_table(&runs);
    if a.refine_psf {
        time_refinement(&a, &data, &config, &device)?;
    }
    Ok(())
}

/// The same steps with the PSF grid refined on every step, beside plain aware ones.
fn time_refinement(
    a: &StepArgs,
    data: &data::Dataset,
    config: &TrainConfig,
    device: &Device,
) -> Result<()> {
    let defaults = metasplat::train::psf_refine::PsfRefineConfig::for_iters(
        a.steps,
        metasplat::train::psf_refine::PsfModel::Warp,
    );
    let refining = TrainConfig {
        refine_psf: Some(metasplat::train::psf_refine::PsfRefineConfig {
            from: 0,
            every: 1,
            ..defaults
        }),
        ..config.clone()
    };
    println!(
        "\nThe same steps with the PSF grid refined on every step, beside the plain aware ones (medians of alternated rounds):"
    );
    for &t in &a.threads {
        let (mut plain, mut refined, mut gradient, mut update) =
            (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        for _ in 0..3 {
            plain.push(time_steps(data, config, device, t)?.step);
            let r = time_steps(data, &refining, device, t)?;
            gradient.push(r.phase("PSF gradient"));
            update.push(r.phase("PSF update"));
            refined.push(r.step);
        }
        let (p, r) = (median(plain), median(refined));
        let (gr, up) = (median(gradient), median(update));
        let g = gr + up;
        println!(
            "{t} thread{}: aware {p:.1} ms, with the PSF refined {r:.1} ms (+{:.0} %); the PSF gradient takes {gr:.1} ms and the update {up:.1} ms, so updating every {} steps (the default) adds {:.0} %.",
            if t == 1 { "" } else { "s" },
            100.0 * (r - p) / p,
            defaults.every,
            100.0 * g / defaults.every.max(1) as f64 / p
        );
    }
    Ok(())
}

/// Milliseconds per step by phase, one column per thread count.
fn print_step_table(runs: &[StepTimes]) {
    let mut names: Vec<&str> = Vec::new();
    for r in runs {
        for (name, _) in &r.phases {
            if !names.contains(name) {
                names.push(name);
            }
        }
    }
    print!("{:<40}", "ms per step (wall)");
    for r in runs {
        print!(
            "{:>14}",
            format!(
                "{} thread{}",
                r.threads,
                if r.threads == 1 { "" } else { "s" }
            )
        );
    }
    println!();
    let row = |name: &str, value: &dyn Fn(&StepTimes) -> f64| {
        print!("{name:<40}");
        for r in runs {
            let v = value(r);
            print!("{:>14}", format!("{v:.1} ({:.0} %)", 100.0 * v / r.step));
        }
        println!();
    };
    for name in &names {
        row(name, &|r| r.phase(name));
    }
    row("hooks and the rest", &|r| r.other());
    print!("{:<40}", "whole step");
    for r in runs {
        print!("{:>14}", format!("{:.1}", r.step));
    }
    println!();
    if let (Some(one), Some(last)) = (runs.iter().find(|r| r.threads == 1), runs.last())
        && last.threads > 1
    {
        println!(
            "{} threads run a step {:.2}x as fast as one.",
            last.threads,
            one.step / last.step
        );
    }
}
