//! A capture opened with its imaging model and its source of `I_ac`, before any image is
//! read: training loads its views from it ([`crate::train::data::load`]), and the viewer's
//! comparison asks it for one view at a time, so both see the same pixels.

use std::path::Path;

use aberration::{BlurMode, ImagingModel, NoiseModel, PsfGrid};
use glam::Vec3;
use scenes::aberrated::{self, AberrationRecord};
use scenes::{Capture, OpenOptions, Resolution};

use crate::error::{Result, TrainError};
use crate::settings::DataOptions;
use crate::splats::convert::{image_to_pixels, pixels_to_image, rgb_to_pixels, splat_camera};
use crate::train::iac::{IacSource, OpenedRestorer, open_restorer};

/// The smallest image side a capture trains at.
pub const MIN_TRAIN_SIDE: u32 = 8;

/// The PSF reader's errors name the file themselves.
fn load_psf(path: &Path) -> Result<PsfGrid> {
    Ok(PsfGrid::load_npy(path)?)
}

/// How a capture was imaged: grid, blur mode, sensor size, noise.
type ImagingSettings = (PsfGrid, BlurMode, Option<usize>, NoiseModel);

/// The PSF grid and blur settings of a capture: its own record, checked against `--psf`.
fn imaging_settings(
    dir: &Path,
    capture: &Capture,
    user_psf: Option<&Path>,
    assumed: Option<&Path>,
) -> Result<Option<ImagingSettings>> {
    let record = AberrationRecord::read(dir)?;
    let (w, h) = (capture.cameras[0].width, capture.cameras[0].height);
    if let Some(r) = &record
        && (r.width, r.height) != (w, h)
    {
        return Err(TrainError::file(
            dir.join(aberrated::RECORD_FILE),
            format!(
                "the capture was aberrated at {}x{} but {} holds {w}x{h} images; the PSF model would not match: pass the --downsample whose image folder holds {}x{} images",
                r.width,
                r.height,
                capture.image_dir.display(),
                r.width,
                r.height
            ),
        ));
    }
    // Fewer photos than were made is a user's pruning; more were never made through the lens.
    if let Some(r) = &record
        && capture.len() > r.images
    {
        return Err(TrainError::file(
            dir.join(aberrated::RECORD_FILE),
            format!(
                "the capture was made with {} images but {} holds {}: the others did not come through its PSF model",
                r.images,
                capture.image_dir.display(),
                capture.len()
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
                        "this PSF grid ({}x{} of {} px) is not the one {} was made with ({}x{} of {} px{}, {}); leave out --psf to use the capture's",
                        given.grid(),
                        given.grid(),
                        given.size(),
                        dir.display(),
                        own.grid(),
                        own.grid(),
                        own.size(),
                        if (given.grid(), given.size()) == (own.grid(), own.size()) {
                            ", the same shape with other values"
                        } else {
                            ""
                        },
                        dir.join(aberrated::PSF_FILE).display()
                    ),
                ));
            }
            own
        }
        (Some(p), None) | (None, Some(p)) => p,
        (None, None) => return Ok(None),
    };
    let psf = match assumed {
        Some(path) => load_psf(path)?,
        None => psf,
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
    /// Per-pixel weight in the loss (1 keeps, 0 leaves out), from the capture's `masks/` or
    /// the photo's alpha; None: every pixel counts.
    pub mask: Option<Vec<f32>>,
}

/// A capture with its imaging model and its source of `I_ac`.
pub struct CaptureModel {
    pub capture: Capture,
    pub width: u32,
    pub height: u32,
    /// The blur the capture went through (None for a clean capture without `--psf`).
    pub imaging: Option<ImagingModel>,
    /// Where `I_ac` comes from, when it was asked for and the capture has a PSF grid.
    pub restorer: Option<IacSource>,
    pub restorer_note: Option<String>,
    /// The colour the photos were composited over outside their masks before the blur
    /// (`scene aberrate` on a masked capture); None: photos as taken.
    pub composited_over: Option<[f32; 3]>,
    /// The capture's masks are only the border undistortion left (a `scene aberrate` copy
    /// of a capture without masks of its own).
    pub masks_from_undistortion: bool,
    network: Option<OpenedRestorer>,
    /// Names cached `I_ac` images (None without a restorer).
    keyer: Option<crate::train::iac_cache::Keyer>,
    /// The model `I_ac` is restored through when it is not [`Self::imaging`].
    restoring: Option<ImagingModel>,
}

