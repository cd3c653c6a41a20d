//! Tile-wise Wiener deconvolution and the paper's bank of 13 adaptive filters (the MAFG
//! inputs of the restorer).
//!
//! Each grid tile is deconvolved with its own PSF on a window extended by at least `K/2`
//! pixels of (reflect-padded) image context on every side, filling the whole FFT buffer
//! (zero padding would put a hard edge inside the window):
//! `X = conj(H)·Y / (|H|² + K)`, with the PSF centred at the origin so the result stays
//! registered. Outputs are clamped to [0, 1].

use crate::blur::layout::{AxisLayout, Padded};
use crate::error::{AberrationError, Result};
use crate::fft2::{RealFft2, fast_len};
use crate::image::Image;
use crate::psf_grid::PsfGrid;
use rayon::prelude::*;
use rustfft::num_complex::Complex32;
use std::collections::HashMap;
use std::sync::Arc;

/// Smallest regulariser ever used. `K → 0` (black-and-white tiles drive the adaptive K to
/// zero) together with a spectral zero of the PSF would divide 0 by 0; with this floor the
/// gain `|H| / (|H|² + K)` stays below `1 / (2√K) ≈ 1.6e4`.
pub const K_FLOOR: f32 = 1e-9;

/// Number of filters in the MAFG bank.
pub const BANK_SIZE: usize = 13;
/// Index of the median filter (k ≈ 3.16e-4): the restorer's query and residual base.
pub const BANK_MEDIAN: usize = 6;

/// The bank's base constants, log-spaced from 1e-2 down to 1e-5 (the restorer's order).
pub fn bank_constants() -> [f32; BANK_SIZE] {
    std::array::from_fn(|m| 10f64.powf(-2.0 - 3.0 * m as f64 / (BANK_SIZE - 1) as f64) as f32)
}

/// The fixed Wiener constant `metasplat deconvolve` uses when none is given: the bank's
/// largest. On the Kodak validation photos aberrated at the default noise it improves every
/// one and scores best of the bank's constants (sweep in RESULTS.md); smaller constants
/// amplify noise and tile seams more than they sharpen.
pub const DEFAULT_K: f32 = 1e-2;

/// How the regulariser K is chosen per tile and channel.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Regularizer {
    /// The same K everywhere.
    Fixed(f32),
    /// `K = k·(1 − c_I)`, `c_I` the tile's mean intensity in that channel (the paper's
    /// adaptive filter: brighter tiles have more signal relative to noise).
    Adaptive(f32),
}

impl Regularizer {
    fn value(&self, tile_mean: f32) -> f32 {
        let k = match *self {
            Self::Fixed(k) => k,
            Self::Adaptive(k) => k * (1.0 - tile_mean.clamp(0.0, 1.0)),
        };
        if k.is_finite() {
            k.max(K_FLOOR)
        } else {
            K_FLOOR
        }
    }
}

/// The result of the MAFG bank.
pub struct WienerBank {
    /// 13 images, k from 1e-2 down to 1e-5.
    pub images: Vec<Image>,
}

impl WienerBank {
    /// The median-k output (index 6).
    pub fn median(&self) -> &Image {
        &self.images[BANK_MEDIAN]
    }
}

/// Tile-wise Wiener deconvolution with one regulariser.
pub fn deconvolve(blurred: &Image, psf: &PsfGrid, reg: Regularizer) -> Result<Image> {
    Ok(deconvolve_many(blurred, psf, &[reg])?.remove(0))
}

/// The MAFG bank: 13 adaptive Wiener filters.
pub fn wiener_bank(blurred: &Image, psf: &PsfGrid) -> Result<WienerBank> {
    let regs: Vec<Regularizer> = bank_constants()
        .iter()
        .map(|&k| Regularizer::Adaptive(k))
        .collect();
    Ok(WienerBank {
        images: deconvolve_many(blurred, psf, &regs)?,
    })
}

