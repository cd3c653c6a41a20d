//! What several end-to-end tests share: running the binary ([`cli`]), a procedural capture
//! and its aberrated copy.
#![allow(dead_code)]

pub mod cli;

use std::path::{Path, PathBuf};

use aberration::optics::{SimConfig, simulate_grid};
use metasplat::splats::procedural::{ProceduralOptions, write_capture};

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

/// The capture most training tests share: the procedural scene at 64×48, 10 views, seen
/// through the small lens, in a folder that lives as long as the value.
pub struct SmallCapture {
    pub dir: tempfile::TempDir,
    pub clean: PathBuf,
    pub aberrated: PathBuf,
    pub psf: PathBuf,
}

/// [`SmallCapture`] of the procedural scene drawn with `seed`.
pub fn small_capture(seed: u64) -> SmallCapture {
    let dir = tempfile::tempdir().unwrap();
    let o = ProceduralOptions {
        width: 64,
        height: 48,
        views: 10,
        seed,
    };
    let (clean, aberrated, psf) = aberrated_procedural(dir.path(), &o);
    SmallCapture {
        dir,
        clean,
        aberrated,
        psf,
    }
}
