//! The per-view loss of each mode and its gradient with respect to the rendered image.
//!
//! `aware`: `L_GS(PSF ⊛ r, I_abr) + λ·L_GS(r, I_ac)`; the first term's gradient reaches `r`
//! through the blur's exact adjoint (`aberration::BlurPlan::adjoint`).

use std::borrow::Cow;

use aberration::ImagingModel;
use glam::Vec3;
use rayon::prelude::*;
use splat::loss::photometric_loss;

use crate::error::{Result, TrainError};
use crate::settings::Mode;
use crate::train::config::TrainConfig;
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
    /// In aware mode with `loss` masks on a copy that `scene aberrate` composited over this
    /// colour before the blur (undistortion's border): what the lens saw outside each mask.
    /// The render is composited over it there before the blur, so `PSF ⊛ render` models the
    /// observation exactly and the pixels the loss leaves out, which nothing else constrains,
    /// do not bleed into the ones it keeps. None: the render is blurred as it is.
    pub outside: Option<Vec3>,
}

/// [`Objective::outside`] for a run with `config` on a copy composited over `composited_over`
/// (`aberration.json`) before the blur: that colour in aware mode, unless the masks are an
/// object's in `object` mode, whose runs make their own targets (`ObjectTargets`); every
/// other mask (undistortion's border, `--mask-mode loss`) leaves pixels out of the loss.
pub fn outside_colour(config: &TrainConfig, composited_over: Option<[f32; 3]>) -> Option<Vec3> {
    let loss_masks = config.masks != Some(crate::settings::MaskUse::Object);
    (config.mode == Mode::Aware && loss_masks)
        .then(|| composited_over.map(Vec3::from_array))
        .flatten()
}

/// `image` with the pixels a mask leaves out taken from `target` (a soft mask blends), so they
/// add nothing to the loss: `m·image + (1 − m)·target`. Its gradient with respect to `image`
/// is the mask itself, which [`Objective`] multiplies in.
pub fn composite(image: &[Vec3], target: &[Vec3], mask: &[f32]) -> Vec<Vec3> {
    image
        .iter()
        .zip(target)
        .zip(mask)
        .map(|((i, t), m)| *i * *m + *t * (1.0 - *m))
        .collect()
}

impl Objective<'_> {
    fn term(
        &self,
        image: &[Vec3],
        target: &[Vec3],
        mask: Option<&[f32]>,
    ) -> Result<(f32, Vec<Vec3>, f64)> {
        let (v, g) = self.term_without_psnr(image, target, mask)?;
        let psnr = match mask {
            Some(m) => base::psnr_rgb(&composite(image, target, m), target)?,
            None => base::psnr_rgb(image, target)?,
        };
        Ok((v, g, psnr))
    }

    /// The loss and its gradient, for a term whose PSNR nothing reports; masked pixels (see
    /// [`composite`]) neither count nor get a gradient.
    fn term_without_psnr(
        &self,
        image: &[Vec3],
        target: &[Vec3],
        mask: Option<&[f32]>,
    ) -> Result<(f32, Vec<Vec3>)> {
        let Some(m) = mask else {
            let l = photometric_loss(image, target, self.width, self.height, self.dssim_weight)?;
            return Ok((l.value, l.grad));
        };
        let shown = composite(image, target, m);
        let l = photometric_loss(&shown, target, self.width, self.height, self.dssim_weight)?;
        let grad = l.grad.iter().zip(m).map(|(g, w)| *g * *w).collect();
        Ok((l.value, grad))
    }

    fn blur(&self) -> Result<&ImagingModel> {
        self.imaging
            .ok_or_else(|| TrainError::Invalid("aware mode without an imaging model".into()))
    }

    /// What the lens sees of `rendered` for a view with `mask`: the render, over
    /// [`Self::outside`] where the mask leaves pixels out.
    fn lens_input<'r>(&self, rendered: &'r [Vec3], mask: Option<&[f32]>) -> Cow<'r, [Vec3]> {
        crate::train::object::lens_input(rendered, mask, self.outside)
    }

    /// The image the main term compares with the observation of a view with `mask`: the
    /// render itself, or in aware mode the render as the metalens would have recorded it
    /// (without noise).
    pub fn as_observed(&self, rendered: &[Vec3], mask: Option<&[f32]>) -> Result<Vec<Vec3>> {
        if self.mode != Mode::Aware {
            return Ok(rendered.to_vec());
        }
        Ok(self.blur()?.blur_pixels(&self.lens_input(rendered, mask))?)
    }

    /// The loss alone (what the SH-band probes read): the same value as [`Self::evaluate`]'s
    /// total, without the SSIM backward or the blur's adjoint.
    pub fn value(&self, rendered: &[Vec3], view: &View) -> Result<f32> {
        let mask = view.mask.as_deref();
        let term = |image: &[Vec3], target: &[Vec3]| -> Result<f32> {
            let shown;
            let image = match mask {
                Some(m) => {
                    shown = composite(image, target, m);
                    &shown
                }
                None => image,
            };
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
                let v_abr = term(&self.as_observed(rendered, mask)?, &view.observed)?;
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
        let (parts, grad, _) = self.evaluate_with_psf(rendered, view, false)?;
        Ok((parts, grad))
    }

    /// [`Self::evaluate`], with (when `psf_gradient` and in aware mode) `∂loss/∂PSF` too, in
    /// the layout of [`aberration::PsfGrid::planar`] at the image's scale: only `L_abr` sees
    /// the PSF. Its stage is the span "PSF gradient".
    pub fn evaluate_with_psf(
        &self,
        rendered: &[Vec3],
        view: &View,
        psf_gradient: bool,
    ) -> Result<(LossParts, Vec<Vec3>, Option<Vec<f32>>)> {
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
                let (v, g, p) = tracing::info_span!("loss")
                    .in_scope(|| self.term(rendered, target, view.mask.as_deref()))?;
                Ok((
                    LossParts {
                        total: v,
                        main: v,
                        restored: None,
                        psnr: p,
                    },
                    g,
                    None,
                ))
            }
            Mode::Aware => {
                let mask = view.mask.as_deref();
                let seen = self.lens_input(rendered, mask);
                let blurred = tracing::info_span!("PSF blur")
                    .in_scope(|| -> Result<_> { Ok(self.blur()?.blur_pixels(&seen)?) })?;
                let (v_abr, g_blurred, p) = tracing::info_span!("loss")
                    .in_scope(|| self.term(&blurred, &view.observed, mask))?;
                let g_abr = tracing::info_span!("blur adjoint").in_scope(|| -> Result<_> {
                    let mut g = self.blur()?.plan().adjoint_pixels(&g_blurred)?;
                    // Outside the mask the lens saw the constant, not the render.
                    if let Some((_, m)) = self.outside.zip(mask) {
                        g.iter_mut().zip(m).for_each(|(g, w)| *g *= *w);
                    }
                    Ok(g)
                })?;
                let g_psf = if psf_gradient {
                    Some(
                        tracing::info_span!("PSF gradient").in_scope(|| -> Result<_> {
                            Ok(self.blur()?.plan().psf_gradient_pixels(&seen, &g_blurred)?)
                        })?,
                    )
                } else {
                    None
                };
                let (v_ac, g_ac) = tracing::info_span!("loss").in_scope(|| {
                    if self.lambda != 0.0 {
                        self.term_without_psnr(rendered, restored()?, view.mask.as_deref())
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
                Ok((parts, grad, g_psf))
            }
        }
    }
}
