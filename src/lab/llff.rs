//! `experiment llff`: the paper's comparison on a real capture. Makes the aberrated capture,
//! trains plain, restored and aware with identical settings (and the clean-photo ceiling),
//! and writes one table (PSNR/SSIM against the clean images, minutes, splats) with test PSNR
//! reached against training time: the speed-against-error report of the main job.

use std::fmt::Write as _;

use clap::Args;

use super::runs::{ExperimentRuns, refuse_repeats};
use super::{Runner, arrival};
use crate::error::{Result, TrainError};
use crate::output::plot::{Series, line_plot};
use crate::train::config::Mode;

#[derive(Args)]
pub struct LlffArgs {
    #[command(flatten)]
    pub runs: ExperimentRuns,
    /// Weight of L(render, I_ac) in aware mode (default: as `train`).
    #[arg(long, value_parser = crate::settings::values::weight, allow_negative_numbers = true)]
    pub lambda: Option<f32>,
    /// Modes to run, in order.
    #[arg(long, value_enum, value_delimiter = ',', default_values_t = Mode::ALL.to_vec())]
    pub modes: Vec<Mode>,
}

/// What [`run`] wrote: the table (also in `table.md`) beside `psnr_vs_time.png`, and the
/// restorer the runs used.
#[derive(Clone, Debug)]
pub struct LlffReport {
    pub table: String,
    pub table_path: std::path::PathBuf,
    pub restorer: Option<String>,
}

/// Trains the ceiling and every mode `a` asks for through `train` (the binary shows their
/// progress), writes the table and the plot; `say` hears each stage.
pub fn run(a: &LlffArgs, train: &mut Runner, say: &mut dyn FnMut(String)) -> Result<LlffReport> {
    refuse_repeats("--modes", &a.modes)?;
    let ceiling_run = || {
        let mut args = a.runs.ceiling_run(a.runs.place.out.join("run_clean"));
        args.training.eval_every = Some((a.runs.iters / 20).max(1));
        args
    };
    if a.runs.ceiling {
        a.runs.check_ceiling(&ceiling_run())?;
    }
    let (aberrated, _lock) = a.runs.aberrated(say)?;
    let ceiling = if a.runs.ceiling {
        let args = ceiling_run();
        say("Training plain on the clean photos (the ceiling).".into());
        Some(train(&args)?)
    } else {
        None
    };
    let mut rows = Vec::new();
    for &mode in &a.modes {
        let run_dir = a.runs.place.out.join(format!("run_{mode}"));
        let mut args = a.runs.run(&aberrated, run_dir, mode);
        if mode == Mode::Aware {
            args.training.lambda = a.lambda;
        }
        args.training.eval_every = Some((a.runs.iters / 20).max(1));
        let (summary, log) = train(&args)?;
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
    let _ = writeln!(
        table,
        "| method | PSNR (dB) | vs ceiling | SSIM | minutes | splats | SH |{mask_head}"
    );
    let _ = writeln!(table, "|---|---:|---:|---:|---:|---:|---:|{mask_rule}");
    let _ = writeln!(
        table,
        "| aberrated input | {observed:.2} | {} | | | | |{}",
        below(observed),
        in_mask(rows.iter().find_map(|r| r.1.observed_psnr_in_mask))
    );
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
        let (p, ss) = s.psnr_ssim();
        let _ = writeln!(
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
        );
    }
    if let Some(o) = &on_object {
        let [r, g, b] = o.background;
        let _ = writeln!(
            table,
            "\nScored on the object (mask mode {}): renders and references over {r:.3},{g:.3},{b:.3} outside the held-out views' masks (the aberrated input composited as a render that learnt nothing there), and PSNR inside the masks alone.",
            o.masks
        );
    }
    let _ = writeln!(
        table,
        "\nheld-out PSNR (dB) reached vs training time and splat count:"
    );
    for (mode, _, log) in &rows {
        let points: Vec<String> = log
            .iter()
            .filter_map(|r| {
                r.test_psnr
                    .map(|p| format!("{:.0}s/{}k: {p:.2}", r.seconds, r.splats / 1000))
            })
            .collect();
        let _ = writeln!(table, "- {mode}: {}", points.join(", "));
    }
    let _ = writeln!(
        table,
        "\nspeed against error: where each run first came within 0.5 and 0.1 dB of its final held-out PSNR (training time, share of it):"
    );
    for (mode, s, log) in &rows {
        match arrival(log) {
            Some((phrases, total)) => {
                let _ = writeln!(
                    table,
                    "- {mode}: {}; {} steps in {:.1} min{}",
                    phrases.join(", "),
                    s.iters,
                    total / 60.0,
                    s.stopped
                        .as_ref()
                        .map_or(String::new(), |w| format!(" ({w})"))
                );
            }
            None => {
                let _ = writeln!(table, "- {mode}: not evaluated");
            }
        }
    }
    let table_path = a.runs.place.out.join("table.md");
    base::write_bytes_atomically(&table_path, table.as_bytes())
        .map_err(|e| TrainError::io(&table_path, e))?;
    let curve = |log: &[crate::train::LogRow]| {
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
        &a.runs.place.out.join("psnr_vs_time.png"),
        "held-out PSNR vs training time",
        "training time (s)",
        "PSNR vs clean (dB)",
        &series,
    )?;
    Ok(LlffReport {
        table,
        table_path,
        restorer: rows.iter().find_map(|(_, s, _)| s.restorer.clone()),
    })
}
