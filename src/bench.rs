//! Where a CPU training step goes: the phases of the step the training loop takes (render,
//! blur, loss with SSIM, the blur's adjoint, render backward, Adam), timed one by one on a
//! capture's training views, at each thread count asked for. The loss phases are the training
//! objective's own stages ([`Objective::evaluate_timed`]). A measurement, not a test.

use std::time::Instant;

use splat::optim::Adam;
use splat::{Gaussians, RenderSettings, render_backward, render_for_backward};

use crate::error::{Result, TrainError};
use crate::train::config::Mode;
use crate::train::data::Dataset;
use crate::train::objective::{Objective, Stage};

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
        let recipe = crate::train::config::Recipe::for_iters(7000, false);
        let settings = RenderSettings {
            sh_degree: g.sh_degree,
            ..Default::default()
        };
        let objective = Objective {
            mode,
            lambda,
            dssim_weight: recipe.dssim_weight,
            imaging: data.imaging.as_ref(),
            width: data.width,
            height: data.height,
        };
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
            let (_, v) = objective.evaluate_timed(&out.color, view, &mut |stage| {
                let phase = match stage {
                    Stage::Blur => 1,
                    Stage::Loss => 2,
                    Stage::Adjoint => 3,
                };
                lap(phase, &mut clock);
            })?;
            let grads = render_backward(&g, &state, &v, None, None)?;
            lap(4, &mut clock);
            adam.step(&mut g, &grads.params, &recipe.lrs)?;
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
