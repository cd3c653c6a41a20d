//! Angular-spectrum propagation from the lens plane to the focal plane, in f64.
//!
//! The lens field lives on an `N×N` grid of the meta-atom pitch `dx`, sample `n` at
//! coordinate `(n − N/2)·dx` (so the optical axis is a sample and the grid is symmetric
//! about it). The transfer function is `exp(i·k_z·z)` with `k_z = √(k² − k_x² − k_y²)`;
//! evanescent components are dropped. Only a window of the focal plane is brought back to
//! real space, which skips most of the inverse transform's second pass.

use super::phase::Lens;
use rayon::prelude::*;
use rustfft::num_complex::Complex64;
use rustfft::{Fft, FftPlanner};
use std::f64::consts::TAU;
use std::sync::Arc;

/// Rows handed to one rayon task: enough work to amortise its scratch allocation.
const ROWS_PER_TASK: usize = 16;

pub struct Propagator {
    pub n: usize,
    pub dx_um: f64,
    fwd: Arc<dyn Fft<f64>>,
    inv: Arc<dyn Fft<f64>>,
}

/// The focal-plane intensity around one point, as power per sample.
pub struct FocalWindow {
    /// `(2·half + 1)²` values, row-major; row = y.
    pub intensity: Vec<f64>,
    pub half: usize,
    /// Coordinates (µm) of the window's centre sample.
    pub centre_x_um: f64,
    pub centre_y_um: f64,
    pub dx_um: f64,
    /// Power reaching the whole focal plane (incident power is 1).
    pub total_power: f64,
}

impl FocalWindow {
    pub fn side(&self) -> usize {
        2 * self.half + 1
    }

    /// Power density (per µm²) at a point, bilinear between samples; zero outside.
    pub fn density(&self, x_um: f64, y_um: f64) -> f64 {
        let side = self.side();
        let fx = (x_um - self.centre_x_um) / self.dx_um + self.half as f64;
        let fy = (y_um - self.centre_y_um) / self.dx_um + self.half as f64;
        if !(fx >= 0.0 && fy >= 0.0) {
            return 0.0;
        }
        let (ix, iy) = (fx.floor() as usize, fy.floor() as usize);
        if ix + 1 >= side || iy + 1 >= side {
            return 0.0;
        }
        let (tx, ty) = (fx - ix as f64, fy - iy as f64);
        let at = |y: usize, x: usize| self.intensity[y * side + x];
        let top = at(iy, ix) * (1.0 - tx) + at(iy, ix + 1) * tx;
        let bottom = at(iy + 1, ix) * (1.0 - tx) + at(iy + 1, ix + 1) * tx;
        (top * (1.0 - ty) + bottom * ty) / (self.dx_um * self.dx_um)
    }
}

impl Propagator {
    pub fn new(n: usize, dx_um: f64) -> Self {
        let mut planner = FftPlanner::new();
        Self {
            n,
            dx_um,
            fwd: planner.plan_fft_forward(n),
            inv: planner.plan_fft_inverse(n),
        }
    }

    /// Spatial frequency (rad/µm) of FFT bin `i`.
    fn freq(&self, i: usize) -> f64 {
        let n = self.n as isize;
        let i = i as isize;
        let f = if i < (n + 1) / 2 { i } else { i - n };
        TAU * f as f64 / (n as f64 * self.dx_um)
    }

    /// `exp(i·k_z·z)` on the frequency grid, zero for evanescent waves. Symmetric in
    /// (k_x, k_y), so it serves the transposed spectrum layout as it is.
    pub fn transfer(&self, lambda_nm: f64, z_um: f64) -> Vec<Complex64> {
        let n = self.n;
        let k = TAU / (lambda_nm * 1e-3);
        let freqs: Vec<f64> = (0..n).map(|i| self.freq(i)).collect();
        let mut h = vec![Complex64::ZERO; n * n];
        h.par_chunks_mut(n).enumerate().for_each(|(r, row)| {
            let ky = freqs[r];
            for (v, kx) in row.iter_mut().zip(&freqs) {
                let kz2 = k * k - kx * kx - ky * ky;
                if kz2 > 0.0 {
                    *v = Complex64::from_polar(1.0, kz2.sqrt() * z_um);
                }
            }
        });
        h
    }

    fn coord(&self, i: usize) -> f64 {
        (i as f64 - (self.n / 2) as f64) * self.dx_um
    }

