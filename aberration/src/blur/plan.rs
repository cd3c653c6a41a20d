use super::layout::{AxisLayout, Padded};
use crate::error::{AberrationError, Result};
use crate::fft2::{Fft2Scratch, RealFft2, fast_len};
use crate::image::Image;
use crate::psf_grid::PsfGrid;
use glam::Vec3;
use rayon::prelude::*;
use rustfft::num_complex::Complex32;
use std::collections::HashMap;
use std::ops::Range;
use std::sync::Arc;

#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum BlurMode {
    /// The paper's patch-wise blur: hard tile borders.
    #[default]
    Tiled,
    /// Seamless bilinear interpolation between neighbouring PSFs.
    Blend,
}

impl std::str::FromStr for BlurMode {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "tiled" => Ok(Self::Tiled),
            "blend" => Ok(Self::Blend),
            other => Err(format!("unknown blur mode '{other}' (tiled or blend)")),
        }
    }
}

impl std::fmt::Display for BlurMode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Tiled => "tiled",
            Self::Blend => "blend",
        })
    }
}

/// One grid PSF acting on one rectangle of the (padded) image, computed by FFT.
///
/// The input segment starts at image coordinates `(in_y, in_x)`; FFT output index `m`
/// lands on image row `m + in_y − c`. Only output indices in `out_m × out_n` are kept:
/// for tiles the overlap-save valid part, for blend terms the part inside the image.
struct Term {
    g: usize,
    in_y: isize,
    in_x: isize,
    in_h: usize,
    in_w: usize,
    weights: Option<(Vec<f32>, Vec<f32>)>,
    out_m: Range<usize>,
    out_n: Range<usize>,
    fft: Arc<RealFft2>,
    spectra: [Vec<Complex32>; 3],
}

/// A blur prepared for one image size: FFT plans and PSF spectra are computed once, so
/// repeated `apply`/`adjoint` calls (one per training step) only run the transforms.
pub struct BlurPlan {
    width: usize,
    height: usize,
    mode: BlurMode,
    ksize: usize,
    /// Terms grouped by grid row: the unit of parallel work.
    groups: Vec<Vec<Term>>,
}

impl BlurPlan {
    /// `psf` must already be at the image's scale (see [`PsfGrid::for_image`]).
    pub fn new(psf: &PsfGrid, width: usize, height: usize, mode: BlurMode) -> Result<Self> {
        if width == 0 || height == 0 {
            return Err(AberrationError::BadParameter(format!(
                "cannot blur an empty {width}x{height} image"
            )));
        }
        let (g, k) = (psf.grid(), psf.size());
        let c = (k / 2) as isize;
        let ax = AxisLayout { n: width, g };
        let ay = AxisLayout { n: height, g };
        let mut ffts: HashMap<(usize, usize), Arc<RealFft2>> = HashMap::new();
        let mut fft_for = |rows: usize, cols: usize| {
            ffts.entry((rows, cols))
                .or_insert_with(|| Arc::new(RealFft2::new(rows, cols)))
                .clone()
        };
        // Input reach of an output pixel p is [p + c − (K−1), p + c].
        let (m_lo, m_hi) = (c - (k as isize - 1), c);
        let mut groups = Vec::with_capacity(g);
        for i in 0..g {
            let mut terms = Vec::new();
            for j in 0..g {
                let gi = i * g + j;
                let term = match mode {
                    BlurMode::Tiled => {
                        let (ry, rx) = (ay.tile(i), ax.tile(j));
                        if ry.is_empty() || rx.is_empty() {
                            continue;
                        }
                        let (in_h, in_w) = (ry.len() + k - 1, rx.len() + k - 1);
                        let fft = fft_for(fast_len(in_h), fast_len(in_w));
                        Term {
                            g: gi,
                            in_y: ry.start as isize + m_lo,
                            in_x: rx.start as isize + m_lo,
                            in_h,
                            in_w,
                            weights: None,
                            out_m: k - 1..in_h,
                            out_n: k - 1..in_w,
                            fft,
                            spectra: Default::default(),
                        }
                    }
                    BlurMode::Blend => {
                        let sy = ay.hat_support(i, m_lo, height as isize + m_hi);
                        let sx = ax.hat_support(j, m_lo, width as isize + m_hi);
                        if sy.is_empty() || sx.is_empty() {
                            continue;
                        }
                        let (in_h, in_w) = (sy.len(), sx.len());
                        let out = |start: isize, len: usize, n: usize| {
                            let lo = (c - start).max(0) as usize;
                            let hi = ((n as isize + c - start) as usize).min(len + k - 1);
                            lo..hi.max(lo)
                        };
                        let (out_m, out_n) =
                            (out(sy.start, in_h, height), out(sx.start, in_w, width));
                        if out_m.is_empty() || out_n.is_empty() {
                            continue;
                        }
                        let wy = sy.clone().map(|p| ay.hat(i, p) as f32).collect();
                        let wx = sx.clone().map(|p| ax.hat(j, p) as f32).collect();
                        let fft = fft_for(fast_len(in_h + k - 1), fast_len(in_w + k - 1));
                        Term {
                            g: gi,
                            in_y: sy.start,
                            in_x: sx.start,
                            in_h,
                            in_w,
                            weights: Some((wy, wx)),
                            out_m,
                            out_n,
                            fft,
                            spectra: Default::default(),
                        }
                    }
                };
                terms.push(term);
            }
            groups.push(terms);
        }
        // PSF spectra: the expensive part of planning, done once and in parallel.
        groups.par_iter_mut().flatten().for_each(|t| {
            t.spectra =
                std::array::from_fn(|ch| t.fft.kernel_spectrum(psf.kernel(t.g, ch), k, false));
        });
        Ok(Self {
            width,
            height,
            mode,
            ksize: k,
            groups,
        })
    }

