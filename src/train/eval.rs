//! Held-out evaluation: renders test views and compares them with the clean images.

use glam::Vec3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use splat::{Gaussians, RenderSettings};

use crate::device::Device;
use crate::error::Result;
use crate::train::data::View;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ViewMetrics {
    pub name: String,
    pub psnr: f64,
    pub ssim: f64,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Metrics {
    pub views: Vec<ViewMetrics>,
    pub mean_psnr: f64,
    pub mean_ssim: f64,
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

/// Metrics of `model` on `views` against their clean images; `None` when a view has none.
pub fn evaluate(
    model: &Gaussians,
    views: &[View],
    settings: &RenderSettings,
    device: &Device,
) -> Result<Option<Metrics>> {
    if views.is_empty() || views.iter().any(|v| v.clean.is_none()) {
        return Ok(None);
    }
    let cameras: Vec<splat::Camera> = views.iter().map(|v| v.camera.clone()).collect();
    let images = device.render_views(model, &cameras, settings)?;
    let per_view = views
        .par_iter()
        .zip(images)
        .map(|(v, out)| {
            let image = out.color;
            let clean = v.clean.as_deref().expect("checked above");
            let (p, s) = compare(&image, clean, v.camera.width, v.camera.height)?;
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
    }))
}
