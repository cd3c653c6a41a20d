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

/// The luma weights of ITU-R BT.601 as the paper's code (BasicSR's `test_y_channel`) applies
/// them to RGB in [0, 1]: `Y = (65.481 R + 128.553 G + 24.966 B + 16) / 255`. The offset
/// cancels in a difference, so only the weights enter a PSNR.
pub const LUMA_BT601: [f64; 3] = [65.481 / 255.0, 128.553 / 255.0, 24.966 / 255.0];

/// PSNR in dB of the luma (Y) channel of two planar RGB images (all red, then green, then
/// blue), data range 1: the figure the paper reports (without its 8-bit rounding and with no
/// border cropped), comparable to ours only this way.
pub fn psnr_y_planar(a: &[f32], b: &[f32]) -> Result<f64, BaseError> {
    check_len(a.len(), b.len())?;
    if !a.len().is_multiple_of(3) {
        return Err(BaseError::SizeMismatch {
            what: "planar RGB image (a multiple of 3 values)",
            expected: a.len() / 3 * 3,
            got: a.len(),
        });
    }
    let n = a.len() / 3;
    let se: f64 = (0..n)
        .map(|i| {
            let d: f64 = (0..3)
                .map(|c| LUMA_BT601[c] * (a[c * n + i] as f64 - b[c * n + i] as f64))
                .sum();
            d * d
        })
        .sum();
    Ok(psnr_from_se(se, n))
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
    let fill = |ch: usize, row: usize, s: &mut [f32]| {
        let px = ch * n + row * w..ch * n + (row + 1) * w;
        stats_row(&a[px.clone()], &b[px], s);
    };
    let total = with_work(|work| ssim_channels(w, h, fill, None, work));
    Ok((total / (3 * n) as f64) as f32 as f64)
}

fn ssim_rgb(a: &[Vec3], b: &[Vec3], w: usize, h: usize, grad: Option<&mut [Vec3]>) -> f32 {
    let inv_count = 1.0 / (3 * w * h) as f32;
    let fill = |ch: usize, row: usize, s: &mut [f32]| {
        let px = row * w..(row + 1) * w;
        stats_rgb_row(&a[px.clone()], &b[px], ch, s)
    };
    let total = with_work(|work| ssim_channels(w, h, fill, grad.map(|g| (g, a, b)), work));
    (total * inv_count as f64) as f32
}

/// Working memory of one SSIM call, kept per thread between calls: fresh multi-megabyte
/// buffers cost page faults comparable to the arithmetic itself.
#[derive(Default)]
struct Work {
    stats: Vec<f32>,
    tmp: Vec<f32>,
    blurred: Vec<f32>,
    rows: Vec<f64>,
    d: Vec<f32>,
}

thread_local! {
    static WORK: std::cell::RefCell<Work> = std::cell::RefCell::new(Work::default());
}

