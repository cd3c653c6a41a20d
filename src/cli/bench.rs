//! `metasplat bench step`: the time of each phase of a training step on a capture, at one or
//! more thread counts (CPU rasterizer).

use anyhow::{Context, Result, bail};
use clap::{Args, Subcommand};
use metasplat::bench::{PHASES, time_steps};
use metasplat::train::config::Mode;
use metasplat::train::data::{self, DataOptions};
use std::path::PathBuf;

#[derive(Subcommand)]
pub enum BenchCommand {
    /// Time the phases of a training step (render, blur, loss, adjoint, backward, Adam).
    Step(StepArgs),
}

#[derive(Args)]
pub struct StepArgs {
    /// The capture to train on (an aberrated one for `aware`).
    #[arg(long)]
    pub scene: PathBuf,
    #[arg(long, value_enum, default_value_t = Mode::Aware)]
    pub mode: Mode,
    /// A splat scene to step (e.g. a trained run's PLY); default: the capture's points.
    #[arg(long)]
    pub ply: Option<PathBuf>,
    #[arg(long, default_value_t = 20, value_parser = clap::value_parser!(u64).range(1..=100_000))]
    pub steps: u64,
    /// Thread counts to time, in order.
    #[arg(long, value_delimiter = ',', default_values_t = [1usize, 2], value_parser = clap::value_parser!(usize))]
    pub threads: Vec<usize>,
    #[command(flatten)]
    pub data: DataOptions,
}

pub fn run(cmd: BenchCommand) -> Result<()> {
    let BenchCommand::Step(a) = cmd;
    if a.threads.iter().any(|&t| t == 0 || t > 1024) {
        bail!("--threads: thread counts are 1 to 1024");
    }
    let data = data::load(&a.scene, a.mode, &a.data)
        .with_context(|| format!("cannot load the scene {}", a.scene.display()))?;
    let model = match &a.ply {
        Some(p) => splat::files::read_splats(p)?,
        None => metasplat::init::from_points(&data.points, 0),
    };
    if model.is_empty() {
        bail!("the model to step has no splats");
    }
    let lambda = data::default_lambda(data.restorer.as_ref());
    println!(
        "{} training steps of mode {} on {} splats at {}x{} ({} views), CPU rasterizer:",
        a.steps,
        a.mode,
        model.len(),
        data.width,
        data.height,
        data.train.len()
    );
    // One untimed step first: page faults and lazy set-up are not a phase.
    time_steps(&data, a.mode, lambda, &model, 1, a.threads[0])?;
    let runs = a
        .threads
        .iter()
        .map(|&t| time_steps(&data, a.mode, lambda, &model, a.steps as usize, t))
        .collect::<Result<Vec<_>, _>>()?;
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
    for (i, name) in PHASES.iter().enumerate() {
        print!("{name:<40}");
        for r in &runs {
            print!(
                "{:>14}",
                format!(
                    "{:.1} ({:.0} %)",
                    r.phases[i],
                    100.0 * r.phases[i] / r.total()
                )
            );
        }
        println!();
    }
    print!("{:<40}", "whole step");
    for r in &runs {
        print!("{:>14}", format!("{:.1}", r.total()));
    }
    println!();
    if let (Some(one), Some(last)) = (runs.iter().find(|r| r.threads == 1), runs.last())
        && last.threads > 1
    {
        println!(
            "{} threads run a step {:.2}x as fast as one.",
            last.threads,
            one.total() / last.total()
        );
    }
    Ok(())
}
