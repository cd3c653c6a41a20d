//! Refining a PSF grid from the photos it blurred: free-form PSF values kept physical.
//!
//! Each kernel is the softmax of its own logits, so every PSF stays non-negative and unit-sum
//! per channel whatever the optimiser does. Two penalties keep the correction `d = h − h₀`
//! (refined less supplied) identifiable:
//! - `anchor · mean_kernels ‖d‖² / ‖h₀‖²` pulls each kernel towards the supplied one, so
//!   only what the photos ask for moves;
//! - `smooth · mean_pairs ‖d_a − d_b‖² / mean ‖h₀‖²` over horizontally and vertically
//!   neighbouring grid cells: aberration varies slowly over the field, so a correction that
//!   differs from cell to cell is more likely the PSF taking up scene detail than optics.
//!
//! Both are relative to the supplied kernels' energy, so their weights do not depend on the
//! PSF size. The logits take Adam steps of their own learning rate.

pub mod warp;

use crate::error::{AberrationError, Result};
use crate::psf_grid::PsfGrid;
use rayon::prelude::*;

/// How the grid is refined.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RefineSettings {
    /// Adam step of the logits.
    pub lr: f32,
    /// Weight of the pull towards the supplied grid.
    pub anchor: f32,
    /// Weight of the smoothness of the correction across neighbouring cells.
    pub smooth: f32,
}

/// Adam's moment decay rates (the usual ones).
const BETA1: f32 = 0.9;
const BETA2: f32 = 0.999;
const EPS: f32 = 1e-15;

/// A logit below this (relative to a kernel's largest) starts a pixel the supplied PSF leaves
/// dark; `ln` of zero would pin it there for ever.
const FLOOR: f32 = 1e-7;

/// The refinement's state: logits and their Adam moments. Everything needed to continue.
#[derive(Clone, Debug, PartialEq)]
pub struct RefineState {
    pub logits: Vec<f32>,
    pub m: Vec<f32>,
    pub v: Vec<f32>,
    pub steps: u64,
}

impl RefineState {
    /// Refuses a state of another length than `n` or with a non-finite value.
    fn check(&self, n: usize) -> Result<()> {
        if self.logits.len() != n || self.m.len() != n || self.v.len() != n {
            return Err(AberrationError::BadParameter(format!(
                "a refinement state of {} values does not belong to a refinement of {n}",
                self.logits.len()
            )));
        }
        if self
            .logits
            .iter()
            .chain(&self.m)
            .chain(&self.v)
            .any(|v| !v.is_finite())
        {
            return Err(AberrationError::BadParameter(
                "the refinement state holds a non-finite value".into(),
            ));
        }
        Ok(())
    }

    /// The state after one Adam step of `lr` on `grad`. It is made on a copy and returned
    /// only when every value stays finite: a gradient whose square overflows would leave
    /// moments no later step recovers from.
    fn adam_step(&self, grad: &[f32], lr: f32) -> Result<Self> {
        let mut s = self.clone();
        s.steps += 1;
        let t = s.steps.min(i32::MAX as u64) as i32;
        let (c1, c2) = (1.0 - BETA1.powi(t), 1.0 - BETA2.powi(t));
        s.logits
            .par_iter_mut()
            .zip(s.m.par_iter_mut().zip(s.v.par_iter_mut()))
            .zip(grad)
            .for_each(|((x, (m, v)), g)| {
                *m = BETA1 * *m + (1.0 - BETA1) * g;
                *v = BETA2 * *v + (1.0 - BETA2) * g * g;
                *x -= lr * (*m / c1) / ((*v / c2).sqrt() + EPS);
            });
        if s.logits
            .iter()
            .chain(&s.m)
            .chain(&s.v)
            .any(|v| !v.is_finite())
        {
            return Err(AberrationError::BadParameter(
                "the PSF gradient is too large to take a step with (its square overflows)".into(),
            ));
        }
        Ok(s)
    }
}

/// Refuses a PSF-value gradient of another length than the grid's `n` values, or with a
/// non-finite value, before anything changes.
fn check_gradient(data_grad: &[f32], n: usize) -> Result<()> {
    if data_grad.len() != n {
        return Err(AberrationError::BadParameter(format!(
            "a PSF gradient of {} values for a grid of {n}",
            data_grad.len()
        )));
    }
    if let Some(bad) = data_grad.iter().find(|v| !v.is_finite()) {
        return Err(AberrationError::BadParameter(format!(
            "the PSF gradient holds a non-finite value ({bad})"
        )));
    }
    Ok(())
}

/// The largest change of a PSF value between two grids of one shape, relative to its
/// kernel's peak in `before`.
fn largest_change(after: &PsfGrid, before: &PsfGrid) -> f32 {
    let kk = before.size() * before.size();
    after
        .planar()
        .chunks(kk)
        .zip(before.planar().chunks(kk))
        .map(|(a, b)| {
            let peak = b.iter().cloned().fold(f32::MIN_POSITIVE, f32::max);
            a.iter()
                .zip(b)
                .map(|(x, y)| (x - y).abs() / peak)
                .fold(0.0, f32::max)
        })
        .fold(0.0, f32::max)
}

