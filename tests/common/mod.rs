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

/// Writes `n` smooth colourful test photos of `w × h` into `dir`.
pub fn photos(dir: &Path, n: u32, w: u32, h: u32) {
    std::fs::create_dir_all(dir).unwrap();
    for i in 0..n {
        let img = image::RgbImage::from_fn(w, h, |x, y| {
            let f = (i + 1) as f32;
            let v = |a: f32| (127.0 + 120.0 * a.sin()) as u8;
            image::Rgb([
                v(x as f32 * 0.11 * f),
                v(y as f32 * 0.07 * f + 1.0),
                v((x + y) as f32 * 0.05),
            ])
        });
        img.save(dir.join(format!("p{i}.png"))).unwrap();
    }
}

/// A small simulated grid saved as `d/psf.npy`, two training photos in `d/train` and one
/// validation photo in `d/val`, all `w × h`: what a `restorer train` request reads.
pub fn restorer_inputs(
    d: &Path,
    w: u32,
    h: u32,
) -> (aberration::PsfGrid, PathBuf, PathBuf, PathBuf) {
    let (psf, _) = simulate_grid(&SimConfig::small(21), &|_, _| {}).unwrap();
    let psf_path = d.join("psf.npy");
    psf.save_npy(&psf_path).unwrap();
    let (train, val) = (d.join("train"), d.join("val"));
    photos(&train, 2, w, h);
    photos(&val, 1, w, h);
    (psf, psf_path, train, val)
}

/// `restorer train`'s flags for two steps of batch 1 on those inputs, validated every step on
/// 64 px crops, writing `out`.
pub fn restorer_flags(train: &Path, val: &Path, psf: &Path, out: &Path) -> Vec<String> {
    let s = cli::s;
    [
        "--images",
        s(train),
        "--val",
        s(val),
        "--psf",
        s(psf),
        "--out",
        s(out),
        "--steps",
        "2",
        "--batch",
        "1",
        "--val-every",
        "1",
        "--val-crop",
        "64",
    ]
    .map(String::from)
    .to_vec()
}
