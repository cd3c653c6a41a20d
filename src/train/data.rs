//! The training data of a run: every view's camera and images (observed, restored, clean),
//! the imaging model the capture was made with, and the initial point cloud, loaded from a
//! [`CaptureModel`].

use std::path::{Path, PathBuf};

use glam::Vec3;

use rayon::prelude::*;
use scenes::PointCloud;

use crate::error::{Result, TrainError};
use crate::settings::{DataOptions, Mode};

pub use crate::train::capture::{CaptureModel, View};

/// A capture's views loaded for training: the [`CaptureModel`] they came from (its capture,
/// size, imaging model and `I_ac` source read through this type, as `data.width`), the
/// training and held-out views, and what initialisation needs.
pub struct Dataset {
    pub source: CaptureModel,
    pub train: Vec<View>,
    pub test: Vec<View>,
    /// 3DGS scene extent (camera radius × 1.1): scales position lr and size thresholds.
    pub extent: f32,
    pub points: PointCloud,
    /// A splat scene to start from instead of the points (`train --init`).
    pub initial: Option<splat::Gaussians>,
    /// Training views whose `I_ac` the cache did not hold: [`Dataset::restore_pending`]
    /// makes them.
    pub pending: Vec<usize>,
    /// The cache folder `I_ac` is read from and written to.
    cache: Option<PathBuf>,
}

/// What [`Dataset::restore_pending`] did.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct IacReport {
    /// Training views with an `I_ac`, and how many of them were made now (the others came
    /// from the cache).
    pub views: usize,
    pub made: usize,
    /// Why an image could not be cached (the cache only saves time, so this is not fatal).
    pub cache_failure: Option<String>,
}

impl IacReport {
    /// One sentence for the run's log; None when the run has no `I_ac`.
    pub fn sentence(&self, cache: Option<&Path>) -> Option<String> {
        if let Some(f) = &self.cache_failure {
            return Some(f.clone());
        }
        let (views, made) = (self.views, self.made);
        if views == 0 {
            return None;
        }
        let Some(dir) = cache.map(Path::display) else {
            return Some(format!("I_ac: restored all {views} training views."));
        };
        Some(if made == views {
            format!("I_ac: restored all {views} training views and cached them in {dir}.")
        } else if made == 0 {
            format!("I_ac: read all {views} training views from the cache in {dir}.")
        } else {
            format!(
                "I_ac: restored {made} of {views} training views; the others came from the cache in {dir}."
            )
        })
    }
}

impl std::ops::Deref for Dataset {
    type Target = CaptureModel;

    fn deref(&self) -> &CaptureModel {
        &self.source
    }
}

impl Dataset {
    /// Makes the `I_ac` images the cache did not hold, the network's one view at a time (it
    /// parallelises inside), the Wiener stand-in's in parallel, and caches each as soon as it
    /// is made, so a run stopped here keeps what it restored. `on_view(done, total)` follows
    /// the views; a stop request (Ctrl-C) ends it between views.
    pub fn restore_pending(&mut self, on_view: &mut dyn FnMut(usize, usize)) -> Result<IacReport> {
        let pending = std::mem::take(&mut self.pending);
        let total = pending.len();
        let mut report = IacReport {
            views: self.train.iter().filter(|v| v.restored.is_some()).count() + total,
            made: 0,
            cache_failure: None,
        };
        let (model, cache) = (&self.source, self.cache.as_deref());
        type Key = crate::train::iac_cache::Key;
        let restore = |v: &View| -> Result<(Vec<Vec3>, Option<Key>)> {
            let img = model.restore(&v.observed)?.ok_or_else(|| {
                TrainError::Invalid("I_ac was asked for without a restorer".into())
            })?;
            Ok((img, model.cache_key(&v.observed)))
        };
        let keep = |v: &mut View, (img, key): (Vec<Vec3>, Option<Key>), report: &mut IacReport| {
            if let (Some(dir), Some(key)) = (cache, key)
                && report.cache_failure.is_none()
                && let Err(e) = crate::train::iac_cache::put(dir, key, &img)
            {
                report.cache_failure = Some(format!(
                    "The I_ac images were not cached in {}: {e}.",
                    dir.display()
                ));
            }
            v.restored = Some(img);
            report.made += 1;
        };
        on_view(0, total);
        if model.restores_with_network() {
            for (done, &k) in pending.iter().enumerate() {
                if base::interrupt::requested() {
                    self.pending = pending[done..].to_vec();
                    let kept = if cache.is_some() && report.cache_failure.is_none() {
                        "those are cached, and the same command with --overwrite makes only the others"
                    } else {
                        "they were not cached"
                    };
                    return Err(TrainError::Interrupted(format!(
                        "I_ac stopped after {done} of {total} training views; {kept}"
                    )));
                }
                let made = restore(&self.train[k])?;
                keep(&mut self.train[k], made, &mut report);
                on_view(done + 1, total);
            }
        } else {
            let made = pending
                .par_iter()
                .map(|&k| restore(&self.train[k]))
                .collect::<Result<Vec<_>>>()?;
            for (&k, m) in pending.iter().zip(made) {
                keep(&mut self.train[k], m, &mut report);
            }
            on_view(total, total);
        }
        Ok(report)
    }