/// Runs `f` with this thread's working memory; a call nested in another on the same thread
/// (rayon may run one inside the other's parallel loop) gets fresh memory.
fn with_work<R>(f: impl FnOnce(&mut Work) -> R) -> R {
    WORK.with(|cell| match cell.try_borrow_mut() {
        Ok(mut s) => f(&mut s),
        Err(_) => f(&mut Work::default()),
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

fn sized_f64(v: &mut Vec<f64>, len: usize) -> &mut [f64] {
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
/// pixel loops vectorise (each lane sums its own output) and rows run in parallel.
fn blur_planes<const P: usize>(
    src: &[f32],
    w: usize,
    h: usize,
    k: &[f32; SSIM_WINDOW],
    tmp: &mut Vec<f32>,
    out: &mut Vec<f32>,
) {
    let stride = P * w;
    let tmp = sized(tmp, h * stride);
    tmp.par_chunks_mut(stride)
        .with_min_len(ROWS_PER_TASK)
        .zip(src.par_chunks(stride))
        .for_each_init(Vec::new, |pad, (t, s)| {
            for p in 0..P {
                blur_row(&s[p * w..(p + 1) * w], &mut t[p * w..(p + 1) * w], k, pad);
            }
        });
    let zeros = vec![0.0f32; stride];
    let tmp = &*tmp;
    sized(out, h * stride)
        .par_chunks_mut(stride)
        .with_min_len(ROWS_PER_TASK)
        .enumerate()
        .for_each(|(y, o)| blur_column(tmp, y, h, o, k, &zeros));
}

crate::simd_builds! {
/// One row of the horizontal pass: `out[x] = Σ_j k[j]·row[x + j − r]`, summed in increasing
/// `j` from zero. Taps that fall outside the row read the zeros of a padded copy; adding
/// `k[j]·0 = +0` leaves every sum as skipping the tap would (a sum started at `+0` is never
/// `−0`), so the bits are those of the direct loops. Each output is summed in a register;
/// compiled for several instruction sets and chosen at run time, with the same arithmetic
/// (separate multiply and add, never fused) in each.
fn blur_row(row: &[f32], out: &mut [f32], k: &[f32; SSIM_WINDOW], pad: &mut Vec<f32>) {
    let (w, r) = (row.len(), SSIM_WINDOW / 2);
    pad.clear();
    pad.resize(r, 0.0);
    pad.extend_from_slice(row);
    pad.resize(w + 2 * r, 0.0);
    for (x, o) in out.iter_mut().enumerate() {
        let win = &pad[x..x + SSIM_WINDOW];
        let mut acc = 0.0f32;
        for j in 0..SSIM_WINDOW {
            acc += k[j] * win[j];
        }
        *o = acc;
    }
}
}

crate::simd_builds! {
/// Output row `y` of the vertical pass over `tmp` (rows of `out.len()` values), as
/// [`blur_row`] does along a row: rows outside the image read `zeros`.
fn blur_column(
    tmp: &[f32],
    y: usize,
    h: usize,
    out: &mut [f32],
    k: &[f32; SSIM_WINDOW],
    zeros: &[f32],
) {
    let (stride, r) = (out.len(), SSIM_WINDOW / 2);
    let rows: [&[f32]; SSIM_WINDOW] =
        std::array::from_fn(|j| match (y + j).checked_sub(r).filter(|&yy| yy < h) {
            Some(yy) => &tmp[yy * stride..(yy + 1) * stride],
            None => &zeros[..stride],
        });
    for (x, o) in out.iter_mut().enumerate() {
        let mut acc = 0.0f32;
        for j in 0..SSIM_WINDOW {
            acc += k[j] * rows[j][x];
        }
        *o = acc;
    }
}
}

/// Planes per channel of the statistics: μx, μy, E[x²], E[y²], E[xy] before blurring.
const STATS: usize = 5;
/// Planes per channel of the map's derivatives: with respect to μx, E[x²], E[xy].
const DERIVS: usize = 3;

/// The three channels' SSIM maps summed (channel by channel, each in pixel order, as the
/// direct loops do) and, with `grad`, the gradient of the mean map with respect to the first
/// image, written into `grad.0` (`grad.1`, `grad.2`: the two images). `fill(ch, row, s)`
/// writes channel `ch`'s statistics of a row, `[plane][x]`. One channel at a time: the
/// working memory of all three at once outgrows the caches and is slower.
fn ssim_channels(
    w: usize,
    h: usize,
    fill: impl Fn(usize, usize, &mut [f32]) + Sync,
    mut grad: Option<(&mut [Vec3], &[Vec3], &[Vec3])>,
    work: &mut Work,
) -> f64 {
    let k = window();
    let inv_count = 1.0 / (3 * w * h) as f32;
    let mut total = 0.0f64;
    for ch in 0..3 {
        sized(&mut work.stats, STATS * w * h)
            .par_chunks_mut(STATS * w)
            .with_min_len(ROWS_PER_TASK)
            .enumerate()
            .for_each(|(row, s)| fill(ch, row, s));
        blur_planes::<STATS>(
            &work.stats[..STATS * w * h],
            w,
            h,
            &k,
            &mut work.tmp,
            &mut work.blurred,
        );
        // The SSIM map, summed per row, and its derivatives with respect to μx, E[x²], E[xy];
        // the rows' sums are added in row order.
        let rows = sized_f64(&mut work.rows, h);
        let d = sized(&mut work.d, DERIVS * w * h);
        rows.par_iter_mut()
            .with_min_len(ROWS_PER_TASK)
            .zip(d.par_chunks_mut(DERIVS * w))
            .zip(work.blurred[..STATS * w * h].par_chunks(STATS * w))
            .for_each_init(Vec::new, |m, ((r, d), b)| {
                m.resize(w, 0.0);
                map_row(b, m, d, inv_count);
                // Apart from the map, whose loop would not vectorise with this sum in it.
                *r = m.iter().map(|&v| v as f64).sum();
            });
        for r in &work.rows[..h] {
            total += *r;
        }
        let Some((grad, x, y)) = grad.as_mut() else {
            continue;
        };
        // The blur is symmetric, so it is its own adjoint (its output reuses the stats' memory).
        blur_planes::<DERIVS>(
            &work.d[..DERIVS * w * h],
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
                let px = row * w..(row + 1) * w;
                let g = &g[row * DERIVS * w..(row + 1) * DERIVS * w];
                grad_rgb_row(g, &x[px.clone()], &y[px], ch, out)
            });
    }
    total
}

crate::simd_builds! {
/// A row of channel `ch`'s five statistics' planes (as [`stats_row`]'s) from interleaved RGB.
fn stats_rgb_row(x: &[Vec3], y: &[Vec3], ch: usize, s: &mut [f32]) {
    let y = &y[..x.len()];
    fill_stats(s, x.len(), |i| (x[i][ch], y[i][ch]));
}
}

crate::simd_builds! {
/// Channel `ch` of a row of the SSIM gradient, interleaved RGB, from the blurred derivatives
/// `g` (planes as [`map_row`]'s `d`).
fn grad_rgb_row(g: &[f32], x: &[Vec3], y: &[Vec3], ch: usize, out: &mut [Vec3]) {
    let w = out.len();
    let (g0, g) = g.split_at(w);
    let (g1, g2) = g.split_at(w);
    for i in 0..w {
        out[i][ch] = g0[i] + 2.0 * x[i][ch] * g1[i] + y[i][ch] * g2[i];
    }
}
}

crate::simd_builds! {
/// A row of the five statistics' planes `[x, y, x², y², xy]` (each `x.len()` long).
fn stats_row(x: &[f32], y: &[f32], s: &mut [f32]) {
    let y = &y[..x.len()];
    fill_stats(s, x.len(), |i| (x[i], y[i]));
}
}

/// The five statistics' planes of `w` pixels whose values `pixel(i)` gives; inlined into each
/// instruction-set build of its callers.
#[inline(always)]
fn fill_stats(s: &mut [f32], w: usize, pixel: impl Fn(usize) -> (f32, f32)) {
    let (sx, s) = s.split_at_mut(w);
    let (sy, s) = s.split_at_mut(w);
    let (sxx, s) = s.split_at_mut(w);
    let (syy, sxy) = s.split_at_mut(w);
    for i in 0..w {
        let (xi, yi) = pixel(i);
        sx[i] = xi;
        sy[i] = yi;
        sxx[i] = xi * xi;
        syy[i] = yi * yi;
        sxy[i] = xi * yi;
    }
}

crate::simd_builds! {
/// A row of the SSIM map `m` and its derivatives `d` (planes: μx, E[x²], E[xy]; scaled by
/// `inv_count`) from the blurred statistics `b` (planes as [`stats_row`]'s).
fn map_row(b: &[f32], m: &mut [f32], d: &mut [f32], inv_count: f32) {
    let w = m.len();
    let (bx, b) = b.split_at(w);
    let (by, b) = b.split_at(w);
    let (bxx, b) = b.split_at(w);
    let (byy, bxy) = b.split_at(w);
    let (d0, d) = d.split_at_mut(w);
    let (d1, d2) = d.split_at_mut(w);
    for i in 0..w {
        let (mx, my) = (bx[i], by[i]);
        let vx = bxx[i] - mx * mx;
        let vy = byy[i] - my * my;
        let cxy = bxy[i] - mx * my;
        let a1 = 2.0 * mx * my + SSIM_C1;
        let a2 = 2.0 * cxy + SSIM_C2;
        let b1 = mx * mx + my * my + SSIM_C1;
        let b2 = vx + vy + SSIM_C2;
        let s = a1 * a2 / (b1 * b2);
        m[i] = s;
        let d_m2 = -s / b2;
        let d_mxy = 2.0 * a1 / (b1 * b2);
        let d_mx = 2.0 * my * (a2 - a1) / (b1 * b2) - 2.0 * mx * s / b1 + 2.0 * mx * s / b2;
        d0[i] = d_mx * inv_count;
        d1[i] = d_m2 * inv_count;
        d2[i] = d_mxy * inv_count;
    }
}
}
