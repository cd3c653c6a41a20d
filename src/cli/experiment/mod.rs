//! `metasplat experiment llff`: the paper's comparison on a real capture. Makes the
//! aberrated capture, trains plain, restored and aware with identical settings, and prints
//! one table (PSNR/SSIM against the clean images, minutes, splats) plus test PSNR reached
//! against training time: the speed-against-error report of the main job.

use super::train::train_run;
use anyhow::{Context, Result};
use clap::{Args, Subcommand};
use metasplat::lab::psf_mismatch;
use metasplat::lab::runs::{ExperimentRuns, refuse_repeats};
use metasplat::output::plot::{Series, line_plot};
use metasplat::train::config::Mode;
use std::fmt::Write as _;

#[derive(Subcommand)]
pub enum ExperimentCommand {
    /// Plain vs restored vs aware on an LLFF capture (e.g. ../shared/data/llff/fern).
    Llff(LlffArgs),
    /// Held-out PSNR and training time against the splat budget: how many splats a scene
    /// needs.
    Budget(BudgetArgs),
    /// Aware training with a mis-calibrated PSF grid, one error at a time (focal length, the
    /// calibration lasers' wavelengths, defocus, rotation, measurement noise, a pedestal),
    /// with and without --refine-psf.
    PsfMismatch(psf_mismatch::PsfMismatchArgs),
}

/// A splat budget: a count, or `unbounded` (3DGS densification without a cap).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Budget(pub Option<u64>);

impl std::str::FromStr for Budget {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        if s == "unbounded" {
            return Ok(Budget(None));
        }
        match s.parse::<u64>() {
            Ok(n) if (1..=UNBOUNDED).contains(&n) => Ok(Budget(Some(n))),
            _ => Err(format!(
                "'{s}' is not a splat budget (a count from 1 to {UNBOUNDED}, or 'unbounded')"
            )),
        }
    }
}

impl std::fmt::Display for Budget {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self.0 {
            Some(n) => write!(f, "{n}"),
            None => write!(f, "unbounded"),
        }
    }
}

/// The cap an `unbounded` run gets: more than densification reaches on any capture we train.
const UNBOUNDED: u64 = 100_000_000;

#[derive(Args)]
pub struct BudgetArgs {
    #[command(flatten)]
    pub runs: ExperimentRuns,
    /// Budgets to train with, in order (`unbounded`: no cap).
    #[arg(long, value_delimiter = ',', default_values_t = [Budget(Some(10_000)), Budget(Some(20_000)), Budget(Some(40_000)), Budget(Some(95_000)), Budget(None)])]
    pub budgets: Vec<Budget>,
    /// The mode every budget trains.
    #[arg(long, value_enum, default_value_t = Mode::Aware)]
    pub mode: Mode,
}

#[derive(Args)]
pub struct LlffArgs {
    #[command(flatten)]
    pub runs: ExperimentRuns,
    /// Weight of L(render, I_ac) in aware mode (default: as `train`).
    #[arg(long, value_parser = metasplat::settings::values::weight, allow_negative_numbers = true)]
    pub lambda: Option<f32>,
    /// Modes to run, in order.
    #[arg(long, value_enum, value_delimiter = ',', default_values_t = Mode::ALL.to_vec())]
    pub modes: Vec<Mode>,
}

pub fn run(cmd: ExperimentCommand) -> Result<()> {
    match cmd {
        ExperimentCommand::Llff(a) => llff(a),
        ExperimentCommand::Budget(a) => budget(a),
        ExperimentCommand::PsfMismatch(a) => {
            let report = psf_mismatch::run(&a, &mut |s| println!("{s}"))?;
            println!("\n{}", report.table);
            println!(
                "wrote {} and the plots beside it",
                report.table_path.display()
            );
            Ok(())
        }
    }
}

