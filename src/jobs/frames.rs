//! A folder of frames in, a folder of frames out (`restore --in DIR`, `aberrate --in DIR`):
//! the frames of one clip, of one size, each written under its own name as PNG. Every check
//! is made before any work: no input overwritten, no frame there unless the caller continues.

use std::path::{Path, PathBuf};

use super::refused;
use crate::error::{Result, TrainError};

pub struct FrameFolders {
    /// The input frames, in name order.
    pub frames: Vec<PathBuf>,
    /// Their common size.
    pub size: (u32, u32),
    out: PathBuf,
}

impl FrameFolders {
    /// The frames of `input` going to `out`. A frame already in `out` is refused with
    /// `existing` (what to do about it) unless that is None (the caller continues there);
    /// `inputs` are the other files the command reads.
    pub fn check(
        input: &Path,
        out: &Path,
        existing: Option<&str>,
        inputs: &[(&str, &Path)],
    ) -> Result<Self> {
        let frames = scenes::images::list_images(input)
            .map_err(|e| TrainError::from(e).context(format!("--in {}", input.display())))?;
        if out.is_file() {
            return refused(format!(
                "--out {}: is a file; a folder of frames goes into a folder",
                out.display()
            ));
        }
        let size = scenes::images::common_size(&frames).map_err(|e| {
            TrainError::from(e).context("--in: the frames of a clip are of one size")
        })?;
        let folders = Self {
            frames,
            size,
            out: out.to_path_buf(),
        };
        for f in &folders.frames {
            let t = folders.target(f);
            if let (true, Some(what)) = (t.exists(), existing) {
                return refused(format!(
                    "--out {}: {} exists; {what}",
                    out.display(),
                    t.display()
                ));
            }
            let mut reads = inputs.to_vec();
            reads.push(("--in", f));
            crate::output::guard::refuse_overwrite("--out", &t, &reads)?;
        }
        Ok(folders)
    }

    /// Where frame `f` goes.
    pub fn target(&self, f: &Path) -> PathBuf {
        self.out
            .join(Path::new(f.file_stem().unwrap_or_default()).with_extension("png"))
    }

    /// Makes the output folder.
    pub fn make_out(&self) -> Result<()> {
        std::fs::create_dir_all(&self.out).map_err(|e| TrainError::io(&self.out, e))
    }
}

/// Seconds left after `done` of `total` frames took `spent` seconds, at the same pace.
pub fn time_left(spent: f64, done: usize, total: usize) -> f64 {
    spent / done.max(1) as f64 * total.saturating_sub(done) as f64
}
