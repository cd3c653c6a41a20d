//! Adam with per-parameter-group learning rates, and the 3DGS exponential position-lr schedule.
//!
//! Moments live in two [`Gaussians`] buffers of the model's shape so densification can carry
//! them along with [`Adam::remap`] (new Gaussians start from zero moments, as in gsplat).

use glam::Vec3;
use rayon::prelude::*;

use crate::error::SplatError;
use crate::model::Gaussians;

/// Learning rate per parameter group.
#[derive(Clone, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct LearningRates {
    pub means: f32,
    pub log_scales: f32,
    pub rotations: f32,
    pub opacities: f32,
    pub sh_dc: f32,
    pub sh_rest: f32,
}

impl Default for LearningRates {
    /// INRIA 3DGS defaults; `means` is the initial value before scaling by scene extent.
    fn default() -> Self {
        Self {
            means: 1.6e-4,
            log_scales: 5e-3,
            rotations: 1e-3,
            opacities: 5e-2,
            sh_dc: 2.5e-3,
            sh_rest: 2.5e-3 / 20.0,
        }
    }
}

impl LearningRates {
    /// The same rates with the position rate taken from its schedule.
    pub fn with_means(&self, means: f32) -> Self {
        Self {
            means,
            ..self.clone()
        }
    }
}

/// Log-linear interpolation from `lr_init` to `lr_final` over `max_steps`, as 3DGS
/// `get_expon_lr_func` (without the optional warm-up delay).
#[derive(Clone, Debug, PartialEq)]
pub struct ExponentialLr {
    pub lr_init: f32,
    pub lr_final: f32,
    pub max_steps: u64,
}

impl ExponentialLr {
    /// The 3DGS position schedule: 1.6e-4 → 1.6e-6 over 30k steps, times the scene extent
    /// (so the step size is relative to the scene's size).
    pub fn position(scene_extent: f32) -> Self {
        Self {
            lr_init: 1.6e-4 * scene_extent,
            lr_final: 1.6e-6 * scene_extent,
            max_steps: 30_000,
        }
    }

