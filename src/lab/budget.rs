//! `experiment budget`: held-out PSNR against the splats kept, one run per budget on the
//! same aberrated copy (and, beside each, the clean-photo ceiling at that budget).

use std::fmt::Write as _;

use clap::Args;

use super::runs::{ExperimentRuns, refuse_repeats};
use super::{NEAR_FINAL_DB, Runner, near_final};
use crate::error::{Result, TrainError};
use crate::output::plot::{Series, line_plot};
use crate::train::config::Mode;

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

/// What [`run`] wrote: the table (also in `budget.md`) beside `budget.png`.
#[derive(Clone, Debug)]
pub struct BudgetReport {
    pub table: String,
    pub table_path: std::path::PathBuf,
}

/// Trains every budget `a` asks for through `train` (the binary shows its progress), writes
/// the table and the plot; `say` hears each stage.
pub fn run(
    a: &BudgetArgs,
    train: &mut Runner,
    say: &mut dyn FnMut(String),
) -> Result<BudgetReport> {
    refuse_repeats("--budgets", &a.budgets)?;
    if a.runs.ceiling
        && let Some(b) = a.budgets.first()
    {
        let mut clean = a
            .runs
            .ceiling_run(a.runs.place.out.join(format!("budget_{b}_clean")));
        clean.training.max_splats = Some(b.0.unwrap_or(UNBOUNDED));
        a.runs.check_ceiling(&clean)?;
    }
    let (aberrated, _lock) = a.runs.aberrated(say)?;
    let mut rows = Vec::new();
    for &b in &a.budgets {
        let run_dir = a.runs.place.out.join(format!("budget_{b}"));
        let mut args = a.runs.run(&aberrated, run_dir.clone(), a.mode);
        args.training.max_splats = Some(b.0.unwrap_or(UNBOUNDED));
        args.training.eval_every = Some((a.runs.iters / 10).max(1));
        say(format!("Training {} with a budget of {b} splats.", a.mode));
        let (summary, log) = train(&args)?;
        let ply_bytes =
            std::fs::metadata(run_dir.join(crate::output::PLY_FILE)).map_or(0, |m| m.len());
        let ceiling = if a.runs.ceiling {
            let mut clean = a
                .runs
                .ceiling_run(a.runs.place.out.join(format!("budget_{b}_clean")));
            clean.training.max_splats = args.training.max_splats;
            clean.training.eval_every = args.training.eval_every;
            say(format!(
                "Training plain on the clean photos with a budget of {b} splats (the ceiling)."
            ));
            train(&clean)?.0.metrics.map(|m| m.mean_psnr)
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
    let _ = writeln!(
        table,
        "| budget | splats | PSNR (dB) | vs largest | SSIM | splats vs largest | minutes | within 0.5 / 0.1 dB (min) | PLY MB | B/splat | SH | clean-photo ceiling (dB) |"
    );
    let _ = writeln!(
        table,
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"
    );
    for (b, s, log, bytes, ceiling) in &rows {
        let at = |db| {
            near_final(log, db).map_or("-".to_string(), |(_, t, _)| format!("{:.1}", t / 60.0))
        };
        let (p, ss) = s.psnr_ssim();
        let _ = writeln!(
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
        );
    }
    let table_path = a.runs.place.out.join("budget.md");
    base::write_bytes_atomically(&table_path, table.as_bytes())
        .map_err(|e| TrainError::io(&table_path, e))?;
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
        &a.runs.place.out.join("budget.png"),
        "held-out PSNR against the splats kept",
        "splats at the end of training",
        "PSNR vs clean (dB)",
        &series,
    )?;
    Ok(BudgetReport { table, table_path })
}