    /// The folder `I_ac` is cached in (None: not cached).
    pub fn cache_dir(&self) -> Option<&Path> {
        self.cache.as_deref()
    }
}

/// Loads a capture for training in `mode`, `I_ac` included. Errors name the file and the
/// problem.
pub fn load(dir: &Path, mode: Mode, options: &DataOptions) -> Result<Dataset> {
    let mut data = load_cached(dir, mode, options)?;
    data.restore_pending(&mut |_, _| {})?;
    Ok(data)
}

/// [`load`] with only the `I_ac` images the cache holds: the others are
/// [`Dataset::pending`], for [`Dataset::restore_pending`] to make once every input has been
/// checked (it is the slow part of loading).
pub fn load_cached(dir: &Path, mode: Mode, options: &DataOptions) -> Result<Dataset> {
    let model = CaptureModel::open(dir, options, mode.needs_psf())?;
    if mode.needs_psf() && model.imaging.is_none() {
        // A psf.npy without its record: the capture cannot say how its photos were made.
        let orphan = dir.join(scenes::aberrated::PSF_FILE).is_file()
            && !dir.join(scenes::aberrated::RECORD_FILE).exists();
        return Err(TrainError::file(
            dir,
            if orphan {
                format!(
                    "mode {mode} needs the PSF model: the capture holds {} but no {} (how its photos were blurred); pass --psf to use that grid with the default blur, or make the capture again with `metasplat scene aberrate`",
                    scenes::aberrated::PSF_FILE,
                    scenes::aberrated::RECORD_FILE
                )
            } else {
                format!(
                    "mode {mode} needs the PSF grid: pass --psf, or train on a capture made by `metasplat scene aberrate` (it holds psf.npy)"
                )
            },
        ));
    }
    let cache = options.iac_cache.as_deref();
    // Only the cached `I_ac` is read here: making the rest is the slow part of loading, and
    // it waits for [`Dataset::restore_pending`], after every input has been checked.
    let restores = model.restorer.is_some() && model.imaging.is_some();
    let make_view = |i: usize, restore: bool| -> Result<View> {
        let mut v = model.view(i)?;
        if restore {
            v.restored = model.cached(&v.observed, cache);
        }
        Ok(v)
    };
    let train = model
        .capture
        .split
        .train
        .par_iter()
        .map(|&i| make_view(i, restores))
        .collect::<Result<Vec<_>>>()?;
    // Masks that keep nothing leave nothing to learn: the loss would be 0 and every score
    // perfect. Refused before any work, naming where the masks come from.
    let keeps = |v: &View| {
        v.mask
            .as_deref()
            .is_none_or(|m| m.iter().sum::<f32>() >= 1.0)
    };
    if !train.is_empty() && !train.iter().any(keeps) {
        return Err(TrainError::file(
            &model.capture.root,
            format!(
                "every training view's mask leaves out every pixel (masks from {}): nothing would be learnt; white keeps a pixel, black leaves it out",
                model.capture.mask_source()
            ),
        ));
    }
    let pending = if restores {
        (0..train.len())
            .filter(|&k| train[k].restored.is_none())
            .collect()
    } else {
        Vec::new()
    };
    let test = model
        .capture
        .split
        .test
        .par_iter()
        .map(|&i| make_view(i, false))
        .collect::<Result<Vec<_>>>()?;
    // One camera (or all at one spot) has no radius; 1 keeps the thresholds meaningful.
    let radius = model.capture.normalization().radius as f32;
    let extent = if radius > 0.0 { radius } else { 1.0 };
    let points = model.capture.points.clone();
    Ok(Dataset {
        source: model,
        train,
        test,
        extent,
        points,
        initial: None,
        pending,
        cache: cache.map(Path::to_path_buf),
    })
}
