//! What the restorer commands share: the network options (weights, tiling), loaded with the
//! sentence that says which network serves and why.

use aberration::PsfGrid;
use clap::Args;
use restore::Restorer;
use std::path::{Path, PathBuf};

use super::refused;
use crate::error::{Result, TrainError};

/// How the network runs over an image: the tiles large images are cut into, and how many
/// mirrored and turned passes are averaged.
#[derive(Args, Clone, Debug)]
pub struct Tiling {
    /// Tile side in px (a multiple of the config's padding unit); default: the largest that
    /// fits the memory budget (512 for `tiny`).
    #[arg(long)]
    pub tile: Option<usize>,
    /// Overlap of neighbouring tiles in px, blended by linear ramps.
    #[arg(long)]
    pub overlap: Option<usize>,
    /// Self-ensemble: average the network's answers on the photo mirrored and turned, 1, 2,
    /// 4 or 8 of them (each one more network pass; restore/README gives the gain per scale).
    #[arg(long, default_value_t = 1, value_parser = ensemble_size)]
    pub ensemble: usize,
}

/// `--ensemble`'s value, refused by the parser (before any file is read) unless the
/// ensemble has that many members.
fn ensemble_size(s: &str) -> std::result::Result<usize, String> {
    match s.parse::<usize>() {
        Ok(n) if restore::ensemble::SIZES.contains(&n) => Ok(n),
        _ => Err("an ensemble has 1, 2, 4 or 8 members".into()),
    }
}

impl Tiling {
    pub fn apply(&self, r: Restorer) -> Result<Restorer> {
        let (tile, overlap) = (
            self.tile.unwrap_or(r.tile),
            self.overlap.unwrap_or(r.overlap),
        );
        let r = r.with_tiling(tile, overlap).map_err(|e| {
            TrainError::from(e).context(format!("--tile {tile} --overlap {overlap}"))
        })?;
        r.with_ensemble(self.ensemble)
            .map_err(|e| TrainError::from(e).context(format!("--ensemble {}", self.ensemble)))
    }
}

/// A trained restorer and the PSF grid it restores through, as `restorer eval` and `restore`
/// load them.
#[derive(Args, Clone, Debug)]
pub struct Inference {
    /// Restorer weights; without it, the network shipped in the binary
    /// (`restore/weights/tiny.bin`, else `large_tiny_9.bin` for 85-140 px PSFs, else the
    /// general `family_tiny_5.bin`), when one serves this PSF grid.
    #[arg(long)]
    pub weights: Option<PathBuf>,
    /// PSF grid (`.npy`, from `psf simulate`) the images were aberrated with.
    #[arg(long)]
    pub psf: PathBuf,
    /// `cpu`, or `vulkan` in a build with `--features vulkan`.
    #[arg(long, default_value = "cpu")]
    pub backend: restore::Compute,
    /// Restore through this grid even when the weights do not cover its lens (to measure them
    /// there); without it such weights are refused, saying what they cover.
    #[arg(long)]
    pub any_grid: bool,
    #[command(flatten)]
    pub tiling: Tiling,
}

impl Inference {
    /// The native PSF grid and the restorer loaded on the chosen backend with its tiling, and
    /// the sentence that says which shipped network serves and why (without --weights: the
    /// shipped one that serves the grid with PSFs `psf_px` wide at the images' size; None: at
    /// any size).
    pub fn load(
        &self,
        psf_px: impl FnOnce(&PsfGrid) -> Option<usize>,
    ) -> Result<(PsfGrid, Restorer, Option<String>)> {
        let native = PsfGrid::load_npy(&self.psf).map_err(|e| {
            TrainError::from(e).context(format!("cannot read {}", self.psf.display()))
        })?;
        let psf_px = psf_px(&native);
        let device = self
            .backend
            .device()
            .map_err(|e| TrainError::from(e).context("--backend"))?;
        let mut said = None;
        let net = match (&self.weights, self.any_grid) {
            (Some(w), false) => Restorer::load_on(w, &native, device).map_err(|e| {
                TrainError::from(e).context(format!("--weights with --psf {}", self.psf.display()))
            })?,
            (Some(w), true) => Restorer::load_any_grid_on(w, device)
                .map_err(|e| TrainError::from(e).context(format!("--weights {}", w.display())))?,
            (None, any_grid) => {
                match restore::shipped::for_capture_on(&native, psf_px, device.clone())? {
                    restore::shipped::Choice::Network(net, why, _) => {
                        said = Some(format!("Using {why}."));
                        *net
                    }
                    restore::shipped::Choice::Declined(why) if any_grid => {
                        let general = restore::shipped::GENERAL;
                        said = Some(format!(
                            "Using {} outside what it covers (--any-grid): {why}.",
                            general.name
                        ));
                        Restorer::from_bytes_any_grid_on(
                            general.bytes,
                            Path::new(general.name),
                            device,
                        )?
                    }
                    restore::shipped::Choice::Declined(why) => {
                        return refused(format!(
                            "--weights: none given, and {why} (--psf {}); train one with `metasplat restorer train`, or pass --any-grid to measure it there",
                            self.psf.display()
                        ));
                    }
                }
            }
        };
        Ok((native, self.tiling.apply(net)?, said))
    }

    /// The files this reads, for the output-aliasing guard.
    pub fn inputs(&self) -> Vec<(&'static str, &Path)> {
        let mut v = vec![("--psf", self.psf.as_path())];
        if let Some(w) = &self.weights {
            v.push(("--weights", w.as_path()));
        }
        v
    }
}
