//! Image metrics, one convention each, used by training losses, evaluation and the restorer.
//!
//! - PSNR: data range 1, MSE over every value of both images, capped at 100 dB (an MSE of
//!   1e-10) so identical images give a finite number.
//! - SSIM: the INRIA 3DGS definition: per channel, an 11×11 Gaussian window (σ = 1.5,
//!   normalised to sum 1) applied as a separable "same" convolution with zero padding,
//!   `C1 = 0.01²`, `C2 = 0.03²` (data range 1), averaged over all pixels and channels. Images
//!   are row-major `width * height` RGB. [`ssim`] also returns the gradient, for losses.
//!
//! Sizes that do not match are errors, never panics.

use glam::Vec3;

use crate::error::BaseError;

pub const SSIM_WINDOW: usize = 11;
pub const SSIM_SIGMA: f32 = 1.5;
pub const SSIM_C1: f32 = 0.01 * 0.01;
pub const SSIM_C2: f32 = 0.03 * 0.03;
/// MSE floor of [`psnr`]: 100 dB.
pub const PSNR_MSE_FLOOR: f64 = 1e-10;

fn check_len(a: usize, b: usize) -> Result<(), BaseError> {
    if a != b {
        return Err(BaseError::SizeMismatch {
            what: "second image",
            expected: a,
            got: b,
        });
    }
    if a == 0 {
        return Err(BaseError::Empty("image"));
    }
    Ok(())
}

/// PSNR in dB of `a` against `b`, over all values (any layout, the same for both).
pub fn psnr(a: &[f32], b: &[f32]) -> Result<f64, BaseError> {
    check_len(a.len(), b.len())?;
    Ok(psnr_of(a.iter().zip(b).map(|(x, y)| (*x, *y)), a.len()))
}

/// [`psnr`] of two RGB images.
pub fn psnr_rgb(a: &[Vec3], b: &[Vec3]) -> Result<f64, BaseError> {
    check_len(a.len(), b.len())?;
    let pairs = a
        .iter()
        .zip(b)
        .flat_map(|(x, y)| (0..3).map(move |c| (x[c], y[c])));
    Ok(psnr_of(pairs, 3 * a.len()))
}

fn psnr_of(pairs: impl Iterator<Item = (f32, f32)>, count: usize) -> f64 {
    let se: f64 = pairs.map(|(x, y)| (x as f64 - y as f64).powi(2)).sum();
    -10.0 * (se / count as f64).max(PSNR_MSE_FLOOR).log10()
}

/// Mean SSIM of `a` against `b` (no gradient).
pub fn ssim_value(a: &[Vec3], b: &[Vec3], width: u32, height: u32) -> Result<f64, BaseError> {
    Ok(ssim_rgb(a, b, width, height, None)? as f64)
}

fn ssim_rgb(
    a: &[Vec3],
    b: &[Vec3],
    width: u32,
    height: u32,
    grad: Option<GradSink<'_>>,
) -> Result<f32, BaseError> {
    check(a.len(), b.len(), width, height)?;
    let plane = |img: &[Vec3], ch: usize| img.iter().map(|v| v[ch]).collect::<Vec<f32>>();
    let (w, h) = (width as usize, height as usize);
    Ok(ssim_channels(w, h, |ch| (plane(a, ch), plane(b, ch)), grad))
}

fn check(rendered: usize, target: usize, width: u32, height: u32) -> Result<(), BaseError> {
    let n = width as usize * height as usize;
    for (what, len) in [("rendered", rendered), ("target", target)] {
        if len != n {
            return Err(BaseError::SizeMismatch {
                what,
                expected: n,
                got: len,
            });
        }
    }
    if n == 0 {
        return Err(BaseError::Empty("image"));
    }
    Ok(())
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
) -> Result<(f32, Vec<Vec3>), BaseError> {
    let mut grad = vec![Vec3::ZERO; rendered.len()];
    let value = ssim_rgb(
        rendered,
        target,
        width,
        height,
        Some(&mut |i, ch, g| grad[i][ch] = g),
    )?;
    Ok((value, grad))
}

/// Mean SSIM of two planar RGB images (all red, then green, then blue; no gradient).
pub fn ssim_planar(a: &[f32], b: &[f32], width: u32, height: u32) -> Result<f64, BaseError> {
    let n = width as usize * height as usize;
    check_len(3 * n, a.len())?;
    check_len(3 * n, b.len())?;
    let plane = |img: &[f32], ch: usize| img[ch * n..(ch + 1) * n].to_vec();
    let (w, h) = (width as usize, height as usize);
    Ok(ssim_channels(w, h, |ch| (plane(a, ch), plane(b, ch)), None) as f64)
}

/// Per-pixel gradient sink: `(pixel, channel, ∂SSIM/∂x)`.
type GradSink<'a> = &'a mut dyn FnMut(usize, usize, f32);

/// The SSIM of three channel pairs, and with `grad` its gradient with respect to the first.
fn ssim_channels(
    w: usize,
    h: usize,
    channel: impl Fn(usize) -> (Vec<f32>, Vec<f32>),
    mut grad: Option<GradSink<'_>>,
) -> f32 {
    let n = w * h;
    let k = window();
    let inv_count = 1.0 / (3 * n) as f32;
    let mut total = 0.0f64;
    let mut tmp = vec![0.0f32; n];
    let mut bufs: Vec<Vec<f32>> = (0..5).map(|_| vec![0.0f32; n]).collect();
    let mut planes: Vec<Vec<f32>> = (0..5).map(|_| vec![0.0f32; n]).collect();
    for ch in 0..3 {
        let (x, y) = channel(ch);
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
        let Some(sink) = grad.as_mut() else {
            continue;
        };
        for p in [0, 2, 4] {
            blur(&planes[p], w, h, &k, &mut tmp, &mut bufs[p]);
        }
        for i in 0..n {
            sink(
                i,
                ch,
                bufs[0][i] + 2.0 * x[i] * bufs[2][i] + y[i] * bufs[4][i],
            );
        }
    }
    (total * inv_count as f64) as f32
}