pub struct PsfRefiner {
    settings: RefineSettings,
    supplied: PsfGrid,
    /// `‖h₀‖²` per kernel.
    energy: Vec<f64>,
    state: RefineState,
    current: PsfGrid,
}

/// What one refinement step did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RefineReport {
    /// The penalties' value before the step.
    pub penalty: f64,
    /// Largest change of a PSF value, relative to its kernel's peak.
    pub largest_change: f32,
}

impl PsfRefiner {
    pub fn new(supplied: PsfGrid, settings: RefineSettings) -> Result<Self> {
        check(&settings)?;
        let kk = supplied.size() * supplied.size();
        let logits: Vec<f32> = supplied
            .planar()
            .par_chunks(kk)
            .flat_map_iter(|kernel| {
                let peak = kernel.iter().cloned().fold(0.0f32, f32::max);
                kernel.iter().map(move |v| v.max(FLOOR * peak).ln())
            })
            .collect();
        let n = logits.len();
        let state = RefineState {
            logits,
            m: vec![0.0; n],
            v: vec![0.0; n],
            steps: 0,
        };
        Self::resume(supplied, settings, state)
    }

    /// Continues from a saved state (of a refiner of the same grid and settings).
    pub fn resume(supplied: PsfGrid, settings: RefineSettings, state: RefineState) -> Result<Self> {
        check(&settings)?;
        state.check(supplied.planar().len())?;
        let kk = supplied.size() * supplied.size();
        let energy = supplied
            .planar()
            .chunks(kk)
            .map(|k| k.iter().map(|v| (*v as f64).powi(2)).sum::<f64>())
            .collect();
        // Before the first step the grid is the supplied one bit for bit (the softmax of its
        // logarithm rounds a little differently), so a run whose PSF is not yet freed blurs
        // exactly as one that never refines.
        let current = if state.steps == 0 {
            supplied.clone()
        } else {
            softmax_grid(&supplied, &state.logits)?
        };
        Ok(Self {
            settings,
            supplied,
            energy,
            state,
            current,
        })
    }

    pub fn settings(&self) -> RefineSettings {
        self.settings
    }

    pub fn supplied(&self) -> &PsfGrid {
        &self.supplied
    }

    /// The refined grid now.
    pub fn current(&self) -> &PsfGrid {
        &self.current
    }

    pub fn state(&self) -> &RefineState {
        &self.state
    }

    /// The penalties at the current grid and their gradient with respect to the PSF values.
    pub fn penalty(&self) -> (f64, Vec<f32>) {
        let (g, k) = (self.supplied.grid(), self.supplied.size());
        let kk = k * k;
        let h = self.current.planar();
        let h0 = self.supplied.planar();
        let kernels = g * g * 3;
        let mut grad = vec![0.0f32; h.len()];
        let mut value = 0.0;
        let anchor = self.settings.anchor as f64;
        for i in 0..kernels {
            let e = self.energy[i].max(f64::MIN_POSITIVE);
            let scale = anchor / kernels as f64 / e;
            for j in i * kk..(i + 1) * kk {
                let d = (h[j] - h0[j]) as f64;
                value += scale * d * d;
                grad[j] += (2.0 * scale * d) as f32;
            }
        }
        let mean_energy = self.energy.iter().sum::<f64>() / kernels as f64;
        let pairs: Vec<(usize, usize)> = (0..g)
            .flat_map(|r| (0..g).map(move |c| (r, c)))
            .flat_map(|(r, c)| {
                let here = r * g + c;
                let right = (c + 1 < g).then_some((here, here + 1));
                let below = (r + 1 < g).then_some((here, here + g));
                right.into_iter().chain(below)
            })
            .collect();
        if !pairs.is_empty() && self.settings.smooth > 0.0 {
            let scale =
                self.settings.smooth as f64 / (pairs.len() * 3) as f64 / mean_energy.max(1e-300);
            for (a, b) in pairs {
                for ch in 0..3 {
                    let (ia, ib) = ((a * 3 + ch) * kk, (b * 3 + ch) * kk);
                    for j in 0..kk {
                        let diff =
                            (h[ia + j] - h0[ia + j]) as f64 - (h[ib + j] - h0[ib + j]) as f64;
                        value += scale * diff * diff;
                        grad[ia + j] += (2.0 * scale * diff) as f32;
                        grad[ib + j] -= (2.0 * scale * diff) as f32;
                    }
                }
            }
        }
        (value, grad)
    }

