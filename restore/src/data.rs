//! Training pairs: clean photos aberrated by the PSF model with sensor noise, turned into the
//! 13 MAFG Wiener images the network reads.
//!
//! Two kinds of sample per photo, as the paper trains: the whole photo blurred by the patch-wise
//! spatially varying grid, and the whole photo blurred by one PSF drawn from a random grid
//! position (so every one of the 81 PSFs is seen on all kinds of content). Wiener images are
//! computed on the whole photo, so a crop's inputs carry the context outside it.

use crate::config::RestorerConfig;
use crate::error::{RestoreError, Result};
use crate::family::{LensFamily, PairDraw};
use aberration::wiener::{BANK_SIZE, bank_constants, deconvolve_many};
use aberration::{BlurMode, BlurPlan, Image, NoiseModel, PsfGrid, Regularizer};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use std::path::{Path, PathBuf};

/// Wiener images stored as 16-bit: halves memory against f32 at an error (7.6e-6) far under
/// the sensor noise.
const Q: f32 = 65535.0;

/// One aberrated photo: its 13 Wiener images and the clean photo, planar, quantised.
pub struct Sample {
    pub width: usize,
    pub height: usize,
    /// `BANK_SIZE · 3` planes, filter-major.
    inputs: Vec<u16>,
    /// 3 planes.
    clean: Vec<u16>,
}

fn quantise(dst: &mut Vec<u16>, img: &Image) {
    dst.extend(
        img.data
            .iter()
            .map(|&v| (v.clamp(0.0, 1.0) * Q).round() as u16),
    );
}

/// The bank's regularisers for a config (adaptive K, or fixed K for the ablation).
pub fn bank_regularizers(adaptive: bool) -> Vec<Regularizer> {
    bank_constants()
        .iter()
        .map(|&k| {
            if adaptive {
                Regularizer::Adaptive(k)
            } else {
                Regularizer::Fixed(k)
            }
        })
        .collect()
}

/// The 13 Wiener images of an aberrated image, `psf` already at the image's scale.
pub fn bank_images(blurred: &Image, psf: &PsfGrid, adaptive: bool) -> Result<Vec<Image>> {
    Ok(deconvolve_many(blurred, psf, &bank_regularizers(adaptive))?)
}

/// Which PSFs blur a sample.
#[derive(Clone, Copy, Debug)]
pub enum Blur {
    /// The whole grid, spatially varying.
    Grid,
    /// One PSF of the grid (row-major index) everywhere.
    Position(usize),
}

impl Sample {
    /// Aberrates `clean` (PSF mapped to its size), adds seeded noise, runs the bank.
    pub fn make(
        clean: &Image,
        native: &PsfGrid,
        blur: Blur,
        noise: NoiseModel,
        adaptive: bool,
        seed: u64,
    ) -> Result<Self> {
        Self::make_on(clean, native, None, blur, noise, adaptive, seed)
    }

    /// [`Self::make`] on a sensor of `sensor_px` (None: the grid's own), which sets the PSF
    /// scale at the photo's size.
    pub fn make_on(
        clean: &Image,
        native: &PsfGrid,
        sensor_px: Option<usize>,
        blur: Blur,
        noise: NoiseModel,
        adaptive: bool,
        seed: u64,
    ) -> Result<Self> {
        let psf = native.for_image(clean.width, clean.height, sensor_px)?;
        let psf = match blur {
            Blur::Grid => psf,
            Blur::Position(g) => {
                let kernels = [psf.kernel(g, 0), psf.kernel(g, 1), psf.kernel(g, 2)];
                PsfGrid::uniform(1, psf.size(), kernels)?
            }
        };
        let plan = BlurPlan::new(&psf, clean.width, clean.height, BlurMode::Tiled)?;
        let blurred = noise.apply(&plan.apply(clean)?, seed);
        let bank = bank_images(&blurred, &psf, adaptive)?;
        Ok(Self::of_bank(&bank, clean))
    }

    /// A captured pair (the photo as the lens took it, and the same scene clean, as a lab
    /// gets by photographing a display): the bank made from the captured photo through
    /// `native` mapped to its size.
    pub fn from_pair(
        captured: &Image,
        clean: &Image,
        native: &PsfGrid,
        adaptive: bool,
    ) -> Result<Self> {
        if (captured.width, captured.height) != (clean.width, clean.height) {
            return Err(RestoreError::BadInput(format!(
                "a captured photo of {}x{} and its clean photo of {}x{}",
                captured.width, captured.height, clean.width, clean.height
            )));
        }
        let psf = native.for_image(captured.width, captured.height, None)?;
        let bank = bank_images(captured, &psf, adaptive)?;
        Ok(Self::of_bank(&bank, clean))
    }

    fn of_bank(bank: &[Image], clean: &Image) -> Self {
        let mut inputs = Vec::with_capacity(BANK_SIZE * clean.data.len());
        for b in bank {
            quantise(&mut inputs, b);
        }
        let mut c = Vec::with_capacity(clean.data.len());
        quantise(&mut c, clean);
        Self {
            width: clean.width,
            height: clean.height,
            inputs,
            clean: c,
        }
    }