    /// The lens field for a plane wave tilted by `theta` about the y axis (towards +x),
    /// unit incident power over the aperture. Rows outside the aperture are zero and are
    /// reported so the forward transform can skip them.
    fn lens_field(
        &self,
        lens: &Lens,
        lambda_nm: f64,
        theta: f64,
    ) -> (Vec<Complex64>, std::ops::Range<usize>) {
        let n = self.n;
        let r_ap = lens.aperture_um / 2.0;
        let k = TAU / (lambda_nm * 1e-3);
        let kx_tilt = k * theta.sin();
        let inside: Vec<usize> = (0..n).filter(|&i| self.coord(i).abs() <= r_ap).collect();
        let rows = match (inside.first(), inside.last()) {
            (Some(&a), Some(&b)) => a..b + 1,
            _ => 0..0,
        };
        let count: usize = (0..n)
            .flat_map(|y| (0..n).map(move |x| (y, x)))
            .filter(|&(y, x)| rows.contains(&y) && rows.contains(&x))
            .filter(|&(y, x)| self.coord(x).hypot(self.coord(y)) <= r_ap)
            .count();
        let amp = 1.0 / ((count.max(1) as f64).sqrt() * self.dx_um);
        let mut field = vec![Complex64::ZERO; n * n];
        field
            .par_chunks_mut(n)
            .enumerate()
            .filter(|(y, _)| rows.contains(y))
            .for_each(|(y, row)| {
                let yc = self.coord(y);
                for (x, v) in row.iter_mut().enumerate() {
                    let xc = self.coord(x);
                    let r = xc.hypot(yc);
                    if r <= r_ap {
                        let phi = lens.phase(r, lambda_nm) + kx_tilt * xc;
                        *v = Complex64::from_polar(amp, phi);
                    }
                }
            });
        (field, rows)
    }

    fn rows_fft(
        &self,
        data: &mut [Complex64],
        rows: std::ops::Range<usize>,
        fft: &Arc<dyn Fft<f64>>,
    ) {
        let n = self.n;
        let slice = &mut data[rows.start * n..rows.end * n];
        slice.par_chunks_mut(n * ROWS_PER_TASK).for_each(|chunk| {
            let mut scratch = vec![Complex64::ZERO; fft.get_inplace_scratch_len()];
            fft.process_with_scratch(chunk, &mut scratch);
        });
    }

    /// Propagates the tilted lens field over `lens.focal_um` and returns the window of
    /// half-size `half` samples centred on the sample nearest to `(centre_x_um, 0)`.
    pub fn focal_window(
        &self,
        lens: &Lens,
        lambda_nm: f64,
        theta: f64,
        transfer: &[Complex64],
        centre_x_um: f64,
        half: usize,
    ) -> FocalWindow {
        let n = self.n;
        let (mut field, rows) = self.lens_field(lens, lambda_nm, theta);
        // Forward: rows (over x) for the aperture rows only, transpose, rows (over y).
        self.rows_fft(&mut field, rows, &self.fwd);
        let mut spec = transpose(&field, n);
        drop(field);
        self.rows_fft(&mut spec, 0..n, &self.fwd);
        // Layout now [kx][ky]; the transfer function is symmetric so it applies as is.
        spec.par_iter_mut().zip(transfer).for_each(|(a, b)| *a *= b);
        let total_power: f64 = spec.par_iter().map(|v| v.norm_sqr()).sum::<f64>()
            * (self.dx_um * self.dx_um)
            / (n * n) as f64;
        // Inverse over ky on every kx row gives [kx][y]; only the window's y are needed.
        self.rows_fft(&mut spec, 0..n, &self.inv);
        let side = 2 * half + 1;
        let cy = n / 2;
        let cx = (centre_x_um / self.dx_um).round() as isize + (n / 2) as isize;
        let wrap = |i: isize| i.rem_euclid(n as isize) as usize;
        let ys: Vec<usize> = (0..side)
            .map(|i| wrap(cy as isize + i as isize - half as isize))
            .collect();
        let xs: Vec<usize> = (0..side)
            .map(|i| wrap(cx + i as isize - half as isize))
            .collect();
        let mut rows_y = vec![Complex64::ZERO; side * n];
        rows_y.par_chunks_mut(n).zip(&ys).for_each(|(row, &y)| {
            for (kx, v) in row.iter_mut().enumerate() {
                *v = spec[kx * n + y];
            }
        });
        drop(spec);
        self.rows_fft(&mut rows_y, 0..side, &self.inv);
        let norm = 1.0 / (n * n) as f64;
        let mut intensity = vec![0.0; side * side];
        for (wy, row) in rows_y.chunks(n).enumerate() {
            for (wx, &x) in xs.iter().enumerate() {
                // Power per sample: |U|²·dx².
                intensity[wy * side + wx] = (row[x] * norm).norm_sqr() * self.dx_um * self.dx_um;
            }
        }
        FocalWindow {
            intensity,
            half,
            centre_x_um: (cx - (n / 2) as isize) as f64 * self.dx_um,
            centre_y_um: 0.0,
            dx_um: self.dx_um,
            total_power,
        }
    }
}

/// Blocked transpose of a square matrix.
fn transpose(src: &[Complex64], n: usize) -> Vec<Complex64> {
    const B: usize = 32;
    let mut dst = vec![Complex64::ZERO; n * n];
    dst.par_chunks_mut(n * B)
        .enumerate()
        .for_each(|(bi, block)| {
            let r0 = bi * B;
            let rows = block.len() / n;
            for c0 in (0..n).step_by(B) {
                for r in 0..rows {
                    for c in c0..(c0 + B).min(n) {
                        block[r * n + c] = src[c * n + r0 + r];
                    }
                }
            }
        });
    dst
}
