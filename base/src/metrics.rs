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

use rayon::prelude::*;

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

/// [`psnr`] of two RGB images. Training computes one per step, so the squared errors are
/// summed in parallel ([`sum_pairs`]).
pub fn psnr_rgb(a: &[Vec3], b: &[Vec3]) -> Result<f64, BaseError> {
    check_len(a.len(), b.len())?;
    let se = sum_pairs(a, b, |x, y| {
        (0..3).map(|c| (x[c] as f64 - y[c] as f64).powi(2)).sum()
    });
    Ok(psnr_from_se(se, 3 * a.len()))
}

/// `Σ f(a[i], b[i])` over the pairs of two equally long slices, in parallel: fixed chunks of
/// pixels, each summed in order, then the chunks' sums in order, so the value is the same for
/// any thread count.
pub fn sum_pairs<T: Sync>(a: &[T], b: &[T], f: impl Fn(&T, &T) -> f64 + Sync) -> f64 {
    const CHUNK: usize = 4096;
    a.par_chunks(CHUNK)
        .zip(b.par_chunks(CHUNK))
        .map(|(a, b)| a.iter().zip(b).map(|(x, y)| f(x, y)).sum::<f64>())
        .collect::<Vec<f64>>()
        .iter()
        .sum()
}

fn psnr_of(pairs: impl Iterator<Item = (f32, f32)>, count: usize) -> f64 {
    psnr_from_se(
        pairs.map(|(x, y)| (x as f64 - y as f64).powi(2)).sum(),
        count,
    )
}

fn psnr_from_se(se: f64, count: usize) -> f64 {
    -10.0 * (se / count as f64).max(PSNR_MSE_FLOOR).log10()
}

/// Mean SSIM of `a` against `b` (no gradient: what evaluation and loss probes need).
pub fn ssim_value(a: &[Vec3], b: &[Vec3], width: u32, height: u32) -> Result<f64, BaseError> {
    check(a.len(), b.len(), width, height)?;
    Ok(ssim_rgb(a, b, width as usize, height as usize, None) as f64)
}

/// Mean SSIM of `rendered` against `target` and its gradient with respect to `rendered`.
pub fn ssim(
    rendered: &[Vec3],
    target: &[Vec3],
    width: u32,
    height: u32,
) -> Result<(f32, Vec<Vec3>), BaseError> {
    check(rendered.len(), target.len(), width, height)?;
    let mut grad = vec![Vec3::ZERO; rendered.len()];
    let value = ssim_rgb(
        rendered,
        target,
        width as usize,
        height as usize,
        Some(&mut grad),
    );
    Ok((value, grad))
}

/// Mean SSIM of two planar RGB images (all red, then green, then blue; no gradient).
pub fn ssim_planar(a: &[f32], b: &[f32], width: u32, height: u32) -> Result<f64, BaseError> {
    let n = width as usize * height as usize;
    check_len(3 * n, a.len())?;
    check_len(3 * n, b.len())?;
    let (w, h) = (width as usize, height as usize);
    let mut total = 0.0f64;
    with_scratch(n, |s| {
        for ch in 0..3 {
            let c = ch * n..(ch + 1) * n;
            let inv = 1.0 / (3 * n) as f32;
            ssim_channel(
                &a[c.clone()],
                &b[c],
                w,
                h,
                inv,
                &mut total,
                None,
                &mut s.work,
            );
        }
    });
    Ok((total / (3 * n) as f64) as f32 as f64)
}

fn ssim_rgb(a: &[Vec3], b: &[Vec3], w: usize, h: usize, mut grad: Option<&mut [Vec3]>) -> f32 {
    let n = w * h;
    let inv_count = 1.0 / (3 * n) as f32;
    let mut total = 0.0f64;
    with_scratch(n, |s| {
        for ch in 0..3 {
            let (x, y, g) = (&mut s.x[..n], &mut s.y[..n], &mut s.grad[..n]);
            x.par_iter_mut().zip(a).for_each(|(d, v)| *d = v[ch]);
            y.par_iter_mut().zip(b).for_each(|(d, v)| *d = v[ch]);
            let want = grad.is_some().then_some(&mut *g);
            ssim_channel(x, y, w, h, inv_count, &mut total, want, &mut s.work);
            if let Some(out) = grad.as_deref_mut() {
                out.par_iter_mut().zip(&*g).for_each(|(o, v)| o[ch] = *v);
            }
        }
    });
    (total * inv_count as f64) as f32
}

