//! The training loop: render a view, score it with the mode's objective, backpropagate
//! through the renderer, step Adam, and let the densification strategy and the SH-band
//! controller act at their hooks. Deterministic for a seed, and resumable bit for bit.

pub mod checkpoint;
pub mod config;
pub mod data;
pub mod densify;
pub mod iac_cache;
pub mod objective;
pub mod sh;

use std::path::Path;
use std::time::Instant;

use base::SplitMix64;
use glam::Vec3;
use serde::{Deserialize, Serialize};
use splat::gpu::GpuTraining;
use splat::optim::{Adam, ExponentialLr};
use splat::{CpuRasterizer, Gaussians, PixelGradients, RenderSettings};

use crate::device::{Device, forward_backward};

use crate::error::{Result, TrainError};
use crate::eval::{self, Metrics};
use checkpoint::State;
use config::TrainConfig;
use data::Dataset;
use densify::{Densifier, Edit};
use objective::{LossParts, Objective};
use sh::{ShBands, ShEvent};

/// One line of `train_log.csv`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LogRow {
    pub step: u64,
    /// Training time so far (evaluation and checkpoint writing excluded).
    pub seconds: f64,
    pub loss: f32,
    pub train_psnr: f64,
    pub test_psnr: Option<f64>,
    pub test_ssim: Option<f64>,
    pub splats: usize,
    pub sh_degree: u32,
}

/// What the loop reports as it goes.
pub enum Event<'a> {
    Step {
        step: u64,
        loss: &'a LossParts,
        splats: usize,
        sh_degree: u32,
        seconds: f64,
    },
    Evaluated {
        step: u64,
        metrics: &'a Metrics,
    },
    Densified {
        step: u64,
        edit: Edit,
        splats: usize,
    },
    Unseen {
        step: u64,
        pruned: usize,
    },
    Sh {
        step: u64,
        event: ShEvent,
    },
    Checkpoint {
        step: u64,
    },
}

pub struct Outcome {
    pub model: Gaussians,
    pub log: Vec<LogRow>,
    pub train_seconds: f64,
    pub settings: RenderSettings,
    /// Splats removed at the end because they could never be blended (α < 1/255).
    pub final_pruned: usize,
    pub sh_events: Vec<ShEvent>,
    pub resumed_from: Option<u64>,
}

/// View `step` visits: a fresh seeded permutation of the training views each epoch.
pub fn view_index(seed: u64, step: u64, n: usize) -> usize {
    let epoch = step / n as u64;
    let mut order: Vec<usize> = (0..n).collect();
    let mut rng = SplitMix64::new(seed ^ epoch.wrapping_mul(base::rng::GOLDEN_GAMMA));
    for i in (1..n).rev() {
        order.swap(i, (rng.next_u64() % (i as u64 + 1)) as usize);
    }
    order[(step % n as u64) as usize]
}

fn settings(config: &TrainConfig, model: &Gaussians) -> RenderSettings {
    RenderSettings {
        sh_degree: model.sh_degree,
        background: Vec3::from_array(config.background),
        antialiased: false,
    }
}

/// Names the settings that differ between two configs (for `--resume`).
fn config_differences(a: &TrainConfig, b: &TrainConfig) -> Vec<String> {
    let (a, b) = (serde_json::to_value(a), serde_json::to_value(b));
    let (Ok(serde_json::Value::Object(a)), Ok(serde_json::Value::Object(b))) = (a, b) else {
        return vec!["config".into()];
    };
    a.iter()
        .filter(|(k, v)| b.get(*k) != Some(*v))
        .map(|(k, v)| {
            format!(
                "{k} (checkpoint {}, now {v})",
                b.get(k).cloned().unwrap_or_default()
            )
        })
        .collect()
}

fn fresh_state(config: &TrainConfig, data: &Dataset) -> Result<State> {
    let model = match &data.initial {
        Some(g) => {
            let mut g = g.clone();
            if g.sh_degree > config.max_sh_degree {
                g.set_sh_degree(config.max_sh_degree);
            }
            g
        }
        None if data.points.is_empty() => {
            return Err(TrainError::file(&data.capture.root, "no initial points"));
        }
        None => crate::init::from_points(
            &crate::init::within_budget(&data.points, config.max_splats, config.seed),
            0,
        ),
    };
    let n = model.len();
    Ok(State {
        config: config.clone(),
        step: 0,
        train_seconds: 0.0,
        adam: Adam::new(&model),
        densifier: Densifier::new(config.recipe.clone(), config.max_splats, data.extent, n),
        sh: ShBands::new(
            config.max_sh_degree,
            config.recipe.sh_every,
            config.recipe.sh_min_gain,
        ),
        log: Vec::new(),
        model,
    })
}