fn budget(a: BudgetArgs) -> Result<()> {
    refuse_repeats("--budgets", &a.budgets)?;
    if a.runs.ceiling
        && let Some(b) = a.budgets.first()
    {
        let mut clean = a
            .runs
            .ceiling_run(a.runs.out.join(format!("budget_{b}_clean")));
        clean.training.max_splats = Some(b.0.unwrap_or(UNBOUNDED));
        a.runs.check_ceiling(&clean)?;
    }
    let (aberrated, _lock) = a.runs.aberrated(&mut |s| println!("{s}"))?;
    let mut rows = Vec::new();
    for &b in &a.budgets {
        let run_dir = a.runs.out.join(format!("budget_{b}"));
        let mut args = a.runs.run(&aberrated, run_dir.clone(), a.mode);
        args.training.max_splats = Some(b.0.unwrap_or(UNBOUNDED));
        args.training.eval_every = Some((a.runs.iters / 10).max(1));
        println!("Training {} with a budget of {b} splats.", a.mode);
        let (summary, log) = train_run(&args, false)?;
        let ply_bytes =
            std::fs::metadata(run_dir.join(metasplat::output::PLY_FILE)).map_or(0, |m| m.len());
        let ceiling = if a.runs.ceiling {
            let mut clean = a
                .runs
                .ceiling_run(a.runs.out.join(format!("budget_{b}_clean")));
            clean.training.max_splats = args.training.max_splats;
            clean.training.eval_every = args.training.eval_every;
            println!(
                "Training plain on the clean photos with a budget of {b} splats (the ceiling)."
            );
            train_run(&clean, false)?.0.metrics.map(|m| m.mean_psnr)
        } else {
            None
        };
        rows.push((b, summary, log, ply_bytes, ceiling));
    }
    // The reference is the largest budget run (unbounded when it is among them).
    let reference = rows
        .iter()
        .max_by_key(|r| r.0.0.unwrap_or(u64::MAX))
        .map(|r| {
            (
                r.1.metrics.as_ref().map_or(f64::NAN, |m| m.mean_psnr),
                r.1.splats,
            )
        })
        .unwrap_or((f64::NAN, 0));
    let mut table = String::new();
    writeln!(
        table,
        "| budget | splats | PSNR (dB) | vs largest | SSIM | splats vs largest | minutes | within 0.5 / 0.1 dB (min) | PLY MB | B/splat | SH | clean-photo ceiling (dB) |"
    )?;
    writeln!(
        table,
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"
    )?;
    for (b, s, log, bytes, ceiling) in &rows {
        let at = |db| {
            near_final(log, db).map_or("-".to_string(), |(_, t, _)| format!("{:.1}", t / 60.0))
        };
        let (p, ss) = s
            .metrics
            .as_ref()
            .map_or((f64::NAN, f64::NAN), |m| (m.mean_psnr, m.mean_ssim));
        writeln!(
            table,
            "| {b} | {} | {p:.2} | {:+.2} | {ss:.4} | {:.0} % | {:.1} | {} / {} | {:.1} | {} | {} | {} |",
            s.splats,
            p - reference.0,
            100.0 * s.splats as f64 / reference.1.max(1) as f64,
            s.train_seconds / 60.0,
            at(NEAR_FINAL_DB[0]),
            at(NEAR_FINAL_DB[1]),
            *bytes as f64 / 1e6,
            bytes / s.splats.max(1) as u64,
            s.sh_degree,
            ceiling.map_or("not run".to_string(), |c| format!("{c:.2}"))
        )?;
    }
    println!("\n{table}");
    let table_path = a.runs.out.join("budget.md");
    base::write_bytes_atomically(&table_path, table.as_bytes())
        .with_context(|| format!("cannot write {}", table_path.display()))?;
    let series = vec![Series {
        name: format!("{} (held-out PSNR)", a.mode),
        points: rows
            .iter()
            .filter_map(|(_, s, _, _, _)| {
                s.metrics.as_ref().map(|m| (s.splats as f64, m.mean_psnr))
            })
            .collect(),
    }];
    line_plot(
        &a.runs.out.join("budget.png"),
        "held-out PSNR against the splats kept",
        "splats at the end of training",
        "PSNR vs clean (dB)",
        &series,
    )?;
    println!("Wrote {}/budget.md and budget.png.", a.runs.out.display());
    Ok(())
}

/// How close to its final held-out PSNR a run counts as having arrived, coarse and fine.
const NEAR_FINAL_DB: [f64; 2] = [0.5, 0.1];

