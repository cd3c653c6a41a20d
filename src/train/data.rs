//! The training data of a run: every view's camera and images (observed, restored, clean),
//! the imaging model the capture was made with, and the initial point cloud.

use std::path::{Path, PathBuf};

use aberration::{BlurMode, ImagingModel, NoiseModel, PsfGrid};
use glam::Vec3;
use rayon::prelude::*;
use scenes::aberrated::{self, AberrationRecord};
use scenes::{Capture, OpenOptions, PointCloud, Resolution};

use crate::convert::{image_to_pixels, pixels_to_image, rgb_to_pixels, splat_camera};
use crate::error::{Result, TrainError};
use crate::train::config::Mode;

/// One camera and its images, row-major RGB in [0, 1].
#[derive(Clone, Debug)]
pub struct View {
    pub name: String,
    pub camera: splat::Camera,
    /// What the camera recorded: `I_abr` for an aberrated capture.
    pub observed: Vec<Vec3>,
    /// `I_ac`: the restorer's output for `observed` (training views of modes that use it).
    pub restored: Option<Vec<Vec3>>,
    /// Ground truth from the capture's `clean/` folder, when it has one.
    pub clean: Option<Vec<Vec3>>,
}

/// Where the user wants `I_ac` to come from.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum RestorerChoice {
    /// The shipped transformer when it was trained for the capture's PSF grid, else the
    /// Wiener image (and every output says which).
    Auto,
    /// The Wiener filter with `metasplat deconvolve`'s default constant.
    Wiener,
    /// Transformer weights from a file (refused if trained for another PSF grid).
    Weights(PathBuf),
}

impl std::str::FromStr for RestorerChoice {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        Ok(match s {
            "auto" => Self::Auto,
            "wiener" => Self::Wiener,
            _ if s.is_empty() => return Err("empty restorer".into()),
            path => Self::Weights(PathBuf::from(path)),
        })
    }
}

/// Where `I_ac` came from.
#[derive(Clone, Debug, PartialEq)]
pub enum Restorer {
    /// The Wiener filter with `metasplat deconvolve`'s default constant (no trained weights
    /// for this PSF grid). It replaced the median of the MAFG bank, which at low resolution is
    /// worse than the aberrated input and whose ringing long runs learned (RESULTS.md).
    Wiener,
    /// The MAFG + STAF transformer: its config name, where its weights came from, and a
    /// hash of the weights file.
    Network {
        config: String,
        source: String,
        weights: String,
    },
}

impl Restorer {
    /// The default weight of `L(render, I_ac)` for this source of `I_ac`: the paper's 0.75
    /// with the transformer; the Wiener stand-in is worse than the aberrated input at low
    /// resolution and a large λ fits its errors, so its default is lower (the demo-scene
    /// sweep is in RESULTS.md).
    pub fn default_lambda(&self) -> f32 {
        match self {
            Restorer::Wiener => 0.25,
            Restorer::Network { .. } => crate::train::config::PAPER_LAMBDA,
        }
    }

    pub fn describe(&self) -> String {
        match self {
            Restorer::Wiener => {
                "I_ac = Wiener image, K = 1e-2 (stand-in: no trained restorer fits this PSF grid and scale)"
                    .into()
            }
            Restorer::Network { config, source, .. } => {
                format!("I_ac = MAFG + STAF restorer, config '{config}', weights {source}")
            }
        }
    }

    /// What makes `I_ac` what it is, independent of where the weights file lies: a resumed
    /// run must get its `I_ac` from the same source.
    pub fn identity(&self) -> String {
        match self {
            Restorer::Wiener => "Wiener K=1e-2".into(),
            Restorer::Network {
                config, weights, ..
            } => format!("{config} network, weights fnv1a {weights}"),
        }
    }
}

/// A loaded network and where its weights came from.
type OpenedRestorer = (restore::Restorer, String);

/// Resolves a restorer choice for the capture's PSF grid (`native`, as simulated) whose PSFs
/// are `psf_px` wide at the capture's size. Also returns a note when `auto` passes over the
/// shipped network, or when given weights never saw this blur scale.
fn open_restorer(
    choice: &RestorerChoice,
    native: &PsfGrid,
    psf_px: usize,
) -> Result<(Option<OpenedRestorer>, Option<String>)> {
    let scale_note = |r: &restore::Restorer, name: &str| {
        let [lo, hi] = r.header.trained_psf_px.unwrap_or([0, 0]);
        format!("{name} was trained on {lo}-{hi} px PSFs; this capture's are {psf_px} px")
    };
    Ok(match choice {
        RestorerChoice::Wiener => (None, None),
        RestorerChoice::Auto => match restore::shipped::for_psf(native)? {
            Some(r) if r.header.fits_psf_px(psf_px) => {
                (Some((r, restore::shipped::TINY_NAME.to_string())), None)
            }
            Some(r) => (
                None,
                Some(format!(
                    "{}: using the Wiener image instead",
                    scale_note(&r, "the shipped restorer")
                )),
            ),
            None => (None, None),
        },
        RestorerChoice::Weights(p) => {
            let r = restore::Restorer::load(p, native)?;
            let note = (!r.header.fits_psf_px(psf_px))
                .then(|| format!("warning: {}", scale_note(&r, &p.display().to_string())));
            (Some((r, p.display().to_string())), note)
        }
    })
}