    pub fn at(&self, step: u64) -> f32 {
        if self.lr_init <= 0.0 || self.lr_final <= 0.0 || self.max_steps == 0 {
            return 0.0;
        }
        let t = (step as f64 / self.max_steps as f64).clamp(0.0, 1.0);
        let (a, b) = ((self.lr_init as f64).ln(), (self.lr_final as f64).ln());
        (a + (b - a) * t).exp() as f32
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ParamGroup {
    Means,
    LogScales,
    Rotations,
    Opacities,
    ShDc,
    ShRest,
}

#[derive(Clone, Debug)]
pub struct Adam {
    pub beta1: f32,
    pub beta2: f32,
    pub eps: f32,
    step: u64,
    m: Gaussians,
    v: Gaussians,
}

struct Step {
    lr: f32,
    b1: f32,
    b2: f32,
    eps: f32,
    bc1: f32,
    bc2: f32,
}

impl Step {
    /// One group's update over matching elements, in parallel chunks: every element is
    /// updated on its own, so the result does not depend on the thread count.
    fn run(&self, p: &mut [f32], g: &[f32], m: &mut [f32], v: &mut [f32]) {
        const CHUNK: usize = 8192;
        p.par_chunks_mut(CHUNK)
            .zip(g.par_chunks(CHUNK))
            .zip(m.par_chunks_mut(CHUNK))
            .zip(v.par_chunks_mut(CHUNK))
            .for_each(|(((p, g), m), v)| adam_chunk(self, p, g, m, v));
    }

    fn vec3s(&self, p: &mut [Vec3], g: &[Vec3], m: &mut [Vec3], v: &mut [Vec3]) {
        self.run(flat_mut(p), flat(g), flat_mut(m), flat_mut(v));
    }
}

base::simd_builds! {
/// The Adam update of one chunk, without branches so that it vectorises: a non-finite
/// gradient would poison the moments forever, so such an element keeps its parameter and
/// moments (selected, not branched around). Compiled for several instruction sets and chosen
/// at run time; separate multiplies and adds (never fused) and exact division and square
/// root give the same bits in each.
fn adam_chunk(s: &Step, p: &mut [f32], g: &[f32], m: &mut [f32], v: &mut [f32]) {
    let n = p.len().min(g.len()).min(m.len()).min(v.len());
    let (p, g, m, v) = (&mut p[..n], &g[..n], &mut m[..n], &mut v[..n]);
    for i in 0..n {
        let gi = g[i];
        let mi = s.b1 * m[i] + (1.0 - s.b1) * gi;
        let vi = s.b2 * v[i] + (1.0 - s.b2) * gi * gi;
        let mh = mi / s.bc1;
        let vh = vi / s.bc2;
        let pi = p[i] - s.lr * mh / (vh.sqrt() + s.eps);
        let ok = gi.is_finite();
        m[i] = if ok { mi } else { m[i] };
        v[i] = if ok { vi } else { v[i] };
        p[i] = if ok { pi } else { p[i] };
    }
}
}

/// The floats of a slice of `Vec3`s (`#[repr(C)]`, three `f32`s, no padding).
fn flat(v: &[Vec3]) -> &[f32] {
    const _: () = assert!(std::mem::size_of::<Vec3>() == 12);
    // SAFETY: Vec3 is three f32s in a row, aligned as f32.
    unsafe { std::slice::from_raw_parts(v.as_ptr().cast(), 3 * v.len()) }
}

fn flat_mut(v: &mut [Vec3]) -> &mut [f32] {
    // SAFETY: as in `flat`, and the borrow is exclusive.
    unsafe { std::slice::from_raw_parts_mut(v.as_mut_ptr().cast(), 3 * v.len()) }
}

impl Adam {
    /// 3DGS settings: β = (0.9, 0.999), ε = 1e-15.
    pub fn new(model: &Gaussians) -> Self {
        Self {
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-15,
            step: 0,
            m: Gaussians::zeros(model.len(), model.sh_degree),
            v: Gaussians::zeros(model.len(), model.sh_degree),
        }
    }

    pub fn steps_taken(&self) -> u64 {
        self.step
    }

    /// One Adam step on every group. `grads` and the optimiser state must have the model's
    /// shape (after densification, call [`Adam::remap`] first).
    pub fn step(
        &mut self,
        params: &mut Gaussians,
        grads: &Gaussians,
        lr: &LearningRates,
    ) -> Result<(), SplatError> {
        params.validate()?;
        grads.validate()?;
        for (what, got) in [
            ("optimiser state", self.m.len()),
            ("gradients", grads.len()),
        ] {
            if got != params.len() {
                return Err(SplatError::SizeMismatch {
                    what,
                    expected: params.len(),
                    got,
                });
            }
        }
        if grads.sh_degree != params.sh_degree || self.m.sh_degree != params.sh_degree {
            return Err(SplatError::InvalidInput(
                "SH degree of gradients or optimiser state differs from the model".into(),
            ));
        }
        self.step += 1;
        let t = self.step as i32;
        let mk = |lr| Step {
            lr,
            b1: self.beta1,
            b2: self.beta2,
            eps: self.eps,
            bc1: 1.0 - self.beta1.powi(t),
            bc2: 1.0 - self.beta2.powi(t),
        };
        let (m, v) = (&mut self.m, &mut self.v);
        mk(lr.means).vec3s(&mut params.means, &grads.means, &mut m.means, &mut v.means);
        mk(lr.log_scales).vec3s(
            &mut params.log_scales,
            &grads.log_scales,
            &mut m.log_scales,
            &mut v.log_scales,
        );
        mk(lr.rotations).run(
            params.rotations.as_flattened_mut(),
            grads.rotations.as_flattened(),
            m.rotations.as_flattened_mut(),
            v.rotations.as_flattened_mut(),
        );
        mk(lr.opacities).run(
            &mut params.logit_opacities,
            &grads.logit_opacities,
            &mut m.logit_opacities,
            &mut v.logit_opacities,
        );
        mk(lr.sh_dc).vec3s(&mut params.sh_dc, &grads.sh_dc, &mut m.sh_dc, &mut v.sh_dc);
        mk(lr.sh_rest).vec3s(
            &mut params.sh_rest,
            &grads.sh_rest,
            &mut m.sh_rest,
            &mut v.sh_rest,
        );
        Ok(())
    }

    /// Re-indexes the moments after densification: new Gaussian `i` takes the moments of old
    /// Gaussian `sources[i]`, or zeros when `None`.
    pub fn remap(&mut self, sources: &[Option<usize>]) -> Result<(), SplatError> {
        let n = self.m.len();
        if let Some(bad) = sources.iter().flatten().find(|&&i| i >= n) {
            return Err(SplatError::InvalidInput(format!(
                "remap source {bad} out of range for {n} Gaussians"
            )));
        }
        for buf in [&mut self.m, &mut self.v] {
            let mut out = Gaussians::zeros(0, buf.sh_degree);
            let zero = Gaussians::zeros(1, buf.sh_degree);
            for s in sources {
                match s {
                    Some(i) => out.push_from(buf, *i),
                    None => out.push_from(&zero, 0),
                }
            }
            *buf = out;
        }
        Ok(())
    }

    /// The moments `(m, v)`, for checkpoints.
    pub fn moments(&self) -> (&Gaussians, &Gaussians) {
        (&self.m, &self.v)
    }

    /// Rebuilds an optimiser from a checkpoint (3DGS β and ε); the moments must share a shape.
    pub fn from_state(step: u64, m: Gaussians, v: Gaussians) -> Result<Self, SplatError> {
        m.validate()?;
        v.validate()?;
        if m.len() != v.len() || m.sh_degree != v.sh_degree {
            return Err(SplatError::InvalidInput(
                "Adam moments m and v differ in shape".into(),
            ));
        }
        let mut adam = Adam::new(&Gaussians::new(m.sh_degree));
        adam.step = step;
        adam.m = m;
        adam.v = v;
        Ok(adam)
    }

    /// Follows [`Gaussians::set_sh_degree`]: new bands start with zero moments.
    pub fn set_sh_degree(&mut self, degree: u32) {
        self.m.set_sh_degree(degree);
        self.v.set_sh_degree(degree);
    }

    /// Zeroes the moments of one group (3DGS does this for opacities after an opacity reset).
    pub fn reset_group(&mut self, group: ParamGroup) {
        for buf in [&mut self.m, &mut self.v] {
            match group {
                ParamGroup::Means => buf.means.fill(Vec3::ZERO),
                ParamGroup::LogScales => buf.log_scales.fill(Vec3::ZERO),
                ParamGroup::Rotations => buf.rotations.fill([0.0; 4]),
                ParamGroup::Opacities => buf.logit_opacities.fill(0.0),
                ParamGroup::ShDc => buf.sh_dc.fill(Vec3::ZERO),
                ParamGroup::ShRest => buf.sh_rest.fill(Vec3::ZERO),
            }
        }
    }
}
