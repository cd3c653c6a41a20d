//! The training data of a run: every view's camera and images (observed, restored, clean),
//! the imaging model the capture was made with, and the initial point cloud, loaded from a
//! [`CaptureModel`].

use std::path::Path;

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
    /// Training views whose `I_ac` was computed (not found in the cache), with their cache
    /// keys: [`Dataset::cache_restored`] stores them.
    pub restored_fresh: Vec<(usize, u64)>,
}

impl std::ops::Deref for Dataset {
    type Target = CaptureModel;

    fn deref(&self) -> &CaptureModel {
        &self.source
    }
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

    /// What held-out evaluation compares with (None: no held-out views).
    pub fn evaluated_against(&self) -> Option<crate::train::eval::Against> {
        crate::train::eval::reference(&self.test)
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
        restored_fresh,
    })
}