/// How a capture is read for training (the defaults are the command line's).
#[derive(clap::Args, Clone, Debug)]
pub struct DataOptions {
    /// Use images_N (1: images/).
    #[arg(long, default_value_t = 8, value_parser = clap::value_parser!(u32).range(1..=64))]
    pub downsample: u32,
    /// Every N-th view is held out for evaluation (0: none).
    #[arg(long, default_value_t = scenes::LLFFHOLD, value_parser = crate::flags::llffhold, allow_negative_numbers = true)]
    pub llffhold: usize,
    /// PSF grid .npy; must match the capture's own psf.npy when it has one.
    #[arg(long)]
    pub psf: Option<PathBuf>,
    /// Source of I_ac: `auto` (the shipped transformer when trained for this PSF grid, else
    /// the Wiener image), `wiener`, or a restorer weights file.
    #[arg(long, default_value = "auto")]
    pub restorer: RestorerChoice,
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// A folder of cached `I_ac` images to read (and, for a run, to fill): see
    /// [`crate::train::iac_cache`].
    #[arg(skip)]
    pub iac_cache: Option<PathBuf>,
}

/// λ when the user gives none: the restorer's, or the paper's where no `I_ac` is used.
pub fn default_lambda(restorer: Option<&Restorer>) -> f32 {
    restorer.map_or(crate::train::config::PAPER_LAMBDA, Restorer::default_lambda)
}

impl Default for DataOptions {
    fn default() -> Self {
        crate::run::parse_args(&[])
    }
}

pub struct Dataset {
    pub capture: Capture,
    pub width: u32,
    pub height: u32,
    pub train: Vec<View>,
    pub test: Vec<View>,
    /// The blur the capture went through (None for a clean capture without `--psf`).
    pub imaging: Option<ImagingModel>,
    pub restorer: Option<Restorer>,
    /// Why the restorer is not the one asked for, or a warning about it.
    pub restorer_note: Option<String>,
    /// 3DGS scene extent (camera radius × 1.1): scales position lr and size thresholds.
    pub extent: f32,
    pub points: PointCloud,
    /// A splat scene to start from instead of the points (`train --init`).
    pub initial: Option<splat::Gaussians>,
    /// Training views whose `I_ac` was computed (not found in the cache), with their cache
    /// keys: [`Dataset::cache_restored`] stores them.
    pub restored_fresh: Vec<(usize, u64)>,
}

impl Dataset {
    /// Stores the `I_ac` images computed at load in the cache folder `dir`. The cache only
    /// saves time, so a failure to write it is reported, not fatal.
    pub fn cache_restored(&self, dir: &Path) -> Option<String> {
        for &(i, key) in &self.restored_fresh {
            if let Some(img) = &self.train[i].restored
                && let Err(e) = crate::train::iac_cache::put(dir, key, img)
            {
                return Some(format!(
                    "The I_ac images were not cached in {}: {e}.",
                    dir.display()
                ));
            }
        }
        None
    }

    /// True when every test view has a clean image to compare against.
    pub fn can_evaluate(&self) -> bool {
        !self.test.is_empty() && self.test.iter().all(|v| v.clean.is_some())
    }
}

fn load_psf(path: &Path) -> Result<PsfGrid> {
    PsfGrid::load_npy(path).map_err(|e| TrainError::file(path, e.to_string()))
}

/// How a capture was imaged: grid, blur mode, sensor size, noise.
type ImagingSettings = (PsfGrid, BlurMode, Option<usize>, NoiseModel);

