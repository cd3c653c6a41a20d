//! Converting a splat scene between file formats (PLY, GLB, SPZ) as a job: [`prepare`] checks
//! both names and reads the scene (or a run's checkpoint), writing nothing; [`PreparedExport::run`]
//! writes it, leaving nothing behind when it cannot.

use clap::Args;
use std::path::{Path, PathBuf};

use super::refused;
use crate::error::{Result, TrainError};

/// What `export` is asked to do (its flags).
#[derive(Args, Clone, Debug)]
pub struct ExportRequest {
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

/// The scene read and checked, to be written.
pub struct PreparedExport {
    request: ExportRequest,
    model: splat::Gaussians,
    /// Where the model came from, when that needs saying (a checkpoint's step).
    pub note: Option<String>,
}

/// What was written.
#[derive(Clone, Debug)]
pub struct ExportReport {
    pub splats: usize,
    pub sh_degree: u32,
    pub bytes: u64,
    pub out: PathBuf,
}

/// Both names checked (formats, no input overwritten) and the scene read, its SH bands cut
/// to `--sh-degree`.
pub fn prepare(a: &ExportRequest) -> Result<PreparedExport> {
    let format = |flag: &str, p: &Path| {
        splat::formats::files::Format::of(p).map_err(|e| TrainError::from(e).context(flag))
    };
    format("--out", &a.out)?;
    let is_checkpoint = a
        .input
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("bin"));
    if !is_checkpoint {
        format("--in", &a.input)?;
    }
    crate::output::guard::refuse_overwrite("--out", &a.out, &[("--in", &a.input)])?;
    let (mut model, note) = if is_checkpoint {
        let state = crate::train::checkpoint::load(&a.input)?;
        let note = format!(
            "Reading the model of the checkpoint at step {} of {} (before the end-of-run pruning).",
            state.progress.step, state.config.iters
        );
        (state.model, Some(note))
    } else {
        (splat::formats::files::read_splats(&a.input)?, None)
    };
    if model.is_empty() {
        return refused(format!("{}: the scene has no splats", a.input.display()));
    }
    if let Some(d) = a.sh_degree {
        if d > model.sh_degree {
            return refused(format!(
                "--sh-degree {d}: {} has SH degree {} only",
                a.input.display(),
                model.sh_degree
            ));
        }
        model.set_sh_degree(d);
    }
    Ok(PreparedExport {
        request: a.clone(),
        model,
        note,
    })
}

impl PreparedExport {
    /// Writes the scene; a folder made for the file goes again when the file cannot be written
    /// (a position SPZ cannot hold, a full disk): a refused export leaves nothing behind.
    pub fn run(self) -> Result<ExportReport> {
        let a = &self.request;
        let made = a
            .out
            .parent()
            .filter(|d| !d.as_os_str().is_empty() && !d.exists())
            .map(Path::to_path_buf);
        if let Some(dir) = &made {
            std::fs::create_dir_all(dir).map_err(|e| TrainError::io(dir, e))?;
        }
        if let Err(e) = splat::formats::files::write_splats(&a.out, &self.model) {
            if let Some(dir) = &made {
                let _ = std::fs::remove_dir(dir);
            }
            return Err(TrainError::from(e).context(format!(
                "--out {}: cannot convert {}",
                a.out.display(),
                a.input.display()
            )));
        }
        Ok(ExportReport {
            splats: self.model.len(),
            sh_degree: self.model.sh_degree,
            bytes: std::fs::metadata(&a.out).map_or(0, |m| m.len()),
            out: a.out.clone(),
        })
    }
}