    /// One Adam step on the logits from `data_grad`, the loss's gradient with respect to the
    /// PSF values (e.g. [`crate::BlurPlan::psf_gradient_pixels`]); the penalties are added
    /// here. A non-finite gradient is refused before anything changes.
    pub fn step(&mut self, data_grad: &[f32]) -> Result<RefineReport> {
        let n = self.state.logits.len();
        check_gradient(data_grad, n)?;
        let (penalty, reg) = self.penalty();
        let kk = self.supplied.size() * self.supplied.size();
        let h = self.current.planar();
        // Through the softmax: ∂/∂θ_i = h_i (∂/∂h_i − Σ_j h_j ∂/∂h_j), per kernel.
        let logit_grad: Vec<f32> = (0..n / kk)
            .into_par_iter()
            .flat_map_iter(|i| {
                let r = i * kk..(i + 1) * kk;
                let total = |j: usize| data_grad[j] + reg[j];
                let mean: f64 = r.clone().map(|j| h[j] as f64 * total(j) as f64).sum();
                r.map(move |j| h[j] * (total(j) - mean as f32))
            })
            .collect();
        let next_state = self.state.adam_step(&logit_grad, self.settings.lr)?;
        let next = softmax_grid(&self.supplied, &next_state.logits)?;
        self.state = next_state;
        let largest_change = largest_change(&next, &self.current);
        self.current = next;
        Ok(RefineReport {
            penalty,
            largest_change,
        })
    }
}

fn check(s: &RefineSettings) -> Result<()> {
    let ok = |v: f32| v.is_finite() && v >= 0.0;
    if !(ok(s.lr) && s.lr > 0.0 && ok(s.anchor) && ok(s.smooth)) {
        return Err(AberrationError::BadParameter(format!(
            "PSF refinement needs a positive learning rate and non-negative penalty weights (lr {}, anchor {}, smooth {})",
            s.lr, s.anchor, s.smooth
        )));
    }
    Ok(())
}

/// The grid whose every kernel is the softmax of its logits.
fn softmax_grid(like: &PsfGrid, logits: &[f32]) -> Result<PsfGrid> {
    let kk = like.size() * like.size();
    let data: Vec<f32> = logits
        .par_chunks(kk)
        .flat_map_iter(|l| {
            let top = l.iter().cloned().fold(f32::NEG_INFINITY, f32::max);
            let e: Vec<f64> = l.iter().map(|v| ((v - top) as f64).exp()).collect();
            let sum: f64 = e.iter().sum();
            e.into_iter().map(move |v| (v / sum) as f32)
        })
        .collect();
    PsfGrid::from_planar(like.grid(), like.size(), data)
}

/// How far a grid is from a reference: per cell (grid point, all channels), the relative
/// L2 distance `‖a − b‖ / ‖b‖`; the mean over cells is the figure to report.
pub fn cell_errors(a: &PsfGrid, reference: &PsfGrid) -> Result<Vec<f64>> {
    if a.grid() != reference.grid() || a.size() != reference.size() {
        return Err(AberrationError::BadParameter(format!(
            "a {}x{} grid of {} px PSFs cannot be compared with a {}x{} grid of {} px PSFs",
            a.grid(),
            a.grid(),
            a.size(),
            reference.grid(),
            reference.grid(),
            reference.size()
        )));
    }
    let per_cell = 3 * a.size() * a.size();
    Ok(a.planar()
        .chunks(per_cell)
        .zip(reference.planar().chunks(per_cell))
        .map(|(x, y)| {
            let d: f64 = x
                .iter()
                .zip(y)
                .map(|(p, q)| (*p as f64 - *q as f64).powi(2))
                .sum();
            let e: f64 = y.iter().map(|q| (*q as f64).powi(2)).sum();
            (d / e.max(f64::MIN_POSITIVE)).sqrt()
        })
        .collect())
}

/// A grid as a measurement would give it: seeded Gaussian noise of `noise` times each
/// kernel's peak on every value, plus a uniform background holding `pedestal` of the energy,
/// clamped at zero and renormalised.
pub fn measured(grid: &PsfGrid, noise: f32, pedestal: f32, seed: u64) -> Result<PsfGrid> {
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};
    if !(noise.is_finite()
        && noise >= 0.0
        && pedestal.is_finite()
        && (0.0..1.0).contains(&pedestal))
    {
        return Err(AberrationError::BadParameter(format!(
            "measurement noise {noise} must be non-negative and the pedestal {pedestal} in [0, 1)"
        )));
    }
    let kk = grid.size() * grid.size();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let normal = Normal::new(0.0f32, 1.0).expect("unit normal");
    let mut data = grid.planar().to_vec();
    for kernel in data.chunks_mut(kk) {
        let peak = kernel.iter().cloned().fold(0.0f32, f32::max);
        for v in kernel.iter_mut() {
            let n = normal.sample(&mut rng) * noise * peak;
            *v = ((1.0 - pedestal) * *v + pedestal / kk as f32 + n).max(0.0);
        }
    }
    PsfGrid::from_planar(grid.grid(), grid.size(), data)
}