fn gradients_finite(g: &splat::Gradients) -> bool {
    g.params.is_finite()
        && g.means2d
            .iter()
            .chain(&g.means2d_abs)
            .flatten()
            .all(|v| v.is_finite())
}

/// Trains on `data`. With `checkpoint_path`, saves there every `checkpoint_every` steps;
/// with `resume` too, continues from the checkpoint if one exists (same config required).
pub fn train(
    config: &TrainConfig,
    data: &Dataset,
    device: &Device,
    checkpoint_path: Option<&Path>,
    resume: bool,
    on_event: &mut dyn FnMut(Event),
) -> Result<Outcome> {
    let (mut s, resumed_from) = match checkpoint_path {
        Some(p) if resume && p.exists() => {
            let mut s = checkpoint::load(p)?;
            let diff = config_differences(config, &s.config);
            if !diff.is_empty() {
                return Err(TrainError::file(
                    p,
                    format!("cannot resume with other settings: {}", diff.join("; ")),
                ));
            }
            s.densifier.extent = data.extent;
            let from = s.step;
            (s, Some(from))
        }
        _ => (fresh_state(config, data)?, None),
    };
    let objective = Objective {
        mode: config.mode,
        lambda: config.lambda,
        dssim_weight: config.recipe.dssim_weight,
        imaging: data.imaging.as_ref(),
        width: data.width,
        height: data.height,
    };
    let lrs = &config.recipe.lrs;
    let position_lr = ExponentialLr {
        lr_init: lrs.means * data.extent,
        lr_final: lrs.means * data.extent * config.recipe.position_lr_final_ratio,
        max_steps: config.iters,
    };
    let n_views = data.train.len();
    let mut sh_events = Vec::new();
    // Mean training loss over (up to 8, evenly spread) training views at a given SH degree.
    let probe: Vec<usize> = (0..n_views.min(8))
        .map(|k| k * n_views / n_views.min(8))
        .collect();
    let mut loss_at = |model: &Gaussians, degree: u32| -> Result<f64> {
        let rs = RenderSettings {
            sh_degree: degree,
            ..settings(config, model)
        };
        let mut sum = 0.0;
        for &i in &probe {
            let out = device.render(model, &data.train[i].camera, &rs)?;
            sum += objective.value(&out.color, &data.train[i])? as f64;
        }
        Ok(sum / probe.len() as f64)
    };

    let mut resident: Option<GpuTraining> = None;
    while s.step < config.iters {
        let started = Instant::now();
        let view = &data.train[view_index(config.seed, s.step, n_views)];
        let rs = settings(config, &s.model);
        // The first non-finite value stops the run before it reaches the model or a checkpoint
        // (the last checkpoint written stays the last good one).
        let at = |what: &str, cause: &str| {
            TrainError::Invalid(format!(
                "step {}: {what} is not finite (view {}); {cause}. The last checkpoint is kept",
                s.step + 1,
                view.name
            ))
        };
        let objective = Objective {
            lambda: config.lambda_at(s.step),
            ..objective
        };
        let lr = lrs.with_means(position_lr.at(s.step));
        let check_loss = |parts: &LossParts| {
            if parts.total.is_finite() {
                Ok(())
            } else {
                Err(at(
                    "the loss",
                    "a non-finite pixel in the capture's images or I_ac, or a huge --lambda, is the likely cause",
                ))
            }
        };
        let not_finite_gradient = || {
            at(
                "a gradient",
                "a degenerate splat or camera is the likely cause",
            )
        };
        let not_finite_parameter = || {
            at(
                "a parameter after the update",
                "a learning rate too large for the scene is the likely cause",
            )
        };
        let (out, parts, means2d) = match device {
            // The model and its optimiser stay on the GPU between the steps that need them here.
            Device::Gpu(gpu) => {
                if resident.is_none() {
                    resident = Some(GpuTraining::new(gpu, &s.model, &s.adam)?);
                }
                let r = resident.as_mut().expect("uploaded above");
                let (out, saved) = r.render_for_backward(&view.camera, &rs)?;
                let (parts, v) = objective.evaluate(&out.color, view)?;
                check_loss(&parts)?;
                let report = r.step(&saved, PixelGradients::color(&v), &lr, config.opacity_reg)?;
                if report.nonfinite_gradient {
                    return Err(not_finite_gradient());
                }
                if report.nonfinite_parameter {
                    return Err(not_finite_parameter());
                }
                (out, parts, report.means2d)
            }
            Device::Cpu => {
                let (out, parts, mut grads) =
                    forward_backward(&CpuRasterizer, &s.model, &view.camera, &rs, |out| {
                        let (parts, v) = objective.evaluate(&out.color, view)?;
                        check_loss(&parts)?;
                        Ok((parts, v))
                    })?;
                if !gradients_finite(&grads) {
                    return Err(not_finite_gradient());
                }
                if config.opacity_reg > 0.0 {
                    // d/dx of reg·mean(sigmoid(x)): a splat no view needs has no other
                    // gradient, so Adam turns even this small one into full steps towards
                    // transparency.
                    let k = config.opacity_reg / s.model.len().max(1) as f32;
                    for (g, &x) in grads
                        .params
                        .logit_opacities
                        .iter_mut()
                        .zip(&s.model.logit_opacities)
                    {
                        let o = splat::model::sigmoid(x);
                        *g += k * o * (1.0 - o);
                    }
                }
                s.adam.step(&mut s.model, &grads.params, &lr)?;
                if !s.model.is_finite() {
                    return Err(not_finite_parameter());
                }
                (out, parts, grads.means2d)
            }
        };
        s.densifier.after_backward(s.step, &means2d, &out);
        drop((out, means2d));
        s.step += 1;
        let step = s.step;
        let eval_now =
            step == config.iters || (config.eval_every > 0 && step % config.eval_every == 0);
        let checkpoint_now = checkpoint_path.is_some()
            && config.checkpoint_every > 0
            && (step % config.checkpoint_every == 0 || step == config.iters);
        let epoch_end = step % n_views as u64 == 0;
        // The hooks below read the host model: bring it back from the GPU when one will.
        if let Some(r) = &resident
            && (eval_now
                || checkpoint_now
                || s.sh.acts_at(step)
                || s.densifier.acts_at(step)
                || (epoch_end && s.densifier.has_unseen()))
        {
            (s.model, s.adam) = r.download()?;
        }
        let mut edited = false;
        // SH bands are judged before densification acts on this step: an opacity reset falling
        // on the same step would leave the probes comparing two nearly transparent models, and
        // every band would look worthless.
        for event in
            s.sh.after_step(step, &mut s.model, &mut s.adam, &mut loss_at)?
        {
            sh_events.push(event);
            on_event(Event::Sh { step, event });
            edited = true;
        }
        if let Some(edit) = s
            .densifier
            .after_step(step, &mut s.model, &mut s.adam, config.seed)?
        {
            edited = true;
            on_event(Event::Densified {
                step,
                edit,
                splats: s.model.len(),
            });
        }
        if epoch_end {
            let pruned = s.densifier.end_of_epoch(&mut s.model, &mut s.adam)?;
            if pruned > 0 {
                edited = true;
                on_event(Event::Unseen { step, pruned });
            }
        }
        if edited {
            resident = None;
        }
        s.train_seconds += started.elapsed().as_secs_f64();
        on_event(Event::Step {
            step,
            loss: &parts,
            splats: s.model.len(),
            sh_degree: s.model.sh_degree,
            seconds: s.train_seconds,
        });

        if eval_now {
            let metrics =
                eval::evaluate(&s.model, &data.test, &settings(config, &s.model), device)?;
            if let Some(m) = &metrics {
                on_event(Event::Evaluated { step, metrics: m });
            }
            s.log.push(LogRow {
                step,
                seconds: s.train_seconds,
                loss: parts.total,
                train_psnr: parts.psnr,
                test_psnr: metrics.as_ref().map(|m| m.mean_psnr),
                test_ssim: metrics.as_ref().map(|m| m.mean_ssim),
                splats: s.model.len(),
                sh_degree: s.model.sh_degree,
            });
        }
        if let Some(p) = checkpoint_path
            && checkpoint_now
        {
            checkpoint::save(p, &s)?;
            on_event(Event::Checkpoint { step });
        }
    }

    let final_pruned = s.densifier.finish(&mut s.model, &mut s.adam)?;
    for event in s.sh.finish(&mut s.model, &mut s.adam, &mut loss_at)? {
        sh_events.push(event);
        on_event(Event::Sh {
            step: s.step,
            event,
        });
    }
    Ok(Outcome {
        settings: settings(config, &s.model),
        model: s.model,
        log: s.log,
        train_seconds: s.train_seconds,
        final_pruned,
        sh_events,
        resumed_from,
    })
}
