//! Where each grid PSF acts on an image: tiles, bilinear weights and boundary padding.
//!
//! Along an axis of `n` pixels with `g` grid points, grid point `i` owns the pixels whose
//! centres (`p + 0.5`) fall in `[i·n/g, (i+1)·n/g)` (its tile) and sits at the tile centre
//! `(i + 0.5)·n/g`. Blend weights are hat functions between neighbouring centres, held at 1
//! beyond the outermost centres, so they sum to one everywhere (padding included).

use std::ops::Range;

use rayon::prelude::*;

#[derive(Clone, Copy, Debug)]
pub struct AxisLayout {
    pub n: usize,
    pub g: usize,
}

impl AxisLayout {
    pub fn tile_of(&self, p: usize) -> usize {
        ((2 * p + 1) * self.g / (2 * self.n)).min(self.g - 1)
    }

    /// Pixels of tile `i` (may be empty when the image is smaller than the grid).
    pub fn tile(&self, i: usize) -> Range<usize> {
        // First pixel p with tile_of(p) >= i, i.e. the least p with (2p+1)·g >= 2·i·n.
        let first = |i: usize| ((2 * i * self.n).div_ceil(self.g) / 2).min(self.n);
        let a = first(i);
        let b = if i + 1 == self.g {
            self.n
        } else {
            first(i + 1)
        };
        a..b.max(a)
    }

    pub fn centre(&self, i: usize) -> f64 {
        (i as f64 + 0.5) * self.n as f64 / self.g as f64
    }

    /// Blend weight of grid point `i` at pixel `p` (may be outside the image).
    pub fn hat(&self, i: usize, p: isize) -> f64 {
        if self.g == 1 {
            return 1.0;
        }
        let t = p as f64 + 0.5;
        let c = self.centre(i);
        if (i == 0 && t <= c) || (i + 1 == self.g && t >= c) {
            return 1.0;
        }
        let spacing = self.n as f64 / self.g as f64;
        (1.0 - (t - c).abs() / spacing).max(0.0)
    }

    /// Pixels in `[lo, hi)` where the hat of `i` is non-zero.
    pub fn hat_support(&self, i: usize, lo: isize, hi: isize) -> Range<isize> {
        let mut first = None;
        let mut last = lo;
        for p in lo..hi {
            if self.hat(i, p) > 0.0 {
                first.get_or_insert(p);
                last = p + 1;
            }
        }
        match first {
            Some(f) => f..last,
            None => lo..lo,
        }
    }
}

/// Half-sample symmetric reflection (`… 1 0 | 0 1 2 … n-1 | n-1 n-2 …`), valid for any
/// offset and any `n >= 1`, so an image smaller than its PSF still pads correctly.
pub fn reflect(p: isize, n: usize) -> usize {
    let period = 2 * n as isize;
    let m = p.rem_euclid(period) as usize;
    if m < n { m } else { 2 * n - 1 - m }
}

/// An image plane extended by `pad` pixels on every side with [`reflect`]ed content.
pub struct Padded {
    pub width: usize,
    pub height: usize,
    pub pad: usize,
    pub data: Vec<f32>,
}

impl Padded {
    pub fn new(plane: &[f32], width: usize, height: usize, pad: usize) -> Self {
        Self::from_fn(|i| plane[i], width, height, pad)
    }

    /// Pads the plane whose pixel `i` (row-major) is `value(i)`.
    pub fn from_fn(value: impl Fn(usize) -> f32, width: usize, height: usize, pad: usize) -> Self {
        let (pw, ph) = (width + 2 * pad, height + 2 * pad);
        let mut data = vec![0.0; pw * ph];
        let cols: Vec<usize> = (0..pw)
            .map(|x| reflect(x as isize - pad as isize, width))
            .collect();
        for y in 0..ph {
            let row = reflect(y as isize - pad as isize, height) * width;
            for (d, &sx) in data[y * pw..(y + 1) * pw].iter_mut().zip(&cols) {
                *d = value(row + sx);
            }
        }
        Self {
            width,
            height,
            pad,
            data,
        }
    }

    pub fn zeros(width: usize, height: usize, pad: usize) -> Self {
        Self {
            width,
            height,
            pad,
            data: vec![0.0; (width + 2 * pad) * (height + 2 * pad)],
        }
    }

    pub fn stride(&self) -> usize {
        self.width + 2 * self.pad
    }

    /// Value at image coordinates (may lie in the padding).
    pub fn at(&self, y: isize, x: isize) -> f32 {
        let p = self.pad as isize;
        self.data[(y + p) as usize * self.stride() + (x + p) as usize]
    }

    /// The adjoint of [`Padded::new`]: every padded value is added back to the pixel it
    /// was copied from.
    ///
    /// Output rows are folded in parallel; each gathers the padded rows copied from it in
    /// increasing order and adds their values left to right, the order of a serial sweep over
    /// the padded image, so the sums are the same to the bit.
    pub fn fold(&self) -> Vec<f32> {
        let (w, h, pad) = (self.width, self.height, self.pad as isize);
        let pw = self.stride();
        let cols: Vec<usize> = (0..pw).map(|x| reflect(x as isize - pad, w)).collect();
        let mut sources: Vec<Vec<usize>> = vec![Vec::new(); h];
        for y in 0..h + 2 * self.pad {
            sources[reflect(y as isize - pad, h)].push(y);
        }
        let mut out = vec![0.0f32; w * h];
        out.par_chunks_mut(w).zip(&sources).for_each(|(dst, rows)| {
            for &y in rows {
                for (v, &sx) in self.data[y * pw..(y + 1) * pw].iter().zip(&cols) {
                    dst[sx] += *v;
                }
            }
        });
        out
    }
}