/// Working memory of one SSIM call, kept per thread between calls: fresh multi-megabyte
/// buffers cost page faults comparable to the arithmetic itself.
#[derive(Default)]
struct Scratch {
    x: Vec<f32>,
    y: Vec<f32>,
    grad: Vec<f32>,
    work: Work,
}

#[derive(Default)]
struct Work {
    stats: Vec<f32>,
    tmp: Vec<f32>,
    blurred: Vec<f32>,
    map: Vec<f32>,
    d: Vec<f32>,
}

thread_local! {
    static SCRATCH: std::cell::RefCell<Scratch> = std::cell::RefCell::new(Scratch::default());
}

/// Runs `f` with this thread's scratch grown to `n` pixels; a call nested in another on the
/// same thread (rayon may run one inside the other's parallel loop) gets fresh memory.
fn with_scratch<R>(n: usize, f: impl FnOnce(&mut Scratch) -> R) -> R {
    let grow = |s: &mut Scratch| {
        for v in [&mut s.x, &mut s.y, &mut s.grad] {
            if v.len() < n {
                v.resize(n, 0.0);
            }
        }
    };
    SCRATCH.with(|cell| match cell.try_borrow_mut() {
        Ok(mut s) => {
            grow(&mut s);
            f(&mut s)
        }
        Err(_) => {
            let mut s = Scratch::default();
            grow(&mut s);
            f(&mut s)
        }
    })
}

