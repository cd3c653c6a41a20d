//! Held-out evaluation: renders test views and compares them with the clean images, or with
//! the held-out photos themselves when the capture has no clean copies (the standard 3DGS
//! report, which other trainers' figures can be set beside).

use glam::Vec3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use splat::{Gaussians, RenderSettings};

use crate::error::{Result, TrainError};
use crate::settings::MaskUse;
use crate::splats::device::Device;
use crate::train::data::View;
use crate::train::object::{over, psnr_in_mask};
use std::borrow::Cow;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ViewMetrics {
    pub name: String,
    pub psnr: f64,
    pub ssim: f64,
    /// PSNR over the pixels the view's object mask keeps (a run scored on the object).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub psnr_in_mask: Option<f64>,
}

/// How a run on an object's masks was scored: the reference composited over the run's
/// background outside each mask, and the render as drawn (`object`: what it shows outside
/// the object counts against it) or composited the same way (`loss`: it learnt nothing
/// there); beside it, PSNR inside the masks alone.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct OnObject {
    pub masks: MaskUse,
    pub background: [f32; 3],
    pub mean_psnr_in_mask: f64,
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
    /// Scored on the object (a capture with object masks); None: on the whole images.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub on_object: Option<OnObject>,
    /// PSNR over the pixels the held-out views' loss masks keep (undistortion's border, the
    /// photos' alpha), which alone their references hold.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub sourced_pixels: bool,
}

/// What a held-out view is scored on ([`scored`]).
pub struct Scored<'v> {
    pub image: Cow<'v, [Vec3]>,
    pub reference: Cow<'v, [Vec3]>,
    /// The object's mask, for PSNR inside it; None: scored whole.
    pub mask: Option<&'v [f32]>,
    /// Without object masks, the view's loss mask (the pixels undistortion left a source for,
    /// the photo's alpha): its PSNR is over those pixels alone, which the reference holds.
    pub sourced: Option<&'v [f32]>,
}

impl Scored<'_> {
    /// PSNR and SSIM ([`compare`]); where [`Self::sourced`] says, PSNR over the pixels it
    /// keeps, and SSIM of both composited over black outside them (equal there).
    pub fn compare(&self, width: u32, height: u32) -> Result<(f64, f64)> {
        let Some(m) = self.sourced else {
            return compare(&self.image, &self.reference, width, height);
        };
        let (p, s) = compare(
            &over(&self.image, m, Vec3::ZERO),
            &over(&self.reference, m, Vec3::ZERO),
            width,
            height,
        )?;
        let p = psnr_in_mask(&clamp01(&self.image), &self.reference, m).unwrap_or(p);
        Ok((p, s))
    }

    /// PSNR inside the object's mask ([`Self::mask`]); None without one, or when it keeps no
    /// pixel.
    pub fn psnr_in_mask(&self) -> Option<f64> {
        psnr_in_mask(&clamp01(&self.image), &self.reference, self.mask?)
    }
}

/// The mean of `values`; None without any.
pub fn mean(values: &[f64]) -> Option<f64> {
    (!values.is_empty()).then(|| values.iter().sum::<f64>() / values.len() as f64)
}

/// What a held-out view is scored on: the image and reference composited over `background`
/// outside an object's mask as [`OnObject`] says; without object masks, a view's loss mask
/// composites both alike and its PSNR counts only the pixels it keeps (a reference has
/// nothing where undistortion left no source); unchanged without a mask.
pub fn scored<'v>(
    image: &'v [Vec3],
    reference: &'v [Vec3],
    mask: Option<&'v [f32]>,
    masks: Option<MaskUse>,
    background: Vec3,
) -> Scored<'v> {
    match (masks, mask) {
        (Some(use_), Some(m)) => Scored {
            image: match use_ {
                MaskUse::Object => Cow::Borrowed(image),
                MaskUse::Loss => Cow::Owned(over(image, m, background)),
            },
            reference: Cow::Owned(over(reference, m, background)),
            mask: Some(m),
            sourced: None,
        },
        (None, Some(m)) => Scored {
            image: Cow::Borrowed(image),
            reference: Cow::Borrowed(reference),
            mask: None,
            sourced: Some(m),
        },
        _ => Scored {
            image: Cow::Borrowed(image),
            reference: Cow::Borrowed(reference),
            mask: None,
            sourced: None,
        },
    }
}

/// PSNR and SSIM (the 3DGS SSIM, data range 1) of `image` against `reference`.
pub fn compare(image: &[Vec3], reference: &[Vec3], width: u32, height: u32) -> Result<(f64, f64)> {
    let clamped = clamp01(image);
    Ok((
        base::psnr_rgb(&clamped, reference)?,
        base::ssim_value(&clamped, reference, width, height)?,
    ))
}

fn clamp01(image: &[Vec3]) -> Vec<Vec3> {
    image
        .iter()
        .map(|p| p.clamp(Vec3::ZERO, Vec3::ONE))
        .collect()
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

/// Metrics of `model` on `views` against their [`reference`], on the object when `masks`
/// says the views' masks are an object's; `None` without views.
pub fn evaluate(
    model: &Gaussians,
    views: &[View],
    settings: &RenderSettings,
    device: &Device,
    masks: Option<MaskUse>,
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
            let sc = scored(
                &image,
                target,
                v.mask.as_deref(),
                masks,
                settings.background,
            );
            let (p, s) = sc.compare(v.camera.width, v.camera.height)?;
            Ok(ViewMetrics {
                name: v.name.clone(),
                psnr: p,
                ssim: s,
                psnr_in_mask: sc.psnr_in_mask(),
            })
        })
        .collect::<Result<Vec<_>>>()?;
    let n = per_view.len() as f64;
    let in_mask: Vec<f64> = per_view.iter().filter_map(|v| v.psnr_in_mask).collect();
    let on_object = masks.zip(mean(&in_mask)).map(|(masks, m)| OnObject {
        masks,
        background: settings.background.to_array(),
        mean_psnr_in_mask: m,
    });
    Ok(Some(Metrics {
        sourced_pixels: masks.is_none() && views.iter().any(|v| v.mask.is_some()),
        on_object,
        mean_psnr: per_view.iter().map(|v| v.psnr).sum::<f64>() / n,
        mean_ssim: per_view.iter().map(|v| v.ssim).sum::<f64>() / n,
        views: per_view,
        against,
    }))
}