/// The PSF grid and blur settings of a capture: its own record, checked against `--psf`.
fn imaging_settings(
    dir: &Path,
    capture: &Capture,
    user_psf: Option<&Path>,
) -> Result<Option<ImagingSettings>> {
    let record = AberrationRecord::read(dir)?;
    let (w, h) = (capture.cameras[0].width, capture.cameras[0].height);
    if let Some(r) = &record
        && (r.width, r.height) != (w, h)
    {
        return Err(TrainError::file(
            dir.join(aberrated::RECORD_FILE),
            format!(
                "the capture was aberrated at {}x{} but {} holds {w}x{h} images; the PSF model would not match (use the downsample it was made at)",
                r.width,
                r.height,
                capture.image_dir.display()
            ),
        ));
    }
    let own = match &record {
        Some(r) => Some(r.load_psf(dir)?),
        None => None,
    };
    let given = user_psf.map(load_psf).transpose()?;
    let psf = match (own, given) {
        (Some(own), Some(given)) => {
            if own != given {
                return Err(TrainError::file(
                    user_psf.expect("given implies a path"),
                    format!(
                        "this PSF grid ({}x{} of {} px) is not the one {} was made with ({}x{} of {} px, {}); leave out --psf to use the capture's",
                        given.grid(),
                        given.grid(),
                        given.size(),
                        dir.display(),
                        own.grid(),
                        own.grid(),
                        own.size(),
                        dir.join(aberrated::PSF_FILE).display()
                    ),
                ));
            }
            own
        }
        (Some(p), None) | (None, Some(p)) => p,
        (None, None) => return Ok(None),
    };
    let (mode, sensor, noise) = match &record {
        Some(r) => (
            r.blur_mode(&dir.join(aberrated::RECORD_FILE))?,
            r.sensor_px,
            r.noise(),
        ),
        None => (BlurMode::Tiled, None, NoiseModel::default()),
    };
    Ok(Some((psf, mode, sensor, noise)))
}

/// A capture opened with its imaging model and its source of `I_ac`, before any image is
/// read: training loads its views from it, and the viewer's comparison asks it for one view
/// at a time, so both see the same pixels.
pub struct CaptureModel {
    pub capture: Capture,
    pub width: u32,
    pub height: u32,
    /// The blur the capture went through (None for a clean capture without `--psf`).
    pub imaging: Option<ImagingModel>,
    /// Where `I_ac` comes from, when it was asked for and the capture has a PSF grid.
    pub restorer: Option<Restorer>,
    pub restorer_note: Option<String>,
    network: Option<OpenedRestorer>,
    /// Names cached `I_ac` images (None without a restorer).
    keyer: Option<crate::train::iac_cache::Keyer>,
}

impl CaptureModel {
    /// Opens the capture, its PSF model, and (with `with_restorer`) the restorer. Errors name
    /// the file and the problem.
    pub fn open(dir: &Path, options: &DataOptions, with_restorer: bool) -> Result<Self> {
        let open = OpenOptions {
            resolution: Resolution::Downsample(options.downsample),
            llffhold: options.llffhold,
            seed: options.seed,
            ..OpenOptions::default()
        };
        let capture = scenes::open(dir, &open)?;
        if capture.split.train.is_empty() {
            return Err(TrainError::file(dir, "no training views after the split"));
        }
        let (width, height) = (capture.cameras[0].width, capture.cameras[0].height);
        let settings = imaging_settings(dir, &capture, options.psf.as_deref())?;
        let imaging = match &settings {
            Some((psf, blur, sensor, noise)) => Some(
                ImagingModel::new(psf, width as usize, height as usize, *blur, *sensor, *noise)
                    .map_err(|e| {
                        TrainError::file(
                            options.psf.clone().unwrap_or(dir.join(aberrated::PSF_FILE)),
                            format!("PSF grid does not fit {width}x{height} images: {e}"),
                        )
                    })?,
            ),
            None => None,
        };
        let (network, restorer_note) = match (&settings, &imaging, with_restorer) {
            (Some((psf, ..)), Some(model), true) => {
                open_restorer(&options.restorer, psf, model.psf().size())?
            }
            _ => (None, None),
        };
        let restorer = (with_restorer && imaging.is_some()).then(|| match &network {
            Some((r, source)) => Restorer::Network {
                config: r.config().name.clone(),
                source: source.clone(),
                weights: r.weights_hash.clone().unwrap_or_default(),
            },
            None => Restorer::Wiener,
        });
        let keyer = match (&restorer, &imaging) {
            (Some(r), Some(m)) => Some(crate::train::iac_cache::Keyer::new(&r.identity(), m.psf())),
            _ => None,
        };
        Ok(Self {
            capture,
            width,
            height,
            imaging,
            restorer,
            restorer_note,
            network,
            keyer,
        })
    }

