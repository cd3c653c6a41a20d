//! `metasplat experiment`: the jobs of [`metasplat::lab`], each run shown as `train` shows it,
//! the reports printed.

use super::train::train_run;
use anyhow::Result;
use clap::Subcommand;
use metasplat::lab::{budget, llff, psf_mismatch};

#[derive(Subcommand)]
pub enum ExperimentCommand {
    /// Plain vs restored vs aware on an LLFF capture (e.g. ../shared/data/llff/fern).
    Llff(llff::LlffArgs),
    /// Held-out PSNR and training time against the splat budget: how many splats a scene
    /// needs.
    Budget(budget::BudgetArgs),
    /// Aware training with a mis-calibrated PSF grid, one error at a time (focal length, the
    /// calibration lasers' wavelengths, defocus, rotation, measurement noise, a pedestal),
    /// with and without --refine-psf.
    PsfMismatch(psf_mismatch::PsfMismatchArgs),
}

/// Trains one run of an experiment as `train` would, its progress shown.
fn shown(
    request: &metasplat::settings::RunRequest,
) -> metasplat::Result<(metasplat::output::RunSummary, Vec<metasplat::train::LogRow>)> {
    train_run(request, false)
}

pub fn run(cmd: ExperimentCommand) -> Result<()> {
    let say = &mut |s: String| println!("{s}");
    let (table, path, also) = match cmd {
        ExperimentCommand::Llff(a) => {
            let r = llff::run(&a, &mut shown, say)?;
            (r.table, r.table_path, r.restorer.map(|r| format!("({r})")))
        }
        ExperimentCommand::Budget(a) => {
            let r = budget::run(&a, &mut shown, say)?;
            (r.table, r.table_path, None)
        }
        ExperimentCommand::PsfMismatch(a) => {
            let r = psf_mismatch::run(&a, say)?;
            (r.table, r.table_path, None)
        }
    };
    println!("\n{table}");
    if let Some(line) = also {
        println!("{line}");
    }
    println!("wrote {} and the plots beside it", path.display());
    Ok(())
}