/// The first evaluation of a run whose held-out PSNR is within `db` of the last one, and when
/// it came: `(step, seconds, total seconds)`.
fn near_final(log: &[metasplat::train::LogRow], db: f64) -> Option<(u64, f64, f64)> {
    let evals: Vec<_> = log.iter().filter(|r| r.test_psnr.is_some()).collect();
    let last = evals.last()?;
    let final_psnr = last.test_psnr?;
    let first = evals
        .iter()
        .find(|r| r.test_psnr.is_some_and(|p| p >= final_psnr - db))?;
    Some((first.step, first.seconds, last.seconds))
}

/// Where a run came within each of [`NEAR_FINAL_DB`] of its final held-out PSNR, as
/// "step S (M min, P %)" phrases, and its whole training time.
fn arrival(log: &[metasplat::train::LogRow]) -> Option<(Vec<String>, f64)> {
    let mut total = 0.0;
    let phrases = NEAR_FINAL_DB
        .iter()
        .map(|&db| {
            near_final(log, db).map(|(step, seconds, all)| {
                total = all;
                format!(
                    "within {db} dB at step {step} ({:.1} min, {:.0} %)",
                    seconds / 60.0,
                    100.0 * seconds / all.max(1e-9)
                )
            })
        })
        .collect::<Option<Vec<_>>>()?;
    Some((phrases, total))
}