    pub fn width(&self) -> usize {
        self.width
    }

    pub fn height(&self) -> usize {
        self.height
    }

    pub fn mode(&self) -> BlurMode {
        self.mode
    }

    /// Bytes held by the cached PSF spectra.
    pub fn spectra_bytes(&self) -> usize {
        self.groups
            .iter()
            .flatten()
            .map(|t| t.spectra.iter().map(|s| s.len() * 8).sum::<usize>())
            .sum()
    }

    fn check(&self, img: &Image) -> Result<()> {
        if img.width != self.width || img.height != self.height {
            return Err(AberrationError::SizeMismatch {
                width: img.width,
                height: img.height,
                plan_width: self.width,
                plan_height: self.height,
            });
        }
        Ok(())
    }

    fn check_pixels(&self, pixels: &[Vec3]) -> Result<()> {
        if pixels.len() != self.width * self.height {
            return Err(AberrationError::BadParameter(format!(
                "{} pixels given to a blur planned for {}x{}",
                pixels.len(),
                self.width,
                self.height
            )));
        }
        Ok(())
    }

    /// The unit of parallel work: (channel, grid row).
    fn jobs(&self) -> Vec<(usize, usize)> {
        (0..3)
            .flat_map(|ch| (0..self.groups.len()).map(move |gi| (ch, gi)))
            .collect()
    }

    fn pad(&self) -> usize {
        self.ksize
    }

    /// `y = A x`.
    pub fn apply(&self, x: &Image) -> Result<Image> {
        self.check(x)?;
        let n = x.plane_len();
        let planes = self.apply_with(|ch, i| x.data[ch * n + i]);
        let mut y = Image::new(self.width, self.height);
        y.data = planes.concat();
        Ok(y)
    }

    /// `y = A x` on row-major RGB pixels, the renderer's layout: the channels are read and
    /// written in place of the copies the FFTs make anyway, so no layout conversion is paid.
    pub fn apply_pixels(&self, x: &[Vec3]) -> Result<Vec<Vec3>> {
        self.check_pixels(x)?;
        Ok(interleave(&self.apply_with(|ch, i| x[i][ch])))
    }

    /// `x = Aᵀ y` on row-major RGB pixels, the exact adjoint of [`BlurPlan::apply_pixels`].
    pub fn adjoint_pixels(&self, y: &[Vec3]) -> Result<Vec<Vec3>> {
        self.check_pixels(y)?;
        Ok(interleave(&self.adjoint_with(|ch, i| y[i][ch])))
    }

    /// Replaces the PSFs the plan blurs with (same grid and size, at the image's scale): only
    /// the spectra are recomputed, the FFT plans and the layout stay.
    pub fn set_psf(&mut self, psf: &PsfGrid) -> Result<()> {
        if psf.size() != self.ksize || psf.grid() != self.groups.len() {
            return Err(AberrationError::BadParameter(format!(
                "a {g}x{g} grid of {} px PSFs cannot replace the {}x{} grid of {} px PSFs the blur was planned with",
                psf.size(),
                self.groups.len(),
                self.groups.len(),
                self.ksize,
                g = psf.grid(),
            )));
        }
        let k = self.ksize;
        self.groups.par_iter_mut().flatten().for_each(|t| {
            t.spectra =
                std::array::from_fn(|ch| t.fft.kernel_spectrum(psf.kernel(t.g, ch), k, false));
        });
        Ok(())
    }

