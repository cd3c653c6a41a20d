//! `metasplat restorer average`: the parameter-wise mean of fine-tuned networks
//! ([`restore::average`]).

use anyhow::{Context, Result};
use clap::Args;
use restore::Device;
use std::path::PathBuf;

#[derive(Args)]
pub struct AverageArgs {
    /// Weights files to average (two or more): runs of one configuration from one starting
    /// point, on the same PSF-scale range (e.g. two seeds of a fine-tune).
    #[arg(required = true, num_args = 2..)]
    pub weights: Vec<PathBuf>,
    /// Where to write the mean (a new file; the first member's coverage, every member in its
    /// provenance).
    #[arg(long)]
    pub out: PathBuf,
}

pub(crate) fn run_average(a: AverageArgs) -> Result<()> {
    let inputs: Vec<(&str, &std::path::Path)> =
        a.weights.iter().map(|p| ("WEIGHTS", p.as_path())).collect();
    metasplat::output::guard::refuse_overwrite("--out", &a.out, &inputs)?;
    metasplat::output::guard::refuse_unwritable_file("--out", &a.out)?;
    let (net, header) = restore::average::average(&a.weights, &Device::flex())?;
    restore::weights::save(&net, &header, &a.out)
        .with_context(|| format!("--out {}", a.out.display()))?;
    println!(
        "{}: the mean of {} networks of config '{}'",
        a.out.display(),
        a.weights.len(),
        header.config.name
    );
    Ok(())
}