    /// Copies the `s × s` crop at `(x0, y0)` into `inputs` (39 planes) and `target` (3).
    pub fn crop_into(
        &self,
        x0: usize,
        y0: usize,
        s: usize,
        inputs: &mut Vec<f32>,
        target: &mut Vec<f32>,
    ) {
        let plane = self.width * self.height;
        let copy = |src: &[u16], planes: usize, dst: &mut Vec<f32>| {
            for p in 0..planes {
                for y in y0..y0 + s {
                    let row = p * plane + y * self.width;
                    dst.extend(src[row + x0..row + x0 + s].iter().map(|&v| v as f32 / Q));
                }
            }
        };
        copy(&self.inputs, BANK_SIZE * 3, inputs);
        copy(&self.clean, 3, target);
    }
}

/// PNG/JPEG photos in a folder, sorted by name.
pub fn list_images(dir: &Path) -> Result<Vec<PathBuf>> {
    let rd = std::fs::read_dir(dir).map_err(|e| RestoreError::Io(dir.to_path_buf(), e))?;
    let mut v: Vec<PathBuf> = rd
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.extension()
                .and_then(|e| e.to_str())
                .is_some_and(|e| matches!(e.to_ascii_lowercase().as_str(), "png" | "jpg" | "jpeg"))
        })
        .collect();
    v.sort();
    if v.is_empty() {
        return Err(RestoreError::BadInput(format!(
            "{}: no PNG or JPEG images",
            dir.display()
        )));
    }
    Ok(v)
}

/// The photos of a folder ([`list_images`]), each at least `min_side` on both sides, with their
/// file names.
pub fn load_folder(dir: &Path, min_side: usize) -> Result<Vec<(String, Image)>> {
    list_images(dir)?
        .iter()
        .map(|p| {
            let name = p
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default();
            Ok((name, load_photo(p, min_side)?))
        })
        .collect()
}

/// The folders of a pairs folder: the photos as the lens took them, and the same scenes clean.
pub const CAPTURED_DIR: &str = "captured";
pub const CLEAN_DIR: &str = "clean";

/// Whether `dir` is a pairs folder (`captured/` and `clean/` inside).
pub fn is_pairs_folder(dir: &Path) -> bool {
    dir.join(CAPTURED_DIR).is_dir() && dir.join(CLEAN_DIR).is_dir()
}

/// The pairs of a pairs folder, by name: every photo of `captured/` with the photo of the
/// same name in `clean/`, of the same size (both at least `min_side`). A photo without its
/// partner, or of another size, is an error naming it.
pub fn load_pairs(dir: &Path, min_side: usize) -> Result<Vec<(String, Image, Image)>> {
    let captured = list_images(&dir.join(CAPTURED_DIR))?;
    let clean_dir = dir.join(CLEAN_DIR);
    let clean = list_images(&clean_dir)?;
    let name = |p: &Path| p.file_name().map(|n| n.to_string_lossy().into_owned());
    if let Some(lone) = clean
        .iter()
        .find(|c| !captured.iter().any(|p| name(p) == name(c)))
    {
        return Err(RestoreError::BadInput(format!(
            "{}: no captured photo of that name in {}",
            lone.display(),
            dir.join(CAPTURED_DIR).display()
        )));
    }
    captured
        .iter()
        .map(|p| {
            let n = name(p).unwrap_or_default();
            let c = clean_dir.join(&n);
            if !c.is_file() {
                return Err(RestoreError::BadInput(format!(
                    "{}: no clean photo of that name in {}",
                    p.display(),
                    clean_dir.display()
                )));
            }
            let (a, b) = (load_photo(p, min_side)?, load_photo(&c, min_side)?);
            if (a.width, a.height) != (b.width, b.height) {
                return Err(RestoreError::BadInput(format!(
                    "{} is {}x{} and {} is {}x{}: a pair must be of one size",
                    p.display(),
                    a.width,
                    a.height,
                    c.display(),
                    b.width,
                    b.height
                )));
            }
            Ok((n, a, b))
        })
        .collect()
}

/// Loads a photo as RGB in [0, 1] (alpha dropped, 16-bit scaled), refusing ones smaller
/// than a crop.
pub fn load_photo(path: &Path, min_side: usize) -> Result<Image> {
    let img = Image::load(path)?;
    if img.width < min_side || img.height < min_side {
        return Err(RestoreError::BadInput(format!(
            "{}: {}x{} is smaller than the {min_side}px training crop",
            path.display(),
            img.width,
            img.height
        )));
    }
    Ok(img)
}

/// Smallest and largest PSF side (px) `native` maps to over the photos' sizes.
fn psf_px_range<'a>(photos: impl Iterator<Item = &'a Image>, native: &PsfGrid) -> [usize; 2] {
    photos.fold([usize::MAX, 0], |[lo, hi], p| {
        let k = native.mapped_size(p.width, p.height, None);
        [lo.min(k), hi.max(k)]
    })
}

