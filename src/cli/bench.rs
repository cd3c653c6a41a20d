//! `metasplat bench step`: the time of each phase of the training loop's own step on a
//! capture, at one or more thread counts, on the device training would use.
//! `metasplat bench restorer`: the restorer's forward passes and training steps with its fast
//! kernels and with the reference ones, alternated in one run.

use anyhow::Result;
use clap::Subcommand;
use metasplat::jobs::bench_restorer::{self, RestorerBenchRow};
use metasplat::jobs::bench_step::{self, StepTimes};

pub use metasplat::jobs::bench_restorer::RestorerBenchRequest as RestorerBenchArgs;
pub use metasplat::jobs::bench_step::StepBenchRequest as StepArgs;

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

pub fn run(cmd: BenchCommand) -> Result<()> {
    match cmd {
        BenchCommand::Step(a) => step(a),
        BenchCommand::Restorer(a) => restorer(a),
    }
}

fn restorer(a: RestorerBenchArgs) -> Result<()> {
    let prepared = bench_restorer::prepare(&a)?;
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
    prepared.run(&mut print_restorer_row)?;
    Ok(())
}

/// One row of `bench restorer`'s table; with --fast-only the reference columns say `-`.
fn print_restorer_row(r: &RestorerBenchRow) {
    let (reference, speed_up) = match r.reference_s {
        Some(s) => (format!("{s:.3}"), format!("{:.2}x", s / r.fast_s)),
        None => ("-".to_string(), "-".to_string()),
    };
    println!(
        "{:<6} {:<20} {:>7} {:>12} {:>12.3} {:>8} {:>12.3} {:>10.2} {:>10.2}",
        r.config,
        r.workload.describe(),
        r.threads,
        reference,
        r.fast_s,
        speed_up,
        r.fast_cpu_s,
        r.s_per_mp(),
        r.gflops
    );
}

fn step(a: StepArgs) -> Result<()> {
    let prepared = bench_step::prepare(&a)?;
    println!("{}", prepared.note);
    let report = prepared.run()?;
    print_step_table(&report.runs);
    if !report.refinement.is_empty() {
        println!(
            "\nThe same steps with the PSF grid refined on every step, beside the plain aware ones (medians of alternated rounds):"
        );
    }
    for r in &report.refinement {
        let (p, gr, up) = (r.aware_ms, r.gradient_ms, r.update_ms);
        println!(
            "{} thread{}: aware {p:.1} ms, with the PSF refined {:.1} ms (+{:.0} %); the PSF gradient takes {gr:.1} ms and the update {up:.1} ms, so updating every {} steps (the default) adds {:.0} %.",
            r.threads,
            if r.threads == 1 { "" } else { "s" },
            r.refined_ms,
            100.0 * (r.refined_ms - p) / p,
            r.every,
            100.0 * (gr + up) / r.every.max(1) as f64 / p
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
