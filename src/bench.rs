//! Where a CPU training step goes: the phases of the step the training loop takes (render,
//! blur, loss with SSIM, the blur's adjoint, render backward, Adam), timed one by one on a
//! capture's training views, at each thread count asked for. A measurement, not a test.

use std::time::Instant;

use glam::Vec3;
use splat::optim::Adam;
use splat::{Gaussians, RenderSettings, render_backward, render_for_backward};

use crate::error::{Result, TrainError};
use crate::train::config::Mode;
use crate::train::data::Dataset;

/// The phases of a step, in the order they run.
pub const PHASES: [&str; 6] = [
    "render forward",
    "PSF blur",
    "loss (L1 + SSIM, value and gradient)",
    "blur adjoint",
    "render backward",
    "Adam",
];

/// Mean milliseconds per step of each phase (wall clock), for one thread count.
#[derive(Clone, Debug)]
pub struct StepTimes {
    pub threads: usize,
    pub steps: usize,
    pub phases: [f64; 6],
}

impl StepTimes {
    pub fn total(&self) -> f64 {
        self.phases.iter().sum()
    }
}

/// Times `steps` training steps of `mode` on `model` (cycling through the training views) with
/// `threads` worker threads. The model is updated by Adam as in training, from the same start
/// at every thread count.
pub fn time_steps(
    data: &Dataset,
    mode: Mode,
    lambda: f32,
    model: &Gaussians,
    steps: usize,
    threads: usize,
) -> Result<StepTimes> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| TrainError::Invalid(format!("cannot start {threads} threads: {e}")))?;
    pool.install(|| {
        let mut g = model.clone();
        let mut adam = Adam::new(&g);
        let lrs = crate::train::config::Recipe::for_iters(7000, false).lrs;
        let settings = RenderSettings {
            sh_degree: g.sh_degree,
            ..Default::default()
        };
        let (w, h) = (data.width, data.height);
        let mut t = [0.0f64; 6];
        let mut lap = |i: usize, start: &mut Instant| {
            t[i] += start.elapsed().as_secs_f64() * 1e3;
            *start = Instant::now();
        };
        for k in 0..steps {
            let view = &data.train[k % data.train.len()];
            let mut clock = Instant::now();
            let (out, state) = render_for_backward(&g, &view.camera, &settings)?;
            lap(0, &mut clock);
            let imaging = data.imaging.as_ref();
            let observed_render = match (mode, imaging) {
                (Mode::Aware, Some(m)) => m.blur_pixels(&out.color)?,
                _ => out.color.clone(),
            };
            lap(1, &mut clock);
            let target = match mode {
                Mode::Restored => view.restored.as_deref().unwrap_or(&view.observed),
                _ => &view.observed,
            };
            let main = splat::loss::photometric_loss(&observed_render, target, w, h, 0.2)?;
            let side = match (mode, view.restored.as_deref()) {
                (Mode::Aware, Some(r)) if lambda != 0.0 => {
                    Some(splat::loss::photometric_loss(&out.color, r, w, h, 0.2)?)
                }
                _ => None,
            };
            lap(2, &mut clock);
            let mut v: Vec<Vec3> = match (mode, imaging) {
                (Mode::Aware, Some(m)) => m.plan().adjoint_pixels(&main.grad)?,
                _ => main.grad,
            };
            if let Some(s) = side {
                for (a, b) in v.iter_mut().zip(&s.grad) {
                    *a += *b * lambda;
                }
            }
            lap(3, &mut clock);
            let grads = render_backward(&g, &state, &v, None, None)?;
            lap(4, &mut clock);
            adam.step(&mut g, &grads.params, &lrs)?;
            lap(5, &mut clock);
        }
        let n = steps.max(1) as f64;
        Ok(StepTimes {
            threads,
            steps,
            phases: t.map(|v| v / n),
        })
    })
}