/// The training set: every photo as a grid sample and as a single-PSF sample.
pub struct TrainSet {
    pub samples: Vec<Sample>,
    /// Smallest and largest PSF side (px) over the photos' sizes.
    pub psf_px: [usize; 2],
}

impl TrainSet {
    pub fn build(
        photos: &[Image],
        native: &PsfGrid,
        cfg: &RestorerConfig,
        noise: NoiseModel,
        seed: u64,
        progress: &(dyn Fn() + Sync),
    ) -> Result<Self> {
        let positions = native.grid() * native.grid();
        let jobs: Vec<(usize, Blur, u64)> = photos
            .iter()
            .enumerate()
            .flat_map(|(i, _)| {
                let mut rng = ChaCha8Rng::seed_from_u64(
                    seed ^ (i as u64).wrapping_mul(base::rng::GOLDEN_GAMMA),
                );
                let g = rng.random_range(0..positions);
                [
                    (i, Blur::Grid, rng.random()),
                    (i, Blur::Position(g), rng.random()),
                ]
            })
            .collect();
        let samples = jobs
            .par_iter()
            .map(|&(i, blur, s)| {
                let r = Sample::make(&photos[i], native, blur, noise, cfg.adaptive_k, s);
                progress();
                r
            })
            .collect::<Result<Vec<_>>>()?;
        let psf_px = psf_px_range(photos.iter(), native);
        Ok(Self { samples, psf_px })
    }

    /// Pairs over a lens family: for every photo a grid sample and a single-PSF sample, each
    /// through a lens of `lenses` (native grids of the family's bank), at a PSF scale, noise
    /// level and augmentation drawn by [`LensFamily::pair`]. The Wiener bank is computed
    /// through the pair's own grid at its own scale, on the whole photo.
    pub fn build_family(
        photos: &[Image],
        lenses: &[PsfGrid],
        family: &LensFamily,
        cfg: &RestorerConfig,
        noise: NoiseModel,
        seed: u64,
        progress: &(dyn Fn() + Sync),
    ) -> Result<Self> {
        if lenses.is_empty() {
            return Err(RestoreError::BadInput("a lens family of no lenses".into()));
        }
        let jobs: Vec<(usize, bool, PairDraw)> = photos
            .iter()
            .enumerate()
            .flat_map(|(i, _)| {
                let s = seed ^ (i as u64).wrapping_mul(base::rng::GOLDEN_GAMMA);
                [
                    (i, false, family.pair(lenses.len(), s)),
                    (i, true, family.pair(lenses.len(), base::mix64(s))),
                ]
            })
            .collect();
        let samples = jobs
            .par_iter()
            .map(|&(i, single, draw)| {
                let photo = draw.augment(&photos[i]);
                let native = &lenses[draw.lens];
                let sensor = native.sensor_for_psf_px(photo.width, photo.height, draw.psf_px);
                let blur = if single {
                    let g = (draw.seed % (native.grid() * native.grid()) as u64) as usize;
                    Blur::Position(g)
                } else {
                    Blur::Grid
                };
                let r = Sample::make_on(
                    &photo,
                    native,
                    Some(sensor),
                    blur,
                    draw.noise(noise),
                    cfg.adaptive_k,
                    draw.seed,
                );
                progress();
                r
            })
            .collect::<Result<Vec<_>>>()?;
        Ok(Self {
            samples,
            psf_px: family.psf_px,
        })
    }

    /// Captured pairs (`(captured, clean)`), each one sample whose bank comes through
    /// `native`: fine-tuning to a lens that exists. The PSF scale is the grid's at the
    /// photos' size.
    pub fn from_pairs(
        pairs: &[(Image, Image)],
        native: &PsfGrid,
        cfg: &RestorerConfig,
        progress: &(dyn Fn() + Sync),
    ) -> Result<Self> {
        let samples = pairs
            .par_iter()
            .map(|(captured, clean)| {
                let r = Sample::from_pair(captured, clean, native, cfg.adaptive_k);
                progress();
                r
            })
            .collect::<Result<Vec<_>>>()?;
        let psf_px = psf_px_range(pairs.iter().map(|(p, _)| p), native);
        Ok(Self { samples, psf_px })
    }

    /// A batch of random crops: inputs `[b, 39, s, s]` and targets `[b, 3, s, s]`, flat.
    pub fn batch(&self, rng: &mut ChaCha8Rng, b: usize, s: usize) -> (Vec<f32>, Vec<f32>) {
        let mut inputs = Vec::with_capacity(b * BANK_SIZE * 3 * s * s);
        let mut target = Vec::with_capacity(b * 3 * s * s);
        for _ in 0..b {
            let smp = &self.samples[rng.random_range(0..self.samples.len())];
            let x0 = rng.random_range(0..=smp.width - s);
            let y0 = rng.random_range(0..=smp.height - s);
            smp.crop_into(x0, y0, s, &mut inputs, &mut target);
        }
        (inputs, target)
    }
}
