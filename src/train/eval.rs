//! Held-out evaluation: renders test views and compares them with the clean images, or with
//! the held-out photos themselves when the capture has no clean copies (the standard 3DGS
//! report, which other trainers' figures can be set beside).

use glam::Vec3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use splat::{Gaussians, RenderSettings};

use crate::device::Device;
use crate::error::{Result, TrainError};
use crate::train::data::View;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ViewMetrics {
    pub name: String,
    pub psnr: f64,
    pub ssim: f64,
}

/// What the held-out renders were compared with.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Against {
    /// The capture's `clean/` images (an aberrated capture made by `scene aberrate`).
    #[default]
    Clean,
    /// The held-out photos as the capture holds them.
    Photos,
}

impl std::fmt::Display for Against {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Against::Clean => "the clean images",
            Against::Photos => "the held-out photos",
        })
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Metrics {
    pub views: Vec<ViewMetrics>,
    pub mean_psnr: f64,
    pub mean_ssim: f64,
    /// Metrics files written before photos could be the reference compared with clean images.
    #[serde(default)]
    pub against: Against,
}

/// PSNR and SSIM (the 3DGS SSIM, data range 1) of `image` against `reference`.
pub fn compare(image: &[Vec3], reference: &[Vec3], width: u32, height: u32) -> Result<(f64, f64)> {
    let clamped: Vec<Vec3> = image
        .iter()
        .map(|p| p.clamp(Vec3::ZERO, Vec3::ONE))
        .collect();
    Ok((
        base::psnr_rgb(&clamped, reference)?,
        base::ssim_value(&clamped, reference, width, height)?,
    ))
}

/// What `views` are compared with: their clean images when every one has them, else their
/// photos (None without views).
pub fn reference(views: &[View]) -> Option<Against> {
    if views.is_empty() {
        None
    } else if views.iter().all(|v| v.clean.is_some()) {
        Some(Against::Clean)
    } else {
        Some(Against::Photos)
    }
}

/// Metrics of `model` on `views` against their [`reference`]; `None` without views.
pub fn evaluate(
    model: &Gaussians,
    views: &[View],
    settings: &RenderSettings,
    device: &Device,
) -> Result<Option<Metrics>> {
    let Some(against) = reference(views) else {
        return Ok(None);
    };
    let cameras: Vec<splat::Camera> = views.iter().map(|v| v.camera.clone()).collect();
    let images = device.render_views(model, &cameras, settings)?;
    let per_view = views
        .par_iter()
        .zip(images)
        .map(|(v, out)| {
            let image = out.color;
            let target = match against {
                // `reference` says Clean only when every view has its clean image.
                Against::Clean => v.clean.as_deref().ok_or_else(|| {
                    TrainError::Invalid(format!("held-out view {} has no clean image", v.name))
                })?,
                Against::Photos => &v.observed,
            };
            let (p, s) = compare(&image, target, v.camera.width, v.camera.height)?;
            Ok(ViewMetrics {
                name: v.name.clone(),
                psnr: p,
                ssim: s,
            })
        })
        .collect::<Result<Vec<_>>>()?;
    let n = per_view.len() as f64;
    Ok(Some(Metrics {
        mean_psnr: per_view.iter().map(|v| v.psnr).sum::<f64>() / n,
        mean_ssim: per_view.iter().map(|v| v.ssim).sum::<f64>() / n,
        views: per_view,
        against,
    }))
}
