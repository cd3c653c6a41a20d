//! `metasplat export`: a splat scene from one file format to another (PLY, GLB, SPZ).

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use clap::Args;

#[derive(Args)]
pub struct ExportArgs {
    /// The scene to convert (.ply, .glb, .gltf or .spz), or a run's `checkpoint.bin` (the
    /// model as training left it at that step).
    #[arg(long = "in", visible_aliases = ["ply", "scene-file"])]
    pub input: PathBuf,
    /// The file to write; its extension (.ply, .glb, .gltf or .spz) picks the format.
    #[arg(long)]
    pub out: PathBuf,
    /// Keep SH bands up to this degree (default: all the input has).
    #[arg(long, value_parser = clap::value_parser!(u32).range(0..=3))]
    pub sh_degree: Option<u32>,
}

pub fn run(a: ExportArgs) -> Result<()> {
    splat::formats::files::Format::of(&a.out).context("--out")?;
    let is_checkpoint = a
        .input
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("bin"));
    if !is_checkpoint {
        splat::formats::files::Format::of(&a.input).context("--in")?;
    }
    metasplat::output::guard::refuse_overwrite("--out", &a.out, &[("--in", &a.input)])?;
    let mut g = if is_checkpoint {
        let state = metasplat::train::checkpoint::load(&a.input)?;
        println!(
            "Reading the model of the checkpoint at step {} of {} (before the end-of-run pruning).",
            state.progress.step, state.config.iters
        );
        state.model
    } else {
        splat::formats::files::read_splats(&a.input)?
    };
    if g.is_empty() {
        bail!("{}: the scene has no splats", a.input.display());
    }
    if let Some(d) = a.sh_degree {
        if d > g.sh_degree {
            bail!(
                "--sh-degree {d}: {} has SH degree {} only",
                a.input.display(),
                g.sh_degree
            );
        }
        g.set_sh_degree(d);
    }
    // A folder made for the file goes again when the file cannot be written (a position SPZ
    // cannot hold, a full disk): a refused export leaves nothing behind.
    let made = a
        .out
        .parent()
        .filter(|d| !d.as_os_str().is_empty() && !d.exists())
        .map(Path::to_path_buf);
    if let Some(dir) = &made {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    }
    if let Err(e) = splat::formats::files::write_splats(&a.out, &g) {
        if let Some(dir) = &made {
            let _ = std::fs::remove_dir(dir);
        }
        return Err(e).with_context(|| {
            format!(
                "--out {}: cannot convert {}",
                a.out.display(),
                a.input.display()
            )
        });
    }
    let size = std::fs::metadata(&a.out).map(|m| m.len()).unwrap_or(0);
    println!(
        "Wrote {} splats (SH degree {}) to {}: {} bytes, {:.1} per splat.",
        g.len(),
        g.sh_degree,
        a.out.display(),
        size,
        size as f64 / g.len().max(1) as f64
    );
    Ok(())
}
