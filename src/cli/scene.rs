//! `metasplat scene info`.

use anyhow::{Context, Result};
use clap::{Args, Subcommand};
use std::path::PathBuf;

#[derive(Subcommand)]
pub enum SceneCommand {
    /// Print cameras, resolution, split, bounds and points of a capture.
    Info(InfoArgs),
}

#[derive(Args)]
pub struct InfoArgs {
    /// Capture directory (LLFF or COLMAP).
    pub dir: PathBuf,
    /// Use images_N.
    #[arg(long, default_value_t = 8)]
    pub downsample: u32,
    /// Every N-th image is held out for testing.
    #[arg(long, default_value_t = 8)]
    pub llffhold: usize,
}

pub fn run(cmd: SceneCommand) -> Result<()> {
    match cmd {
        SceneCommand::Info(a) => {
            let opts = scenes::OpenOptions {
                resolution: scenes::Resolution::Downsample(a.downsample),
                llffhold: a.llffhold,
                ..Default::default()
            };
            let capture = scenes::open(&a.dir, &opts)
                .with_context(|| format!("cannot open the scene {}", a.dir.display()))?;
            println!("{}", capture.summary());
            Ok(())
        }
    }
}
