//! The per-view loss of each mode and its gradient with respect to the rendered image.
//!
//! `aware`: `L_GS(PSF ⊛ r, I_abr) + λ·L_GS(r, I_ac)`; the first term's gradient reaches `r`
//! through the blur's exact adjoint (`aberration::BlurPlan::adjoint`).

use aberration::ImagingModel;
use glam::Vec3;
use rayon::prelude::*;
use splat::loss::photometric_loss;

use crate::error::{Result, TrainError};
use crate::settings::Mode;
use crate::train::data::View;

/// Loss parts of one view.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LossParts {
    pub total: f32,
    /// The term against the observed images (`L_abr` in aware mode, or the only term).
    pub main: f32,
    /// `L_GS(render, I_ac)` in aware mode.
    pub restored: Option<f32>,
    /// PSNR of what the main term compares (e.g. the re-blurred render) to its target.
    pub psnr: f64,
}

#[derive(Clone, Copy)]
pub struct Objective<'a> {
    pub mode: Mode,
    pub lambda: f32,
    pub dssim_weight: f32,
    pub imaging: Option<&'a ImagingModel>,
    pub width: u32,
    pub height: u32,
}

impl Objective<'_> {
    fn term(&self, image: &[Vec3], target: &[Vec3]) -> Result<(f32, Vec<Vec3>, f64)> {
        let (v, g) = self.term_without_psnr(image, target)?;
        Ok((v, g, base::psnr_rgb(image, target)?))
    }

    /// The loss and its gradient, for a term whose PSNR nothing reports.
    fn term_without_psnr(&self, image: &[Vec3], target: &[Vec3]) -> Result<(f32, Vec<Vec3>)> {
        let l = photometric_loss(image, target, self.width, self.height, self.dssim_weight)?;
        Ok((l.value, l.grad))
    }

    fn blur(&self) -> Result<&ImagingModel> {
        self.imaging
            .ok_or_else(|| TrainError::Invalid("aware mode without an imaging model".into()))
    }

    /// The image the main term compares with the observation: the render itself, or in aware
    /// mode the render as the metalens would have recorded it (without noise).
    pub fn as_observed(&self, rendered: &[Vec3]) -> Result<Vec<Vec3>> {
        if self.mode != Mode::Aware {
            return Ok(rendered.to_vec());
        }
        Ok(self.blur()?.blur_pixels(rendered)?)
    }

    /// The loss alone (what the SH-band probes read): the same value as [`Self::evaluate`]'s
    /// total, without the SSIM backward or the blur's adjoint.
    pub fn value(&self, rendered: &[Vec3], view: &View) -> Result<f32> {
        let term = |image: &[Vec3], target: &[Vec3]| -> Result<f32> {
            Ok(splat::loss::photometric_value(
                image,
                target,
                self.width,
                self.height,
                self.dssim_weight,
            )?)
        };
        let restored = || {
            view.restored.as_deref().ok_or_else(|| {
                TrainError::Invalid(format!("view {} has no restored image", view.name))
            })
        };
        match self.mode {
            Mode::Plain => term(rendered, &view.observed),
            Mode::Restored => term(rendered, restored()?),
            Mode::Aware => {
                let v_abr = term(&self.as_observed(rendered)?, &view.observed)?;
                let v_ac = if self.lambda != 0.0 {
                    term(rendered, restored()?)?
                } else {
                    0.0
                };
                Ok(v_abr + self.lambda * v_ac)
            }
        }
    }

    /// Loss and `∂loss/∂rendered`. Its stages are `tracing` spans ("PSF blur", "loss", "blur
    /// adjoint"), which `metasplat bench step` times.
    pub fn evaluate(&self, rendered: &[Vec3], view: &View) -> Result<(LossParts, Vec<Vec3>)> {
        let restored = || {
            view.restored.as_deref().ok_or_else(|| {
                TrainError::Invalid(format!("view {} has no restored image", view.name))
            })
        };
        match self.mode {
            Mode::Plain | Mode::Restored => {
                let target = match self.mode {
                    Mode::Plain => view.observed.as_slice(),
                    _ => restored()?,
                };
                let (v, g, p) =
                    tracing::info_span!("loss").in_scope(|| self.term(rendered, target))?;
                Ok((
                    LossParts {
                        total: v,
                        main: v,
                        restored: None,
                        psnr: p,
                    },
                    g,
                ))
            }
            Mode::Aware => {
                let blurred =
                    tracing::info_span!("PSF blur").in_scope(|| self.as_observed(rendered))?;
                let (v_abr, g_blurred, p) =
                    tracing::info_span!("loss").in_scope(|| self.term(&blurred, &view.observed))?;
                let g_abr = tracing::info_span!("blur adjoint").in_scope(|| -> Result<_> {
                    Ok(self.blur()?.plan().adjoint_pixels(&g_blurred)?)
                })?;
                let (v_ac, g_ac) = tracing::info_span!("loss").in_scope(|| {
                    if self.lambda != 0.0 {
                        self.term_without_psnr(rendered, restored()?)
                    } else {
                        Ok((0.0, vec![Vec3::ZERO; rendered.len()]))
                    }
                })?;
                let mut grad = g_abr;
                tracing::info_span!("blur adjoint").in_scope(|| {
                    grad.par_iter_mut()
                        .zip(&g_ac)
                        .for_each(|(a, b)| *a += *b * self.lambda)
                });
                let parts = LossParts {
                    total: v_abr + self.lambda * v_ac,
                    main: v_abr,
                    restored: Some(v_ac),
                    psnr: p,
                };
                Ok((parts, grad))
            }
        }
    }
}
