//! `metasplat bench step`: the time of each phase of the training loop's own step on a
//! capture, at one or more thread counts, on the device training would use.

use anyhow::{Context, Result, bail};
use clap::{Args, Subcommand};
use metasplat::bench::{StepTimes, time_steps};
use metasplat::device::{Device, DeviceChoice};
use metasplat::settings::DataOptions;
use metasplat::settings::TrainSettings;
use metasplat::train::config::{Mode, TrainConfig};
use metasplat::train::data;
use std::path::PathBuf;

#[derive(Subcommand)]
pub enum BenchCommand {
    /// Time the phases of the training loop's step (render, blur, loss, adjoint, backward,
    /// Adam, densification statistics) for a few steps from the start of a run.
    Step(StepArgs),
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
    #[command(flatten)]
    pub data: DataOptions,
}

pub fn run(cmd: BenchCommand) -> Result<()> {
    let BenchCommand::Step(a) = cmd;
    if a.threads.iter().any(|&t| t == 0 || t > 1024) {
        bail!("--threads: thread counts are 1 to 1024");
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
        iters: a.steps,
        eval_every: Some(0),
        checkpoint_every: Some(0),
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
    let mut names: Vec<&str> = Vec::new();
    for r in &runs {
        for (name, _) in &r.phases {
            if !names.contains(name) {
                names.push(name);
            }
        }
    }
    print!("{:<40}", "ms per step (wall)");
    for r in &runs {
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
        for r in &runs {
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
    for r in &runs {
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
    Ok(())
}
