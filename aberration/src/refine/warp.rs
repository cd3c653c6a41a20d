//! A low-dimensional correction of a PSF grid: every supplied PSF scaled about its centre
//! by a factor per channel that varies quadratically over the field, and the whole grid turned
//! by one angle.
//!
//! The errors a calibration makes most (a focal length or a sensor distance a little off,
//! lasers at other wavelengths than the design's, a rig rotated against the sensor) change a
//! metalens PSF mostly in size, differently per colour, and in orientation. Seven numbers
//! describe that: per channel `c` the scale `exp(a_c + b_c·ρ²)` at normalised field radius
//! `ρ` (corners at 1), and the angle. Being few, they cannot take up scene detail, and every
//! view's every pixel constrains them; they cannot correct a PSF's shape beyond size and
//! orientation, which the free-form refiner ([`super::PsfRefiner`]) can.
//!
//! The gradient with respect to the parameters is the PSF-value gradient pushed through the
//! warp analytically in one pass (checked against central differences through the warp).

use super::{RefineReport, RefineState, check_gradient, largest_change};
use crate::error::{AberrationError, Result};
use crate::psf_grid::PsfGrid;
use rayon::prelude::*;

/// Parameters: `a_R a_G a_B b_R b_G b_B angle` (log-scales and radians).
pub const PARAMS: usize = 7;

/// Step of the central differences through the warp (the check of the one-pass gradient).
const DELTA: f64 = 1e-4;

/// `supplied` warped by `p` (see the module documentation), each kernel renormalised.
pub fn warp_grid(supplied: &PsfGrid, p: &[f64]) -> Result<PsfGrid> {
    if p.len() != PARAMS || p.iter().any(|v| !v.is_finite()) {
        return Err(AberrationError::BadParameter(format!(
            "a PSF warp takes {PARAMS} finite parameters, not {p:?}"
        )));
    }
    let (g, k) = (supplied.grid(), supplied.size());
    let kk = k * k;
    let c = (k / 2) as f64;
    let (sin, cos) = p[6].sin_cos();
    let data: Vec<f32> = (0..g * g * 3)
        .into_par_iter()
        .flat_map_iter(|idx| {
            let (gi, ch) = (idx / 3, idx % 3);
            let rho2 = field_radius2(gi / g, gi % g, g);
            let s = (p[ch] + p[3 + ch] * rho2).exp();
            let src = supplied.kernel(gi, ch);
            let sample = |y: f64, x: f64| -> f64 {
                let (y0, x0) = (y.floor(), x.floor());
                let (fy, fx) = (y - y0, x - x0);
                let at = |yy: f64, xx: f64| -> f64 {
                    if yy < 0.0 || xx < 0.0 || yy >= k as f64 || xx >= k as f64 {
                        0.0
                    } else {
                        src[yy as usize * k + xx as usize] as f64
                    }
                };
                at(y0, x0) * (1.0 - fy) * (1.0 - fx)
                    + at(y0, x0 + 1.0) * (1.0 - fy) * fx
                    + at(y0 + 1.0, x0) * fy * (1.0 - fx)
                    + at(y0 + 1.0, x0 + 1.0) * fy * fx
            };
            let mut out = vec![0.0f64; kk];
            for y in 0..k {
                for x in 0..k {
                    // The output pixel's offset, turned back and shrunk onto the source.
                    let (dy, dx) = (y as f64 - c, x as f64 - c);
                    let (ry, rx) = ((dy * cos - dx * sin) / s, (dy * sin + dx * cos) / s);
                    out[y * k + x] = sample(c + ry, c + rx);
                }
            }
            let sum: f64 = out.iter().sum();
            // A warp that leaves nothing of the kernel in the crop keeps the kernel.
            let ok = sum > 1e-12;
            out.into_iter()
                .enumerate()
                .map(move |(i, v)| if ok { (v / sum) as f32 } else { src[i] })
        })
        .collect();
    PsfGrid::from_planar(g, k, data)
}

/// `ρ²` of grid point (row i, column j): 0 at the centre, 1 at the corners.
fn field_radius2(i: usize, j: usize, g: usize) -> f64 {
    if g < 2 {
        return 0.0;
    }
    let (u, v) = (
        (2 * j) as f64 / (g - 1) as f64 - 1.0,
        (2 * i) as f64 / (g - 1) as f64 - 1.0,
    );
    (u * u + v * v) / 2.0
}