fn llff(a: LlffArgs) -> Result<()> {
    refuse_repeats("--modes", &a.modes)?;
    let ceiling_run = || {
        let mut args = a.runs.ceiling_run(a.runs.out.join("run_clean"));
        args.training.eval_every = Some((a.runs.iters / 20).max(1));
        args
    };
    if a.runs.ceiling {
        a.runs.check_ceiling(&ceiling_run())?;
    }
    let (aberrated, _lock) = a.runs.aberrated(&mut |s| println!("{s}"))?;
    let ceiling = if a.runs.ceiling {
        let args = ceiling_run();
        println!("Training plain on the clean photos (the ceiling).");
        Some(train_run(&args, false)?)
    } else {
        None
    };
    let mut rows = Vec::new();
    for &mode in &a.modes {
        let run_dir = a.runs.out.join(format!("run_{mode}"));
        let mut args = a.runs.run(&aberrated, run_dir, mode);
        if mode == Mode::Aware {
            args.training.lambda = a.lambda;
        }
        args.training.eval_every = Some((a.runs.iters / 20).max(1));
        let (summary, log) = train_run(&args, false)?;
        rows.push((mode, summary, log));
    }

    let mut table = String::new();
    let observed = rows
        .iter()
        .find_map(|r| r.1.observed_psnr)
        .unwrap_or(f64::NAN);
    let ceiling_psnr = ceiling
        .as_ref()
        .and_then(|(s, _)| s.metrics.as_ref())
        .map(|m| m.mean_psnr);
    let below = |p: f64| ceiling_psnr.map_or(String::new(), |c| format!("{:+.2}", p - c));
    // A capture with object masks is scored on the object, every row alike.
    let on_object = rows
        .iter()
        .map(|r| &r.1)
        .chain(ceiling.iter().map(|c| &c.0))
        .find_map(|s| s.metrics.as_ref().and_then(|m| m.on_object.clone()));
    let (mask_head, mask_rule) = if on_object.is_some() {
        (" in the mask |", "---:|")
    } else {
        ("", "")
    };
    let in_mask = |p: Option<f64>| match (&on_object, p) {
        (None, _) => String::new(),
        (Some(_), Some(p)) => format!(" {p:.2} |"),
        (Some(_), None) => " |".into(),
    };
    writeln!(
        table,
        "| method | PSNR (dB) | vs ceiling | SSIM | minutes | splats | SH |{mask_head}"
    )?;
    writeln!(table, "|---|---:|---:|---:|---:|---:|---:|{mask_rule}")?;
    writeln!(
        table,
        "| aberrated input | {observed:.2} | {} | | | | |{}",
        below(observed),
        in_mask(rows.iter().find_map(|r| r.1.observed_psnr_in_mask))
    )?;
    let named = ceiling
        .iter()
        .map(|(s, _)| ("3D-GS on the clean photos (ceiling)", s))
        .chain(rows.iter().map(|(mode, s, _)| {
            let name = match mode {
                Mode::Plain => "3D-GS (plain)",
                Mode::Restored => "3D-GS w/ restored I_ac",
                Mode::Aware => "3D-GS + aberration-aware",
            };
            (name, s)
        }));
    for (name, s) in named {
        let (p, ss) = s
            .metrics
            .as_ref()
            .map_or((f64::NAN, f64::NAN), |m| (m.mean_psnr, m.mean_ssim));
        writeln!(
            table,
            "| {name} | {p:.2} | {} | {ss:.4} | {:.1} | {} | {} |{}",
            below(p),
            s.train_seconds / 60.0,
            s.splats,
            s.sh_degree,
            in_mask(
                s.metrics
                    .as_ref()
                    .and_then(|m| m.on_object.as_ref())
                    .map(|o| o.mean_psnr_in_mask)
            )
        )?;
    }
    if let Some(o) = &on_object {
        let [r, g, b] = o.background;
        writeln!(
            table,
            "\nScored on the object (mask mode {}): renders and references over {r:.3},{g:.3},{b:.3} outside the held-out views' masks (the aberrated input composited as a render that learnt nothing there), and PSNR inside the masks alone.",
            o.masks
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
    writeln!(
        table,
        "\nspeed against error: where each run first came within 0.5 and 0.1 dB of its final held-out PSNR (training time, share of it):"
    )?;
    for (mode, s, log) in &rows {
        match arrival(log) {
            Some((phrases, total)) => writeln!(
                table,
                "- {mode}: {}; {} steps in {:.1} min{}",
                phrases.join(", "),
                s.iters,
                total / 60.0,
                s.stopped
                    .as_ref()
                    .map_or(String::new(), |w| format!(" ({w})"))
            )?,
            None => writeln!(table, "- {mode}: not evaluated")?,
        }
    }
    println!("\n{table}");
    if let Some(r) = rows.iter().find_map(|(_, s, _)| s.restorer.clone()) {
        println!("({r})");
    }
    let table_path = a.runs.out.join("table.md");
    base::write_bytes_atomically(&table_path, table.as_bytes())
        .with_context(|| format!("cannot write {}", table_path.display()))?;
    let curve = |log: &[metasplat::train::LogRow]| {
        log.iter()
            .filter_map(|r| r.test_psnr.map(|p| (r.seconds, p)))
            .collect()
    };
    let series: Vec<Series> = ceiling
        .iter()
        .map(|(_, log)| Series {
            name: "clean photos (ceiling)".into(),
            points: curve(log),
        })
        .chain(rows.iter().map(|(mode, _, log)| Series {
            name: mode.to_string(),
            points: curve(log),
        }))
        .collect();
    line_plot(
        &a.runs.out.join("psnr_vs_time.png"),
        "held-out PSNR vs training time",
        "training time (s)",
        "PSNR vs clean (dB)",
        &series,
    )?;
    println!(
        "wrote {}/table.md and psnr_vs_time.png",
        a.runs.out.display()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use metasplat::train::LogRow;

    fn row(step: u64, seconds: f64, psnr: Option<f64>) -> LogRow {
        LogRow {
            step,
            seconds,
            loss: 0.0,
            train_psnr: 0.0,
            test_psnr: psnr,
            test_ssim: None,
            splats: 0,
            sh_degree: 0,
        }
    }

    #[test]
    fn near_final_finds_the_first_evaluation_within_half_a_decibel() {
        let log = [
            row(100, 10.0, Some(20.0)),
            row(150, 15.0, None),
            row(200, 20.0, Some(25.4)),
            row(300, 30.0, Some(25.6)),
            row(400, 40.0, Some(25.2)),
            row(500, 50.0, Some(26.0)),
        ];
        // 25.6 is the first at or above 26.0 - 0.5; 25.4 is not. Within 0.1: only the last.
        assert_eq!(near_final(&log, 0.5), Some((300, 30.0, 50.0)));
        assert_eq!(near_final(&log, 0.1), Some((500, 50.0, 50.0)));
        assert_eq!(near_final(&[row(1, 1.0, None)], 0.5), None);
        assert_eq!(near_final(&[], 0.5), None);
        let (phrases, total) = arrival(&log).unwrap();
        assert_eq!(total, 50.0);
        assert_eq!(
            phrases,
            [
                "within 0.5 dB at step 300 (0.5 min, 60 %)",
                "within 0.1 dB at step 500 (0.8 min, 100 %)"
            ]
        );
    }
}