    /// `∂⟨g, A x⟩/∂h`: how a loss whose gradient with respect to the blurred image `A x` is
    /// `g` changes with every PSF value, in [`PsfGrid::planar`]'s layout (grid point, channel,
    /// row, column). The blur is linear in the PSF, so each kernel's gradient is the
    /// correlation of `g` with the (weighted, padded) input that kernel acted on, over the
    /// output the kernel wrote: `Σ_p g[p] · u[p + c − k]`, computed through the plan's own FFTs
    /// (the input's spectrum, conjugated, times the gradient's). The values are raw: a PSF
    /// constrained to unit sum projects them itself.
    pub fn psf_gradient_pixels(&self, x: &[Vec3], g: &[Vec3]) -> Result<Vec<f32>> {
        self.check_pixels(x)?;
        self.check_pixels(g)?;
        let (w, h, k) = (self.width, self.height, self.ksize);
        let c = (k / 2) as isize;
        let padded: Vec<Padded> = (0..3)
            .into_par_iter()
            .map(|ch| Padded::from_fn(|i| x[i][ch], w, h, self.pad()))
            .collect();
        let jobs = self.jobs();
        let kernels: Vec<Vec<(usize, Vec<f32>)>> = jobs
            .par_iter()
            .map(|&(ch, gi)| {
                let mut work = Work::default();
                let mut input_spec = Vec::new();
                self.groups[gi]
                    .iter()
                    .map(|t| {
                        let grad = psf_gradient_term(
                            t,
                            &padded[ch],
                            &|i| g[i][ch],
                            c,
                            k,
                            &mut input_spec,
                            &mut work,
                        );
                        (t.g * 3 + ch, grad)
                    })
                    .collect()
            })
            .collect();
        let grid = self.groups.len();
        let mut out = vec![0.0f32; grid * grid * 3 * k * k];
        for (idx, grad) in kernels.into_iter().flatten() {
            out[idx * k * k..(idx + 1) * k * k].copy_from_slice(&grad);
        }
        Ok(out)
    }

    /// The forward pass over any layout: `value(ch, i)` reads pixel `i` (row-major) of channel
    /// `ch`; returns the three output planes.
    fn apply_with(&self, value: impl Fn(usize, usize) -> f32 + Sync) -> [Vec<f32>; 3] {
        let (w, h) = (self.width, self.height);
        let c = (self.ksize / 2) as isize;
        let padded: Vec<Padded> = (0..3)
            .into_par_iter()
            .map(|ch| Padded::from_fn(|i| value(ch, i), w, h, self.pad()))
            .collect();
        let jobs = self.jobs();
        // Each job sums its terms into a band of rows; bands are added in a fixed order, so
        // the result is bit-identical for any number of threads.
        let bands: Vec<(usize, usize, Vec<f32>)> = jobs
            .par_iter()
            .map(|&(ch, gi)| {
                let terms = &self.groups[gi];
                let rows = band_rows(terms.iter().map(|t| out_rows(t, c)));
                let mut band = vec![0.0f32; rows.len() * w];
                let mut work = Work::default();
                for t in terms {
                    forward_term(t, ch, &padded[ch], c, rows.start, &mut band, w, &mut work);
                }
                (ch, rows.start, band)
            })
            .collect();
        std::array::from_fn(|ch| merge_bands(&bands, ch, w, h))
    }

    /// `x = Aᵀ y`, the exact adjoint of [`BlurPlan::apply`].
    pub fn adjoint(&self, y: &Image) -> Result<Image> {
        self.check(y)?;
        let n = y.plane_len();
        let planes = self.adjoint_with(|ch, i| y.data[ch * n + i]);
        let mut x = Image::new(self.width, self.height);
        x.data = planes.concat();
        Ok(x)
    }