impl CaptureModel {
    /// Opens the capture, its PSF model, and (with `with_restorer`) the restorer. Errors name
    /// the file and the problem.
    pub fn open(dir: &Path, options: &DataOptions, with_restorer: bool) -> Result<Self> {
        let open = OpenOptions {
            resolution: Resolution::Downsample(options.downsample),
            llffhold: options.llffhold,
            seed: options.seed,
            undistort: !options.keep_distortion,
            cache_photos: true,
            ..OpenOptions::default()
        };
        let capture = scenes::open(dir, &open)?;
        if capture.split.train.is_empty() {
            return Err(TrainError::file(
                dir,
                format!(
                    "no training views: the capture has {} view(s) and --llffhold {} holds out every {}th from the first; give a capture with more views or --llffhold 0 to train on all",
                    capture.len(),
                    options.llffhold,
                    options.llffhold
                ),
            ));
        }
        let (width, height) = (capture.cameras[0].width, capture.cameras[0].height);
        // Smaller images hold too few pixels to fit or score splats on (a downsample too
        // large for the capture makes them).
        if width.min(height) < MIN_TRAIN_SIDE {
            return Err(TrainError::file(
                &capture.image_dir,
                format!(
                    "the images are {width}x{height}: training needs at least {MIN_TRAIN_SIDE} px a side; use a smaller --downsample (now {})",
                    options.downsample
                ),
            ));
        }
        let settings = imaging_settings(
            dir,
            &capture,
            options.psf.as_deref(),
            options.assumed_psf.as_deref(),
        )?;
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
        // `I_ac` through another grid than the blur's (the mis-calibration experiment).
        let restoring = match (&options.restorer_psf, &settings) {
            (Some(path), Some((_, blur, sensor, noise))) => {
                let native = load_psf(path)?;
                let model = ImagingModel::new(
                    &native,
                    width as usize,
                    height as usize,
                    *blur,
                    *sensor,
                    *noise,
                )
                .map_err(|e| {
                    TrainError::file(
                        path,
                        format!("PSF grid does not fit {width}x{height} images: {e}"),
                    )
                })?;
                Some((native, model))
            }
            _ => None,
        };
        let restorer_grid = restoring
            .as_ref()
            .map(|(native, model)| (native, model))
            .or(settings.as_ref().map(|s| &s.0).zip(imaging.as_ref()));
        let (network, restorer_note) = match (restorer_grid, with_restorer) {
            (Some((psf, model)), true) => {
                open_restorer(&options.restorer, psf, model.psf().size()).map_err(|e| {
                    // A weights file's error is the flag's, not the capture's.
                    match &options.restorer {
                        crate::settings::RestorerChoice::Weights(w) => {
                            e.context(format!("--restorer {}", w.display()))
                        }
                        _ => e,
                    }
                })?
            }
            _ => (None, None),
        };
        let restoring = restoring.map(|(_, model)| model);
        let record = AberrationRecord::read(dir)?;
        let restorer = (with_restorer && imaging.is_some()).then(|| match &network {
            Some((r, source)) => IacSource::Network {
                config: r.config().name.clone(),
                source: source.clone(),
                weights: r.weights_hash.clone().unwrap_or_default(),
                legacy_weights: r.weights_fnv1a.clone().unwrap_or_default(),
            },
            None => IacSource::Wiener,
        });
        let keyer = match (&restorer, restoring.as_ref().or(imaging.as_ref())) {
            (Some(r), Some(m)) => Some(crate::train::iac_cache::Keyer::new(
                &r.identity(),
                &r.legacy_identity(),
                m.psf(),
            )),
            _ => None,
        };
        Ok(Self {
            capture,
            width,
            height,
            imaging,
            restorer,
            restorer_note,
            composited_over: record.as_ref().and_then(|r| r.composited_over),
            masks_from_undistortion: record.as_ref().is_some_and(|r| r.masks_from_undistortion),
            network,
            keyer,
            restoring,
        })
    }

    /// View `i` with its observed and clean images; `I_ac` is left to [`Self::restore`].
    pub fn view(&self, i: usize) -> Result<View> {
        let observed = rgb_to_pixels(&self.capture.load_image(i)?);
        let clean = aberrated::load_clean_image(&self.capture, i)?.map(|c| rgb_to_pixels(&c));
        let mask = self.capture.load_mask(i)?;
        Ok(View {
            name: self.capture.cameras[i].name.clone(),
            camera: splat_camera(&self.capture.cameras[i]),
            observed,
            restored: None,
            clean,
            mask,
        })
    }

    /// True when `I_ac` comes from the network (which parallelises inside, so callers
    /// restore its views one at a time).
    pub fn restores_with_network(&self) -> bool {
        self.network.is_some()
    }

    /// The key `I_ac` of `observed` is cached under (None without a restorer or PSF grid).
    pub fn cache_key(&self, observed: &[Vec3]) -> Option<crate::train::iac_cache::Key> {
        self.keyer
            .as_ref()
            .map(|k| k.key(self.width, self.height, observed))
    }

    /// `I_ac` of `observed` from the cache folder `cache`, when it holds a whole one.
    pub fn cached(&self, observed: &[Vec3], cache: Option<&Path>) -> Option<Vec<Vec3>> {
        let key = self.cache_key(observed)?;
        crate::train::iac_cache::get(cache?, key, observed.len())
    }

    /// `I_ac` for an observed image: the restorer's output, or None when no restorer was
    /// asked for or the capture has no PSF grid.
    pub fn restore(&self, observed: &[Vec3]) -> Result<Option<Vec<Vec3>>> {
        let (Some(_), Some(model)) = (
            &self.restorer,
            self.restoring.as_ref().or(self.imaging.as_ref()),
        ) else {
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
