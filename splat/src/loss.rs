//! Image losses with analytic gradients: L1, SSIM and the 3DGS mix
//! `(1 − λ) L1 + λ (1 − SSIM)`, λ = 0.2.
//!
//! SSIM follows the INRIA 3DGS code: per channel, an 11×11 Gaussian window (σ = 1.5,
//! normalised to sum 1) applied as a separable "same" convolution with zero padding,
//! `C1 = 0.01²`, `C2 = 0.03²` (data range 1), averaged over all pixels and channels. Images are
//! row-major `width * height` RGB.

use glam::Vec3;

use crate::error::SplatError;

pub const SSIM_WINDOW: usize = 11;
pub const SSIM_SIGMA: f32 = 1.5;
pub const SSIM_C1: f32 = 0.01 * 0.01;
pub const SSIM_C2: f32 = 0.03 * 0.03;
pub const DSSIM_WEIGHT: f32 = 0.2;

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
    let mut value = 0.0f64;
    let grad = rendered
        .iter()
        .zip(target)
        .map(|(r, t)| {
            let d = *r - *t;
            value += d.abs().element_sum() as f64;
            Vec3::new(sign(d.x), sign(d.y), sign(d.z)) * inv
        })
        .collect();
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

fn window() -> [f32; SSIM_WINDOW] {
    let mut w = [0.0f32; SSIM_WINDOW];
    let half = (SSIM_WINDOW / 2) as f32;
    for (k, v) in w.iter_mut().enumerate() {
        let d = k as f32 - half;
        *v = (-(d * d) / (2.0 * SSIM_SIGMA * SSIM_SIGMA)).exp();
    }
    let s: f32 = w.iter().sum();
    w.map(|v| v / s)
}

/// Separable zero-padded "same" convolution; the kernel is symmetric, so this is also its own
/// adjoint, which the backward pass relies on.
fn blur(src: &[f32], w: usize, h: usize, k: &[f32; SSIM_WINDOW], tmp: &mut [f32], dst: &mut [f32]) {
    let r = SSIM_WINDOW / 2;
    for y in 0..h {
        let row = &src[y * w..(y + 1) * w];
        for x in 0..w {
            let lo = x.saturating_sub(r);
            let hi = (x + r).min(w - 1);
            let mut acc = 0.0;
            for xx in lo..=hi {
                acc += k[xx + r - x] * row[xx];
            }
            tmp[y * w + x] = acc;
        }
    }
    for y in 0..h {
        let lo = y.saturating_sub(r);
        let hi = (y + r).min(h - 1);
        for x in 0..w {
            let mut acc = 0.0;
            for yy in lo..=hi {
                acc += k[yy + r - y] * tmp[yy * w + x];
            }
            dst[y * w + x] = acc;
        }
    }
}

/// Mean SSIM of `rendered` against `target` and its gradient with respect to `rendered`.
pub fn ssim(
    rendered: &[Vec3],
    target: &[Vec3],
    width: u32,
    height: u32,
) -> Result<LossGrad, SplatError> {
    check(rendered, target, width, height)?;
    let (w, h) = (width as usize, height as usize);
    let n = w * h;
    let k = window();
    let inv_count = 1.0 / (3 * n) as f32;
    let mut grad = vec![Vec3::ZERO; n];
    let mut total = 0.0f64;
    let mut tmp = vec![0.0f32; n];
    let mut bufs: Vec<Vec<f32>> = (0..5).map(|_| vec![0.0f32; n]).collect();
    let mut planes: Vec<Vec<f32>> = (0..5).map(|_| vec![0.0f32; n]).collect();
    for ch in 0..3 {
        let x: Vec<f32> = rendered.iter().map(|v| v[ch]).collect();
        let y: Vec<f32> = target.iter().map(|v| v[ch]).collect();
        for i in 0..n {
            planes[0][i] = x[i];
            planes[1][i] = y[i];
            planes[2][i] = x[i] * x[i];
            planes[3][i] = y[i] * y[i];
            planes[4][i] = x[i] * y[i];
        }
        for (p, b) in planes.iter().zip(bufs.iter_mut()) {
            blur(p, w, h, &k, &mut tmp, b);
        }
        // Per-pixel derivatives of the SSIM map w.r.t. the blurred statistics μx, E[x²], E[xy],
        // written back into `planes` and then pulled back through the (self-adjoint) blur.
        for i in 0..n {
            let (mx, my) = (bufs[0][i], bufs[1][i]);
            let vx = bufs[2][i] - mx * mx;
            let vy = bufs[3][i] - my * my;
            let cxy = bufs[4][i] - mx * my;
            let a1 = 2.0 * mx * my + SSIM_C1;
            let a2 = 2.0 * cxy + SSIM_C2;
            let b1 = mx * mx + my * my + SSIM_C1;
            let b2 = vx + vy + SSIM_C2;
            let s = a1 * a2 / (b1 * b2);
            total += s as f64;
            let d_m2 = -s / b2;
            let d_mxy = 2.0 * a1 / (b1 * b2);
            let d_mx = 2.0 * my * (a2 - a1) / (b1 * b2) - 2.0 * mx * s / b1 + 2.0 * mx * s / b2;
            planes[0][i] = d_mx * inv_count;
            planes[2][i] = d_m2 * inv_count;
            planes[4][i] = d_mxy * inv_count;
        }
        for p in [0, 2, 4] {
            blur(&planes[p], w, h, &k, &mut tmp, &mut bufs[p]);
        }
        for i in 0..n {
            grad[i][ch] = bufs[0][i] + 2.0 * x[i] * bufs[2][i] + y[i] * bufs[4][i];
        }
    }
    Ok(LossGrad {
        value: (total * inv_count as f64) as f32,
        grad,
    })
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
    let l = l1(rendered, target, width, height)?;
    let s = ssim(rendered, target, width, height)?;
    let grad = l
        .grad
        .iter()
        .zip(&s.grad)
        .map(|(a, b)| *a * (1.0 - dssim_weight) - *b * dssim_weight)
        .collect();
    Ok(PhotometricLoss {
        value: (1.0 - dssim_weight) * l.value + dssim_weight * (1.0 - s.value),
        l1: l.value,
        ssim: s.value,
        grad,
    })
}
