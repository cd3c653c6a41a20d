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
    #[inline]
    fn apply(&self, p: &mut f32, g: f32, m: &mut f32, v: &mut f32) {
        // A non-finite gradient would poison the moments forever; skip that element instead.
        if !g.is_finite() {
            return;
        }
        *m = self.b1 * *m + (1.0 - self.b1) * g;
        *v = self.b2 * *v + (1.0 - self.b2) * g * g;
        let mh = *m / self.bc1;
        let vh = *v / self.bc2;
        *p -= self.lr * mh / (vh.sqrt() + self.eps);
    }

    fn vec3s(&self, p: &mut [Vec3], g: &[Vec3], m: &mut [Vec3], v: &mut [Vec3]) {
        self.lanes(p, g, m, v, |s, p, g, m, v| {
            for k in 0..3 {
                s.apply(&mut p[k], g[k], &mut m[k], &mut v[k]);
            }
        });
    }

    /// `apply` over matching elements, in parallel chunks: every element is updated on its
    /// own, so the result does not depend on the thread count.
    fn lanes<T: Send + Sync>(
        &self,
        p: &mut [T],
        g: &[T],
        m: &mut [T],
        v: &mut [T],
        f: impl Fn(&Step, &mut T, &T, &mut T, &mut T) + Sync,
    ) {
        const CHUNK: usize = 8192;
        p.par_chunks_mut(CHUNK)
            .zip(g.par_chunks(CHUNK))
            .zip(m.par_chunks_mut(CHUNK))
            .zip(v.par_chunks_mut(CHUNK))
            .for_each(|(((p, g), m), v)| {
                for (((p, g), m), v) in p.iter_mut().zip(g).zip(m.iter_mut()).zip(v.iter_mut()) {
                    f(self, p, g, m, v);
                }
            });
    }
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
        mk(lr.rotations).lanes(
            &mut params.rotations,
            &grads.rotations,
            &mut m.rotations,
            &mut v.rotations,
            |s, p, g, m, v| {
                for k in 0..4 {
                    s.apply(&mut p[k], g[k], &mut m[k], &mut v[k]);
                }
            },
        );
        mk(lr.opacities).lanes(
            &mut params.logit_opacities,
            &grads.logit_opacities,
            &mut m.logit_opacities,
            &mut v.logit_opacities,
            |s, p, g, m, v| s.apply(p, *g, m, v),
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
