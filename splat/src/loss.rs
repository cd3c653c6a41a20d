//! Image losses with analytic gradients: L1, SSIM and the 3DGS mix
//! `(1 − λ) L1 + λ (1 − SSIM)` (λ = 0.2 in 3DGS). SSIM is [`base::metrics`]'s, the same one
//! evaluation reports. Images are row-major `width * height` RGB.

use glam::Vec3;
use rayon::prelude::*;

use crate::error::SplatError;

/// A loss value and its gradient with respect to the rendered image.
#[derive(Clone, Debug)]
pub struct LossGrad {
    pub value: f32,
    pub grad: Vec<Vec3>,
}

fn check(rendered: &[Vec3], target: &[Vec3], width: u32, height: u32) -> Result<(), SplatError> {
    let n = width as usize * height as usize;
    for (what, img) in [("rendered", rendered), ("target", target)] {
        if img.len() != n {
            return Err(SplatError::SizeMismatch {
                what,
                expected: n,
                got: img.len(),
            });
        }
    }
    if n == 0 {
        return Err(SplatError::InvalidInput("empty image".into()));
    }
    Ok(())
}

/// Mean absolute error over pixels and channels; the gradient at a tie is 0.
pub fn l1(
    rendered: &[Vec3],
    target: &[Vec3],
    width: u32,
    height: u32,
) -> Result<LossGrad, SplatError> {
    check(rendered, target, width, height)?;
    let inv = 1.0 / (3 * rendered.len()) as f32;
    let grad = rendered
        .par_iter()
        .zip(target)
        .map(|(r, t)| {
            let d = *r - *t;
            Vec3::new(sign(d.x), sign(d.y), sign(d.z)) * inv
        })
        .collect();
    let value = base::sum_pairs(rendered, target, |r, t| {
        (*r - *t).abs().element_sum() as f64
    });
    Ok(LossGrad {
        value: (value * inv as f64) as f32,
        grad,
    })
}

fn sign(v: f32) -> f32 {
    if v > 0.0 {
        1.0
    } else if v < 0.0 {
        -1.0
    } else {
        0.0
    }
}

/// Mean SSIM of `rendered` against `target` and its gradient with respect to `rendered`
/// (the one SSIM of metasplat, [`base::metrics`]).
pub fn ssim(
    rendered: &[Vec3],
    target: &[Vec3],
    width: u32,
    height: u32,
) -> Result<LossGrad, SplatError> {
    check(rendered, target, width, height)?;
    let (value, grad) = base::ssim(rendered, target, width, height)?;
    Ok(LossGrad { value, grad })
}

/// The 3DGS photometric loss and its parts.
#[derive(Clone, Debug)]
pub struct PhotometricLoss {
    pub value: f32,
    pub l1: f32,
    pub ssim: f32,
    pub grad: Vec<Vec3>,
}

/// `(1 − λ) L1 + λ (1 − SSIM)` with `λ = dssim_weight` (0.2 in 3DGS).
pub fn photometric_loss(
    rendered: &[Vec3],
    target: &[Vec3],
    width: u32,
    height: u32,
    dssim_weight: f32,
) -> Result<PhotometricLoss, SplatError> {
    check(rendered, target, width, height)?;
    let inv = 1.0 / (3 * rendered.len()) as f32;
    let l1 = base::sum_pairs(rendered, target, |r, t| {
        (*r - *t).abs().element_sum() as f64
    });
    let l1 = (l1 * inv as f64) as f32;
    let s = ssim(rendered, target, width, height)?;
    // The L1 gradient (as `l1` gives it) mixed into the SSIM gradient's own buffer: the same
    // arithmetic as mixing two gradient images, without making them.
    let mut grad = s.grad;
    grad.par_iter_mut()
        .zip(rendered)
        .zip(target)
        .for_each(|((g, r), t)| {
            let d = *r - *t;
            let a = Vec3::new(sign(d.x), sign(d.y), sign(d.z)) * inv;
            *g = a * (1.0 - dssim_weight) - *g * dssim_weight;
        });
    Ok(PhotometricLoss {
        value: (1.0 - dssim_weight) * l1 + dssim_weight * (1.0 - s.value),
        l1,
        ssim: s.value,
        grad,
    })
}

/// The value of [`photometric_loss`] alone, with the same arithmetic (so the same bits),
/// without the SSIM backward: for evaluation and probes that read only the number.
pub fn photometric_value(
    rendered: &[Vec3],
    target: &[Vec3],
    width: u32,
    height: u32,
    dssim_weight: f32,
) -> Result<f32, SplatError> {
    check(rendered, target, width, height)?;
    let inv = 1.0 / (3 * rendered.len()) as f32;
    let mut sum = 0.0f64;
    for (r, t) in rendered.iter().zip(target) {
        sum += (*r - *t).abs().element_sum() as f64;
    }
    let l1 = (sum * inv as f64) as f32;
    let ssim = base::ssim_value(rendered, target, width, height)? as f32;
    Ok((1.0 - dssim_weight) * l1 + dssim_weight * (1.0 - ssim))
}