/// Deconvolves with several regularisers at once, sharing each tile's transforms.
pub fn deconvolve_many(blurred: &Image, psf: &PsfGrid, regs: &[Regularizer]) -> Result<Vec<Image>> {
    let (w, h) = (blurred.width, blurred.height);
    if w == 0 || h == 0 {
        return Err(AberrationError::BadParameter(
            "cannot deconvolve an empty image".into(),
        ));
    }
    if regs.iter().any(|r| {
        let k = match r {
            Regularizer::Fixed(k) | Regularizer::Adaptive(k) => *k,
        };
        !(k >= 0.0 && k.is_finite())
    }) {
        return Err(AberrationError::BadParameter(
            "Wiener constants must be finite and non-negative".into(),
        ));
    }
    let (g, k) = (psf.grid(), psf.size());
    let margin = k / 2;
    let ax = AxisLayout { n: w, g };
    let ay = AxisLayout { n: h, g };
    let mut ffts: HashMap<(usize, usize), Arc<RealFft2>> = HashMap::new();
    let mut jobs = Vec::new();
    let mut pad = margin;
    for i in 0..g {
        for j in 0..g {
            let (ry, rx) = (ay.tile(i), ax.tile(j));
            if ry.is_empty() || rx.is_empty() {
                continue;
            }
            let (rows, cols) = (
                fast_len(ry.len() + 2 * margin),
                fast_len(rx.len() + 2 * margin),
            );
            // The window is the FFT buffer, centred on the tile.
            let (before_y, before_x) = ((rows - ry.len()) / 2, (cols - rx.len()) / 2);
            pad = pad
                .max(before_y.max(before_x))
                .max(rows - ry.len() - before_y)
                .max(cols - rx.len() - before_x);
            let fft = ffts
                .entry((rows, cols))
                .or_insert_with(|| Arc::new(RealFft2::new(rows, cols)))
                .clone();
            for ch in 0..3 {
                jobs.push((i * g + j, ch, ry.clone(), rx.clone(), fft.clone()));
            }
        }
    }
    let padded: Vec<Padded> = (0..3)
        .map(|c| Padded::new(blurred.channel(c), w, h, pad))
        .collect();
    let tiles: Vec<Vec<Vec<f32>>> = jobs
        .par_iter()
        .map(|(gi, ch, ry, rx, fft)| {
            let xp = &padded[*ch];
            let stride = xp.stride();
            let (th, tw) = (ry.len(), rx.len());
            let (before_y, before_x) = ((fft.rows - th) / 2, (fft.cols - tw) / 2);
            let mut s = fft.scratch();
            let mut spec = vec![Complex32::ZERO; fft.spectrum_len()];
            fft.forward(
                0..fft.rows,
                |r, row| {
                    let base = (pad + ry.start + r - before_y) * stride + pad + rx.start - before_x;
                    row.copy_from_slice(&xp.data[base..base + fft.cols]);
                },
                &mut spec,
                &mut s,
            );
            let kspec = fft.kernel_spectrum(psf.kernel(*gi, *ch), k, true);
            let plane = blurred.channel(*ch);
            let mean = ry
                .clone()
                .flat_map(|y| plane[y * w + rx.start..y * w + rx.end].iter())
                .map(|v| *v as f64)
                .sum::<f64>()
                / (th * tw) as f64;
            // The kernel spectrum carries 1/(rows·cols); undo it in |H|² so K keeps its scale.
            let n = (fft.rows * fft.cols) as f32;
            regs.iter()
                .map(|reg| {
                    let kk = reg.value(mean as f32);
                    let mut x: Vec<Complex32> = spec
                        .iter()
                        .zip(&kspec)
                        .map(|(y, hs)| {
                            let hh = hs * n;
                            y * hs.conj() / (hh.norm_sqr() + kk)
                        })
                        .collect();
                    let mut tile = vec![0.0f32; th * tw];
                    fft.inverse(
                        &mut x,
                        before_y..before_y + th,
                        |r, row| {
                            let dst = &mut tile[(r - before_y) * tw..(r - before_y + 1) * tw];
                            for (d, v) in dst.iter_mut().zip(&row[before_x..before_x + tw]) {
                                *d = if v.is_finite() {
                                    v.clamp(0.0, 1.0)
                                } else {
                                    0.0
                                };
                            }
                        },
                        &mut s,
                    );
                    tile
                })
                .collect()
        })
        .collect();
    let mut out: Vec<Image> = regs.iter().map(|_| Image::new(w, h)).collect();
    for ((_, ch, ry, rx, _), per_reg) in jobs.iter().zip(tiles) {
        for (img, tile) in out.iter_mut().zip(per_reg) {
            let plane = img.channel_mut(*ch);
            for (r, y) in ry.clone().enumerate() {
                plane[y * w + rx.start..y * w + rx.end]
                    .copy_from_slice(&tile[r * rx.len()..(r + 1) * rx.len()]);
            }
        }
    }
    Ok(out)
}