    /// View `i` with its observed and clean images; `I_ac` is left to [`Self::restore`].
    pub fn view(&self, i: usize) -> Result<View> {
        let observed = rgb_to_pixels(&self.capture.load_image(i)?);
        let clean = aberrated::load_clean_image(&self.capture, i)?.map(|c| rgb_to_pixels(&c));
        Ok(View {
            name: self.capture.cameras[i].name.clone(),
            camera: splat_camera(&self.capture.cameras[i]),
            observed,
            restored: None,
            clean,
        })
    }

    /// True when `I_ac` comes from the network (which parallelises inside, so callers
    /// restore its views one at a time).
    pub fn restores_with_network(&self) -> bool {
        self.network.is_some()
    }

    /// `I_ac` from the cache folder `cache` when it holds it, else computed
    /// ([`Self::restore`]) together with the key to cache it under (None when it was read, or
    /// when there is no cache).
    pub fn restore_cached(
        &self,
        observed: &[Vec3],
        cache: Option<&Path>,
    ) -> Result<Option<(Vec<Vec3>, Option<u64>)>> {
        let key = match (cache, &self.keyer) {
            (Some(_), Some(k)) => Some(k.key(self.width, self.height, observed)),
            _ => None,
        };
        if let (Some(dir), Some(key)) = (cache, key)
            && let Some(img) = crate::train::iac_cache::get(dir, key, observed.len())
        {
            return Ok(Some((img, None)));
        }
        Ok(self.restore(observed)?.map(|img| (img, key)))
    }

    /// `I_ac` for an observed image: the restorer's output, or None when no restorer was
    /// asked for or the capture has no PSF grid.
    pub fn restore(&self, observed: &[Vec3]) -> Result<Option<Vec<Vec3>>> {
        let (Some(_), Some(model)) = (&self.restorer, &self.imaging) else {
            return Ok(None);
        };
        let blurred = pixels_to_image(observed, self.width, self.height);
        let restored = match &self.network {
            Some((net, _)) => net.restore(&blurred, model.psf())?,
            None => {
                let mut wiener = aberration::wiener::deconvolve(
                    &blurred,
                    model.psf(),
                    aberration::wiener::Regularizer::Fixed(aberration::wiener::DEFAULT_K),
                )?;
                wiener.clamp01();
                wiener
            }
        };
        Ok(Some(image_to_pixels(&restored)))
    }
}

/// Loads a capture for training in `mode`. Errors name the file and the problem.
pub fn load(dir: &Path, mode: Mode, options: &DataOptions) -> Result<Dataset> {
    let model = CaptureModel::open(dir, options, mode.needs_psf())?;
    if mode.needs_psf() && model.imaging.is_none() {
        return Err(TrainError::file(
            dir,
            format!(
                "mode {mode} needs the PSF grid: pass --psf, or train on a capture made by `metasplat scene aberrate` (it holds psf.npy)"
            ),
        ));
    }
    let cache = options.iac_cache.as_deref();
    // The network parallelises inside, so its views are restored one at a time below.
    let make_view = |i: usize, restore: bool| -> Result<(View, Option<u64>)> {
        let mut v = model.view(i)?;
        let mut fresh = None;
        if restore
            && !model.restores_with_network()
            && let Some((img, key)) = model.restore_cached(&v.observed, cache)?
        {
            v.restored = Some(img);
            fresh = key;
        }
        Ok((v, fresh))
    };
    let loaded = model
        .capture
        .split
        .train
        .par_iter()
        .map(|&i| make_view(i, true))
        .collect::<Result<Vec<_>>>()?;
    let mut restored_fresh = Vec::new();
    let mut train = Vec::with_capacity(loaded.len());
    for (k, (mut v, mut fresh)) in loaded.into_iter().enumerate() {
        if model.restores_with_network()
            && let Some((img, key)) = model.restore_cached(&v.observed, cache)?
        {
            v.restored = Some(img);
            fresh = key;
        }
        if let Some(key) = fresh {
            restored_fresh.push((k, key));
        }
        train.push(v);
    }
    let test = model
        .capture
        .split
        .test
        .par_iter()
        .map(|&i| make_view(i, false).map(|(v, _)| v))
        .collect::<Result<Vec<_>>>()?;
    let CaptureModel {
        capture,
        width,
        height,
        imaging,
        restorer,
        restorer_note,
        ..
    } = model;
    // One camera (or all at one spot) has no radius; 1 keeps the thresholds meaningful.
    let radius = capture.normalization().radius as f32;
    let extent = if radius > 0.0 { radius } else { 1.0 };
    let points = capture.points.clone();
    Ok(Dataset {
        width,
        height,
        train,
        test,
        imaging,
        restorer,
        restorer_note,
        extent,
        points,
        initial: None,
        restored_fresh,
        capture,
    })
}
