//! `metasplat restorer train|eval|average` and `metasplat restore`: the aberration-correcting
//! transformer.

mod apply;
mod average;
mod eval;
mod train;

use anyhow::Result;
use clap::Subcommand;

pub use apply::{RestoreArgs, run_restore};

#[derive(Subcommand)]
pub enum RestorerCommand {
    /// Train the MAFG + STAF restorer on clean photos aberrated on the fly.
    Train(train::TrainRestorerArgs),
    /// Validation table: best single-K Wiener, median MAFG image, the network.
    Eval(eval::EvalArgs),
    /// Score a restored clip (a folder of frames) against its clean one: per-frame PSNR and
    /// SSIM, and its flicker (how much more consecutive frames differ than the clean ones do).
    EvalVideo(eval::EvalVideoArgs),
    /// Average fine-tuned networks parameter by parameter (a "model soup"): one network's
    /// cost, at times better than each member.
    Average(average::AverageArgs),
}

pub fn run(c: RestorerCommand) -> Result<()> {
    match c {
        RestorerCommand::Train(a) => train::run_train(a),
        RestorerCommand::Eval(a) => eval::run_eval(a),
        RestorerCommand::EvalVideo(a) => eval::run_eval_video(a),
        RestorerCommand::Average(a) => average::run_average(a),
    }
}