    /// The adjoint over any layout: `value(ch, i)` reads the input; returns the three output
    /// planes.
    fn adjoint_with(&self, value: impl Fn(usize, usize) -> f32 + Sync) -> [Vec<f32>; 3] {
        let (w, h) = (self.width, self.height);
        let c = (self.ksize / 2) as isize;
        let pad = self.pad();
        let pw = w + 2 * pad;
        let jobs = self.jobs();
        let bands: Vec<(usize, usize, Vec<f32>)> = jobs
            .par_iter()
            .map(|&(ch, gi)| {
                let terms = &self.groups[gi];
                // Bands here are rows of the padded image.
                let rows = band_rows(terms.iter().map(|t| {
                    let a = (t.in_y + pad as isize) as usize;
                    a..a + t.in_h
                }));
                let mut band = vec![0.0f32; rows.len() * pw];
                let mut work = Work::default();
                for t in terms {
                    adjoint_term(
                        t,
                        ch,
                        &|i| value(ch, i),
                        w,
                        c,
                        pad,
                        rows.start,
                        &mut band,
                        &mut work,
                    );
                }
                (ch, rows.start, band)
            })
            .collect();
        std::array::from_fn(|ch| {
            let grads = Padded {
                width: w,
                height: h,
                pad,
                data: merge_bands(&bands, ch, pw, h + 2 * pad),
            };
            grads.fold()
        })
    }
}

/// Channel `ch`'s plane of `rows` rows of `width` values from the jobs' bands (channel, first
/// row, values): rows in parallel, each adding the bands that cover it in job order from zero,
/// as a serial sweep over the bands would, so the sums are the same for any thread count.
fn merge_bands(
    bands: &[(usize, usize, Vec<f32>)],
    ch: usize,
    width: usize,
    rows: usize,
) -> Vec<f32> {
    let mine: Vec<(usize, &[f32])> = bands
        .iter()
        .filter(|b| b.0 == ch)
        .map(|(_, y0, band)| (*y0, &band[..]))
        .collect();
    let mut out = vec![0.0f32; width * rows];
    out.par_chunks_mut(width).enumerate().for_each(|(y, dst)| {
        for &(y0, band) in &mine {
            if y >= y0 && (y - y0 + 1) * width <= band.len() {
                let src = &band[(y - y0) * width..(y - y0 + 1) * width];
                dst.iter_mut().zip(src).for_each(|(d, s)| *d += s);
            }
        }
    });
    out
}

/// Three planes as row-major RGB pixels.
fn interleave(planes: &[Vec<f32>; 3]) -> Vec<Vec3> {
    (0..planes[0].len())
        .into_par_iter()
        .map(|i| Vec3::new(planes[0][i], planes[1][i], planes[2][i]))
        .collect()
}

fn out_rows(t: &Term, c: isize) -> Range<usize> {
    let a = (t.out_m.start as isize + t.in_y - c) as usize;
    a..a + t.out_m.len()
}

fn band_rows(ranges: impl Iterator<Item = Range<usize>>) -> Range<usize> {
    ranges
        .reduce(|a, b| a.start.min(b.start)..a.end.max(b.end))
        .unwrap_or(0..0)
}

/// Working memory reused across the terms of one job: a fresh spectrum per term costs page
/// faults on every term.
#[derive(Default)]
struct Work {
    scratch: Option<((usize, usize), Fft2Scratch)>,
    spec: Vec<Complex32>,
}

impl Work {
    fn get(&mut self, fft: &RealFft2) -> (&mut Fft2Scratch, &mut [Complex32]) {
        let key = (fft.rows, fft.cols);
        if self.scratch.as_ref().is_none_or(|(k, _)| *k != key) {
            self.scratch = Some((key, fft.scratch()));
        }
        let n = fft.spectrum_len();
        if self.spec.len() < n {
            self.spec.resize(n, Complex32::ZERO);
        }
        let s = &mut self.scratch.as_mut().expect("just set").1;
        (s, &mut self.spec[..n])
    }
}

/// The spectrum of a term's input: its rows of the padded image, weighted when the term
/// blends. The forward blur and the PSF gradient read the same input.
fn input_spectrum(t: &Term, xp: &Padded, spec: &mut [Complex32], s: &mut Fft2Scratch) {
    let stride = xp.stride();
    let pad = xp.pad as isize;
    t.fft.forward(
        0..t.in_h,
        |r, row| {
            row.fill(0.0);
            let base = (t.in_y + r as isize + pad) as usize * stride + (t.in_x + pad) as usize;
            let src = &xp.data[base..base + t.in_w];
            match &t.weights {
                None => row[..t.in_w].copy_from_slice(src),
                Some((wy, wx)) => {
                    let a = wy[r];
                    for ((d, v), b) in row.iter_mut().zip(src).zip(wx) {
                        *d = v * a * b;
                    }
                }
            }
        },
        spec,
        s,
    );
}