/// The first `len` values of `v`, grown if needed, holding whatever they held: every caller
/// writes each value before reading it (a serial fill of these buffers was a large part of
/// an SSIM call's serial time).
fn sized(v: &mut Vec<f32>, len: usize) -> &mut [f32] {
    if v.len() < len {
        v.resize(len, 0.0);
    }
    &mut v[..len]
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

/// The normalised Gaussian window.
pub(crate) fn window() -> [f32; SSIM_WINDOW] {
    let mut w = [0.0f32; SSIM_WINDOW];
    let half = (SSIM_WINDOW / 2) as f32;
    for (k, v) in w.iter_mut().enumerate() {
        let d = k as f32 - half;
        *v = (-(d * d) / (2.0 * SSIM_SIGMA * SSIM_SIGMA)).exp();
    }
    let s: f32 = w.iter().sum();
    w.map(|v| v / s)
}

/// Rows of output per parallel task: enough work to pay for the task.
const ROWS_PER_TASK: usize = 8;

/// The zero-padded "same" blur of `P` planes stored row by row (`[row][plane][x]`) into
/// `out`, as two 1-D passes through `tmp`. Each output adds its in-range terms in increasing
/// tap order, exactly as the direct loops do, so the result is bit-identical to them; the
/// loops run over contiguous memory (taps outside, pixels inside), so they vectorise, and
/// rows run in parallel.
fn blur_planes<const P: usize>(
    src: &[f32],
    w: usize,
    h: usize,
    k: &[f32; SSIM_WINDOW],
    tmp: &mut Vec<f32>,
    out: &mut Vec<f32>,
) {
    let r = SSIM_WINDOW / 2;
    let stride = P * w;
    let tmp = sized(tmp, h * stride);
    tmp.par_chunks_mut(stride)
        .with_min_len(ROWS_PER_TASK)
        .zip(src.par_chunks(stride))
        .for_each(|(t, s)| {
            t.fill(0.0);
            for p in 0..P {
                let (row, out) = (&s[p * w..(p + 1) * w], &mut t[p * w..(p + 1) * w]);
                for (j, kj) in k.iter().enumerate() {
                    // Output x reads input x + j − r where that lies in the row.
                    let x0 = r.saturating_sub(j);
                    let x1 = (w + r).saturating_sub(j).min(w);
                    if x0 >= x1 {
                        continue;
                    }
                    let src = &row[x0 + j - r..x1 + j - r];
                    for (o, v) in out[x0..x1].iter_mut().zip(src) {
                        *o += kj * v;
                    }
                }
            }
        });
    let tmp = &*tmp;
    sized(out, h * stride)
        .par_chunks_mut(stride)
        .with_min_len(ROWS_PER_TASK)
        .enumerate()
        .for_each(|(y, o)| {
            o.fill(0.0);
            for (j, kj) in k.iter().enumerate() {
                let Some(yy) = (y + j).checked_sub(r).filter(|&yy| yy < h) else {
                    continue;
                };
                for (o, v) in o.iter_mut().zip(&tmp[yy * stride..(yy + 1) * stride]) {
                    *o += kj * v;
                }
            }
        });
}

/// One channel: adds its SSIM map to `total` (in pixel order) and, with `grad`, writes the
/// gradient of `inv_count · Σ map` with respect to `x`.
#[allow(clippy::too_many_arguments)]
fn ssim_channel(
    x: &[f32],
    y: &[f32],
    w: usize,
    h: usize,
    inv_count: f32,
    total: &mut f64,
    grad: Option<&mut [f32]>,
    work: &mut Work,
) {
    let k = window();
    // μx, μy, E[x²], E[y²], E[xy], blurred in one sweep.
    sized(&mut work.stats, 5 * w * h)
        .par_chunks_mut(5 * w)
        .with_min_len(ROWS_PER_TASK)
        .enumerate()
        .for_each(|(row, s)| {
            let (xr, yr) = (&x[row * w..(row + 1) * w], &y[row * w..(row + 1) * w]);
            for i in 0..w {
                s[i] = xr[i];
                s[w + i] = yr[i];
                s[2 * w + i] = xr[i] * xr[i];
                s[3 * w + i] = yr[i] * yr[i];
                s[4 * w + i] = xr[i] * yr[i];
            }
        });
    blur_planes::<5>(
        &work.stats[..5 * w * h],
        w,
        h,
        &k,
        &mut work.tmp,
        &mut work.blurred,
    );
    // The SSIM map and its derivatives with respect to μx, E[x²], E[xy].
    let map = sized(&mut work.map, w * h);
    let d = sized(&mut work.d, 3 * w * h);
    map.par_chunks_mut(w)
        .with_min_len(ROWS_PER_TASK)
        .zip(d.par_chunks_mut(3 * w))
        .zip(work.blurred[..5 * w * h].par_chunks(5 * w))
        .for_each(|((m, d), b)| {
            for i in 0..w {
                let (mx, my) = (b[i], b[w + i]);
                let vx = b[2 * w + i] - mx * mx;
                let vy = b[3 * w + i] - my * my;
                let cxy = b[4 * w + i] - mx * my;
                let a1 = 2.0 * mx * my + SSIM_C1;
                let a2 = 2.0 * cxy + SSIM_C2;
                let b1 = mx * mx + my * my + SSIM_C1;
                let b2 = vx + vy + SSIM_C2;
                let s = a1 * a2 / (b1 * b2);
                m[i] = s;
                let d_m2 = -s / b2;
                let d_mxy = 2.0 * a1 / (b1 * b2);
                let d_mx = 2.0 * my * (a2 - a1) / (b1 * b2) - 2.0 * mx * s / b1 + 2.0 * mx * s / b2;
                d[i] = d_mx * inv_count;
                d[w + i] = d_m2 * inv_count;
                d[2 * w + i] = d_mxy * inv_count;
            }
        });
    // Summed in pixel order, as the direct loops do.
    for v in &work.map[..w * h] {
        *total += *v as f64;
    }
    let Some(grad) = grad else {
        return;
    };
    // The blur is symmetric, so it is its own adjoint (its output reuses the stats' memory).
    blur_planes::<3>(
        &work.d[..3 * w * h],
        w,
        h,
        &k,
        &mut work.tmp,
        &mut work.stats,
    );
    let g = &work.stats;
    grad.par_chunks_mut(w)
        .with_min_len(ROWS_PER_TASK)
        .enumerate()
        .for_each(|(row, out)| {
            let g = &g[row * 3 * w..(row + 1) * 3 * w];
            for i in 0..w {
                let p = row * w + i;
                out[i] = g[i] + 2.0 * x[p] * g[w + i] + y[p] * g[2 * w + i];
            }
        });
}
