//! What several end-to-end tests share: running the binary ([`cli`]), a procedural capture
//! and its aberrated copy.
#![allow(dead_code)]

pub mod cli;

use std::path::{Path, PathBuf};

use aberration::optics::{SimConfig, simulate_grid};
use metasplat::procedural::{ProceduralOptions, write_capture};

/// Writes the procedural capture `o` to `dir/clean`, simulates a small lens (a 3×3 grid of
/// 21 px PSFs) to `dir/psf.npy` and aberrates the capture through it into `dir/aberrated`.
/// Returns the clean capture, the aberrated one and the PSF file.
pub fn aberrated_procedural(dir: &Path, o: &ProceduralOptions) -> (PathBuf, PathBuf, PathBuf) {
    let (psf, _) = simulate_grid(&SimConfig::small(21), &|_, _| {}).unwrap();
    aberrated_procedural_through(dir, o, &psf)
}

/// As [`aberrated_procedural`], through the grid `psf`.
pub fn aberrated_procedural_through(
    dir: &Path,
    o: &ProceduralOptions,
    psf: &aberration::PsfGrid,
) -> (PathBuf, PathBuf, PathBuf) {
    let clean = write_capture(&dir.join("clean"), o).unwrap();
    let psf_path = dir.join("psf.npy");
    psf.save_npy(&psf_path).unwrap();
    let capture = scenes::open(
        &clean,
        &scenes::OpenOptions {
            resolution: scenes::Resolution::Downsample(1),
            ..Default::default()
        },
    )
    .unwrap();
    let aberrated = dir.join("aberrated");
    scenes::make_aberrated(
        &capture,
        &psf_path,
        &aberrated,
        &scenes::AberrateOptions::default(),
        &|| {},
    )
    .unwrap();
    (clean, aberrated, psf_path)
}