/// The spectrum of the output gradient over the rows and columns a term writes (zero
/// elsewhere). The adjoint and the PSF gradient read the same gradient.
fn gradient_spectrum(
    t: &Term,
    g: &impl Fn(usize) -> f32,
    w: usize,
    c: isize,
    spec: &mut [Complex32],
    s: &mut Fft2Scratch,
) {
    let x0 = (t.out_n.start as isize + t.in_x - c) as usize;
    t.fft.forward(
        t.out_m.clone(),
        |m, row| {
            row.fill(0.0);
            let y = (m as isize + t.in_y - c) as usize;
            let src = y * w + x0;
            for (j, d) in row[t.out_n.clone()].iter_mut().enumerate() {
                *d = g(src + j);
            }
        },
        spec,
        s,
    );
}

#[allow(clippy::too_many_arguments)]
fn forward_term(
    t: &Term,
    ch: usize,
    xp: &Padded,
    c: isize,
    y0: usize,
    band: &mut [f32],
    w: usize,
    work: &mut Work,
) {
    let fft = &t.fft;
    let (s, spec) = work.get(fft);
    input_spectrum(t, xp, spec, s);
    spec.iter_mut()
        .zip(&t.spectra[ch])
        .for_each(|(a, b)| *a *= b);
    let x0 = (t.out_n.start as isize + t.in_x - c) as usize;
    fft.inverse(
        spec,
        t.out_m.clone(),
        |m, row| {
            let y = (m as isize + t.in_y - c) as usize - y0;
            let dst = &mut band[y * w + x0..y * w + x0 + t.out_n.len()];
            dst.iter_mut()
                .zip(&row[t.out_n.clone()])
                .for_each(|(d, v)| *d += v);
        },
        s,
    );
}

/// One term's share of [`BlurPlan::psf_gradient_pixels`]: the `K×K` correlation of the output
/// gradient (zero outside the rows and columns the term writes) with the term's input. No
/// circular wrap reaches the kernel's lags: the tiles' kept outputs start `K − 1` rows in, and
/// the blend terms' transforms are zero-padded by `K − 1` beyond their input.
fn psf_gradient_term(
    t: &Term,
    xp: &Padded,
    g: &impl Fn(usize) -> f32,
    c: isize,
    k: usize,
    input_spec: &mut Vec<Complex32>,
    work: &mut Work,
) -> Vec<f32> {
    let fft = &t.fft;
    let (s, spec) = work.get(fft);
    input_spec.resize(fft.spectrum_len(), Complex32::ZERO);
    input_spectrum(t, xp, input_spec, s);
    gradient_spectrum(t, g, xp.width, c, spec, s);
    let scale = 1.0 / (fft.rows * fft.cols) as f32;
    spec.iter_mut()
        .zip(input_spec.iter())
        .for_each(|(a, b)| *a *= b.conj() * scale);
    let mut grad = vec![0.0f32; k * k];
    fft.inverse(
        spec,
        0..k,
        |r, row| grad[r * k..(r + 1) * k].copy_from_slice(&row[..k]),
        s,
    );
    grad
}

#[allow(clippy::too_many_arguments)]
fn adjoint_term(
    t: &Term,
    ch: usize,
    g: &impl Fn(usize) -> f32,
    w: usize,
    c: isize,
    pad: usize,
    y0: usize,
    band: &mut [f32],
    work: &mut Work,
) {
    let fft = &t.fft;
    let (s, spec) = work.get(fft);
    gradient_spectrum(t, g, w, c, spec, s);
    spec.iter_mut()
        .zip(&t.spectra[ch])
        .for_each(|(a, b)| *a *= b.conj());
    let pw = w + 2 * pad;
    let col0 = (t.in_x + pad as isize) as usize;
    fft.inverse(
        spec,
        0..t.in_h,
        |r, row| {
            let py = (t.in_y + pad as isize) as usize + r - y0;
            let dst = &mut band[py * pw + col0..py * pw + col0 + t.in_w];
            match &t.weights {
                None => dst.iter_mut().zip(row).for_each(|(d, v)| *d += v),
                Some((wy, wx)) => {
                    let a = wy[r];
                    for ((d, v), b) in dst.iter_mut().zip(row).zip(wx) {
                        *d += v * a * b;
                    }
                }
            }
        },
        s,
    );
}