/// Refines the seven warp parameters with Adam from the PSF-value gradient.
pub struct WarpRefiner {
    supplied: PsfGrid,
    lr: f32,
    /// Weight of `Σ p²`: keeps the warp near identity when the photos do not ask for more.
    anchor: f32,
    state: RefineState,
    current: PsfGrid,
}

impl WarpRefiner {
    pub fn new(supplied: PsfGrid, lr: f32, anchor: f32) -> Result<Self> {
        let state = RefineState {
            logits: vec![0.0; PARAMS],
            m: vec![0.0; PARAMS],
            v: vec![0.0; PARAMS],
            steps: 0,
        };
        Self::resume(supplied, lr, anchor, state)
    }

    pub fn resume(supplied: PsfGrid, lr: f32, anchor: f32, state: RefineState) -> Result<Self> {
        if !(lr.is_finite() && lr > 0.0 && anchor.is_finite() && anchor >= 0.0) {
            return Err(AberrationError::BadParameter(format!(
                "PSF warp refinement needs a positive learning rate and a non-negative anchor (lr {lr}, anchor {anchor})"
            )));
        }
        state.check(PARAMS)?;
        let current = if state.steps == 0 {
            supplied.clone()
        } else {
            warp_grid(&supplied, &params(&state))?
        };
        Ok(Self {
            supplied,
            lr,
            anchor,
            state,
            current,
        })
    }

    pub fn supplied(&self) -> &PsfGrid {
        &self.supplied
    }

    pub fn current(&self) -> &PsfGrid {
        &self.current
    }

    pub fn state(&self) -> &RefineState {
        &self.state
    }

    /// The parameters now: `a_R a_G a_B b_R b_G b_B angle`.
    pub fn params(&self) -> Vec<f64> {
        params(&self.state)
    }

    /// The gradient of `⟨data_grad, warp(p)⟩` with respect to the parameters, in one pass
    /// over the kernels: the bilinear sample's slope times how the sample point moves with
    /// each parameter, through each kernel's renormalisation.
    pub fn param_gradient(&self, data_grad: &[f32]) -> Result<Vec<f64>> {
        param_gradient(&self.supplied, &self.params(), data_grad)
    }

    /// [`Self::param_gradient`] by central differences through [`warp_grid`] (slow; the
    /// independent check of the one-pass gradient).
    pub fn param_gradient_by_differences(&self, data_grad: &[f32]) -> Result<Vec<f64>> {
        let p = self.params();
        (0..PARAMS)
            .map(|i| {
                let (mut up, mut down) = (p.clone(), p.clone());
                up[i] += DELTA;
                down[i] -= DELTA;
                let (a, b) = (
                    warp_grid(&self.supplied, &up)?,
                    warp_grid(&self.supplied, &down)?,
                );
                let d: f64 = a
                    .planar()
                    .iter()
                    .zip(b.planar())
                    .zip(data_grad)
                    .map(|((x, y), g)| (*x as f64 - *y as f64) * *g as f64)
                    .sum();
                Ok(d / (2.0 * DELTA))
            })
            .collect()
    }

    /// One Adam step on the parameters from the loss's gradient with respect to the PSF
    /// values.
    pub fn step(&mut self, data_grad: &[f32]) -> Result<RefineReport> {
        check_gradient(data_grad, self.supplied.planar().len())?;
        let p = self.params();
        let penalty: f64 = self.anchor as f64 * p.iter().map(|v| v * v).sum::<f64>();
        let grad: Vec<f32> = param_gradient(&self.supplied, &p, data_grad)?
            .iter()
            .zip(&p)
            .map(|(g, v)| (g + 2.0 * self.anchor as f64 * v) as f32)
            .collect();
        let next_state = self.state.adam_step(&grad, self.lr)?;
        let next = warp_grid(&self.supplied, &params(&next_state))?;
        let largest_change = largest_change(&next, &self.current);
        self.state = next_state;
        self.current = next;
        Ok(RefineReport {
            penalty,
            largest_change,
        })
    }
}

