//! Slow, obvious float64 references for the blur, independent of the crate's own layout
//! code: they re-derive tiles, hat weights and reflection from the definitions. Shared by
//! the tests and (through `#[path]`) the benchmark's error measurement.
#![allow(dead_code)]

use aberration::{Image, PsfGrid};

/// Half-sample symmetric reflection.
pub fn reflect(p: i64, n: usize) -> usize {
    let n = n as i64;
    let mut m = p % (2 * n);
    if m < 0 {
        m += 2 * n;
    }
    (if m < n { m } else { 2 * n - 1 - m }) as usize
}

/// Tile index of pixel p: its centre p+0.5 lies in [i·n/g, (i+1)·n/g).
pub fn tile(p: usize, n: usize, g: usize) -> usize {
    let t = (p as f64 + 0.5) * g as f64 / n as f64;
    (t.floor() as usize).min(g - 1)
}

/// Bilinear weight of grid point i at pixel p (p may be outside the image).
pub fn hat(i: usize, p: i64, n: usize, g: usize) -> f64 {
    if g == 1 {
        return 1.0;
    }
    let spacing = n as f64 / g as f64;
    let centres: Vec<f64> = (0..g).map(|j| (j as f64 + 0.5) * spacing).collect();
    let t = p as f64 + 0.5;
    if t <= centres[0] {
        return if i == 0 { 1.0 } else { 0.0 };
    }
    if t >= centres[g - 1] {
        return if i == g - 1 { 1.0 } else { 0.0 };
    }
    let j = ((t - centres[0]) / spacing).floor() as usize;
    let f = (t - centres[j]) / spacing;
    if i == j {
        1.0 - f
    } else if i == j + 1 {
        f
    } else {
        0.0
    }
}

/// Direct evaluation of the blur at one output pixel and channel:
/// `y[p] = Σ_k h_{r}[k]·w_r[q]·x[q]`, `q = p + c − k`, in f64.
pub fn direct_pixel(x: &Image, psf: &PsfGrid, tiled: bool, py: usize, px: usize, ch: usize) -> f64 {
    let kernel = |gi: usize, ch: usize, i: usize| psf.kernel(gi, ch)[i] as f64;
    direct_pixel_with(x, &kernel, psf.grid(), psf.size(), tiled, py, px, ch)
}

/// [`direct_pixel`] through any kernel values `kernel(grid point, channel, index)` (raw f64,
/// not normalised): what a finite difference on one PSF value perturbs.
#[allow(clippy::too_many_arguments)]
pub fn direct_pixel_with(
    x: &Image,
    kernel: &dyn Fn(usize, usize, usize) -> f64,
    g: usize,
    k: usize,
    tiled: bool,
    py: usize,
    px: usize,
    ch: usize,
) -> f64 {
    let (w, h) = (x.width, x.height);
    let c = (k / 2) as i64;
    let mut acc = 0.0;
    for ky in 0..k {
        for kx in 0..k {
            let qy = py as i64 + c - ky as i64;
            let qx = px as i64 + c - kx as i64;
            let v = x.get(reflect(qx, w), reflect(qy, h), ch) as f64;
            if tiled {
                let gi = tile(py, h, g) * g + tile(px, w, g);
                acc += kernel(gi, ch, ky * k + kx) * v;
            } else {
                for i in 0..g {
                    let wy = hat(i, qy, h, g);
                    if wy == 0.0 {
                        continue;
                    }
                    for j in 0..g {
                        let wx = hat(j, qx, w, g);
                        if wx == 0.0 {
                            continue;
                        }
                        acc += kernel(i * g + j, ch, ky * k + kx) * wy * wx * v;
                    }
                }
            }
        }
    }
    acc
}

pub fn direct(x: &Image, psf: &PsfGrid, tiled: bool) -> Vec<f64> {
    let (w, h) = (x.width, x.height);
    let mut out = vec![0.0; 3 * w * h];
    for ch in 0..3 {
        for py in 0..h {
            for px in 0..w {
                out[ch * w * h + py * w + px] = direct_pixel(x, psf, tiled, py, px, ch);
            }
        }
    }
    out
}