fn params(s: &RefineState) -> Vec<f64> {
    s.logits.iter().map(|v| *v as f64).collect()
}

/// `∂⟨g, warp(p)⟩/∂p`. Per kernel, with `u` the resampled values and `h = u / Σu`:
/// `∂⟨g, h⟩/∂θ = (⟨g, ∂u/∂θ⟩ − ⟨g, h⟩ Σ ∂u/∂θ) / Σu`, where `∂u/∂θ` is the bilinear slope at
/// the sample point times the point's motion: `−(ry, rx)` for the log-scale at the centre,
/// `ρ²` times that for its change over the field, `(−rx, ry)` for the angle.
fn param_gradient(supplied: &PsfGrid, p: &[f64], g: &[f32]) -> Result<Vec<f64>> {
    if p.len() != PARAMS || g.len() != supplied.planar().len() {
        return Err(AberrationError::BadParameter(format!(
            "a warp gradient takes {PARAMS} parameters and {} PSF values",
            supplied.planar().len()
        )));
    }
    let (gs, k) = (supplied.grid(), supplied.size());
    let kk = k * k;
    let c = (k / 2) as f64;
    let (sin, cos) = p[6].sin_cos();
    let per_kernel: Vec<[f64; PARAMS]> = (0..gs * gs * 3)
        .into_par_iter()
        .map(|idx| {
            let (gi, ch) = (idx / 3, idx % 3);
            let rho2 = field_radius2(gi / gs, gi % gs, gs);
            let s = (p[ch] + p[3 + ch] * rho2).exp();
            let src = supplied.kernel(gi, ch);
            let gk = &g[idx * kk..(idx + 1) * kk];
            let at = |yy: i64, xx: i64| -> f64 {
                if yy < 0 || xx < 0 || yy >= k as i64 || xx >= k as i64 {
                    0.0
                } else {
                    src[yy as usize * k + xx as usize] as f64
                }
            };
            // Σu, ⟨g,u⟩, and per motion (scale, angle): Σ∂u, ⟨g,∂u⟩.
            let (mut su, mut gu) = (0.0, 0.0);
            let (mut sd_s, mut gd_s, mut sd_a, mut gd_a) = (0.0, 0.0, 0.0, 0.0);
            for y in 0..k {
                for x in 0..k {
                    let (dy, dx) = (y as f64 - c, x as f64 - c);
                    let (ry, rx) = ((dy * cos - dx * sin) / s, (dy * sin + dx * cos) / s);
                    let (qy, qx) = (c + ry, c + rx);
                    let (y0, x0) = (qy.floor(), qx.floor());
                    let (fy, fx) = (qy - y0, qx - x0);
                    let (iy, ix) = (y0 as i64, x0 as i64);
                    let (v00, v01, v10, v11) = (
                        at(iy, ix),
                        at(iy, ix + 1),
                        at(iy + 1, ix),
                        at(iy + 1, ix + 1),
                    );
                    let u = v00 * (1.0 - fy) * (1.0 - fx)
                        + v01 * (1.0 - fy) * fx
                        + v10 * fy * (1.0 - fx)
                        + v11 * fy * fx;
                    let by = (1.0 - fx) * (v10 - v00) + fx * (v11 - v01);
                    let bx = (1.0 - fy) * (v01 - v00) + fy * (v11 - v10);
                    let du_s = -(by * ry + bx * rx);
                    let du_a = -by * rx + bx * ry;
                    let gv = gk[y * k + x] as f64;
                    su += u;
                    gu += gv * u;
                    sd_s += du_s;
                    gd_s += gv * du_s;
                    sd_a += du_a;
                    gd_a += gv * du_a;
                }
            }
            let mut out = [0.0; PARAMS];
            // A warp that leaves nothing in the crop keeps the kernel: no gradient there.
            if su > 1e-12 {
                let gh = gu / su;
                let d_scale = (gd_s - gh * sd_s) / su;
                out[ch] = d_scale;
                out[3 + ch] = rho2 * d_scale;
                out[6] = (gd_a - gh * sd_a) / su;
            }
            out
        })
        .collect();
    let mut total = vec![0.0; PARAMS];
    for k in &per_kernel {
        for (t, v) in total.iter_mut().zip(k) {
            *t += v;
        }
    }
    Ok(total)
}
