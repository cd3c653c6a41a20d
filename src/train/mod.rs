//! The training loop: render a view, score it with the mode's objective at the step's λ,
//! step the [`SplatTrainer`] (backward, Adam), and let the densification strategy and the
//! SH-band schedule act at their hooks. Deterministic for a seed, and resumable bit for bit.

pub mod capture;
pub mod checkpoint;
pub mod coarse;
pub mod config;
pub mod data;
pub mod decisions;
pub mod densify;
pub mod eval;
pub mod iac;
pub mod iac_cache;
pub mod levels;
pub mod object;
pub mod objective;
pub mod psf_refine;
pub mod sh;
pub mod stop;
pub(crate) mod timing;

use std::path::Path;
use std::time::Instant;

use base::SplitMix64;
use glam::Vec3;
use serde::{Deserialize, Serialize};
use splat::gpu::GpuTrainer;
use splat::optim::{Adam, ExponentialLr};
use splat::{CpuTrainer, Gaussians, PixelGradients, Regularisers, RenderSettings, SplatTrainer};

use crate::error::{Result, TrainError};
use crate::splats::device::Device;
use checkpoint::{Progress, State};
use config::{Strategy, TrainConfig};
use data::Dataset;
use densify::{DensifyStrategy, Edit, Mcmc, Unseen};
use eval::Metrics;
use object::ObjectTargets;
use objective::{LossParts, Objective};
use psf_refine::PsfRefinement;
use sh::{ShEvent, ShSchedule, ShState};

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
        done: Unseen,
    },
    Sh {
        step: u64,
        event: ShEvent,
    },
    Checkpoint {
        step: u64,
    },
    /// `--iters auto`: training stopped paying after `step`; a final phase runs to `end`.
    Stopping {
        step: u64,
        end: u64,
        reason: &'a str,
    },
    /// The run's log so far, after each evaluation added its row (for a log file that can be
    /// followed while the run trains).
    Logged {
        rows: &'a [LogRow],
    },
    /// The splats after a step `--save-at` names, for the caller to keep.
    Snapshot {
        step: u64,
        model: &'a Gaussians,
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
    /// Steps trained: the config's count, or where `--iters auto`'s rule ended the run.
    pub steps: u64,
    /// With `--iters auto`: at which step the rule fired and why.
    pub stopped: Option<String>,
    /// With `--refine-psf`: the supplied grid and the refined one, at the image's scale.
    pub psf: Option<(aberration::PsfGrid, aberration::PsfGrid)>,
    /// With `--refine-psf warp`: the warp learnt.
    pub psf_warp: Option<psf_refine::WarpSummary>,
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

/// Names the settings that differ between two configs (for `--resume`), one leaf each
/// (`recipe.densify_until (checkpoint 500, now 1000)`), so a refusal reads as a sentence
/// instead of two copies of a nested setting.
pub fn config_differences(a: &TrainConfig, b: &TrainConfig) -> Vec<String> {
    use serde_json::Value;
    fn walk(path: &str, now: &Value, then: &Value, out: &mut Vec<String>) {
        match (now, then) {
            (Value::Object(a), Value::Object(b)) => {
                for key in a.keys().chain(b.keys().filter(|k| !a.contains_key(*k))) {
                    let sub = if path.is_empty() {
                        key.clone()
                    } else {
                        format!("{path}.{key}")
                    };
                    let (x, y) = (a.get(key), b.get(key));
                    // A checkpoint from before the capture was recorded cannot tell.
                    if sub == "capture" && y.is_none_or(Value::is_null) {
                        continue;
                    }
                    walk(
                        &sub,
                        x.unwrap_or(&Value::Null),
                        y.unwrap_or(&Value::Null),
                        out,
                    );
                }
            }
            _ if now != then => out.push(format!("{path} (checkpoint {then}, now {now})")),
            _ => {}
        }
    }
    // An extended run is the same run as the one it extends: only its length differs. When
    // the splats are kept, checkpointed and evaluated changes no splat: a resume may change
    // them.
    let same_length = |c: &TrainConfig| TrainConfig {
        iters: c.schedule_iters.unwrap_or(c.iters),
        schedule_iters: None,
        save_at: Vec::new(),
        checkpoint_every: 0,
        eval_every: 0,
        decisions: Vec::new(),
        ..c.clone()
    };
    let (a, b) = (same_length(a), same_length(b));
    let (Ok(a), Ok(b)) = (serde_json::to_value(&a), serde_json::to_value(&b)) else {
        return vec!["config".into()];
    };
    let mut out = Vec::new();
    walk("", &a, &b, &mut out);
    out
}

/// Where a run starts: its first model (the capture's points or `--init`, within the budget)
/// with a fresh optimiser and no progress.
fn fresh_start(config: &TrainConfig, data: &Dataset, densify: &DensifyStrategy) -> Result<State> {
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
        None => {
            let cloud =
                crate::splats::init::within_budget(&data.points, config.max_splats, config.seed);
            let mut g = crate::splats::init::from_points(&cloud, 0);
            densify.prepare_initial(&mut g);
            g
        }
    };
    Ok(State {
        config: config.clone(),
        progress: Progress {
            step: 0,
            train_seconds: 0.0,
            densify: densify.initialize_state(model.len()),
            sh: ShState::default(),
            log: Vec::new(),
            psf: None,
            stop: Default::default(),
        },
        adam: Adam::new(&model),
        model,
        psf: None,
    })
}

/// What stays fixed through a run: its settings, data, objective, schedules and strategy.
struct Run<'a> {
    config: &'a TrainConfig,
    data: &'a Dataset,
    /// Renders the SH-band probes and the held-out views.
    device: &'a Device,
    /// The mode's objective at the configured λ; [`Run::objective_at`] gives a step's.
    objective: Objective<'a>,
    position_lr: ExponentialLr,
    densify: DensifyStrategy,
    sh: ShSchedule,
    /// The training views the SH-band probes render: up to 8, evenly spread.
    probe: Vec<usize>,
    checkpoint_path: Option<&'a Path>,
    /// `--mask-mode object`: how the training views become the object's targets.
    object: Option<ObjectTargets>,
    /// `--coarse-to-fine`: the training views and lens of each smaller resolution, coarsest
    /// first (empty without it).
    levels: Vec<levels::Level>,
}

impl<'a> Run<'a> {
    fn new(
        config: &'a TrainConfig,
        data: &'a Dataset,
        device: &'a Device,
        checkpoint_path: Option<&'a Path>,
    ) -> Result<Self> {
        let recipe = &config.recipe;
        let n_views = data.train.len();
        let position_lr = ExponentialLr {
            lr_init: recipe.lrs.means * data.extent,
            lr_final: recipe.lrs.means * data.extent * recipe.position_lr_final_ratio,
            max_steps: config.schedule_iters.unwrap_or(config.iters),
        };
        let budget = densify::Budget {
            max: config.max_splats,
            coarse: config.coarse.clone(),
        };
        let densify = match &config.strategy {
            Strategy::Adaptive => DensifyStrategy::new(recipe.clone(), budget.clone(), data.extent),
            Strategy::Mcmc(m) => DensifyStrategy::Mcmc(Mcmc {
                recipe: m.clone(),
                budget: budget.clone(),
                position_lr: position_lr.clone(),
            }),
        };
        Ok(Run {
            object: ObjectTargets::for_run(config, data)?,
            levels: levels::Level::for_run(config, data)?,
            config,
            data,
            device,
            objective: Objective {
                mode: config.mode,
                lambda: config.lambda,
                dssim_weight: recipe.dssim_weight,
                imaging: data.imaging.as_ref(),
                width: data.width,
                height: data.height,
                outside: objective::outside_colour(config, data.composited_over),
            },
            position_lr,
            densify,
            sh: ShSchedule::new(config.max_sh_degree, recipe.sh_every, recipe.sh_min_gain),
            probe: (0..n_views.min(8))
                .map(|k| k * n_views / n_views.min(8))
                .collect(),
            checkpoint_path,
        })
    }

    /// Training view `index` as step training compares a render drawn over `background` with:
    /// the object's targets in `object` mask mode, the view itself otherwise.
    /// At a coarse `level`, its shrunk copy of the view.
    fn train_view<'b>(
        &'b self,
        index: usize,
        background: Vec3,
        level: Option<&'b levels::Level>,
    ) -> std::borrow::Cow<'b, data::View> {
        let (view, object) = match level {
            Some(l) => (&l.train[index], &l.object),
            None => (&self.data.train[index], &self.object),
        };
        match object {
            Some(o) => o.view(index, view, background),
            None => std::borrow::Cow::Borrowed(view),
        }
    }

    /// The coarse level step `step` trains at; None: full size.
    fn level_at(&self, step: u64) -> Option<&levels::Level> {
        let factor = self.config.coarse.as_ref()?.factor_at(step);
        self.levels.iter().find(|l| l.factor == factor)
    }

    /// The objective step `step` minimises (λ may fade), through the PSF grid as refined so
    /// far when it is; at a coarse `level`, at its size through its shrunk lens (a grid being
    /// refined is refined at full size only).
    fn objective_at<'b>(
        &'b self,
        step: u64,
        psf: Option<&'b PsfRefinement>,
        level: Option<&'b levels::Level>,
    ) -> Objective<'b> {
        let lambda = self.config.lambda_at(step);
        match level {
            None => Objective {
                lambda,
                imaging: psf.map(PsfRefinement::imaging).or(self.objective.imaging),
                ..self.objective
            },
            Some(l) => Objective {
                lambda,
                imaging: l.imaging.as_ref(),
                width: l.width,
                height: l.height,
                ..self.objective
            },
        }
    }

    fn settings(&self, sh_degree: u32) -> RenderSettings {
        RenderSettings {
            sh_degree,
            background: Vec3::from_array(self.config.background),
            antialiased: false,
        }
    }

    /// What training step `step` renders with: the run's background, or that step's own
    /// under `--background random`.
    fn step_settings(&self, sh_degree: u32, step: u64) -> RenderSettings {
        let mut s = self.settings(sh_degree);
        if self.config.random_background {
            s.background = Vec3::from_array(config::random_background(self.config.seed, step));
        }
        s
    }

    /// What an SH band is judged on after `step` steps: the mean loss of the probe views
    /// rendered with `degree` bands, under the objective the next step minimises (at its
    /// coarse level's size: a model fitted at a quarter of the size is not judged on detail
    /// it has not been shown yet).
    fn band_loss<'b>(
        &'b self,
        step: u64,
        psf: Option<&'b PsfRefinement>,
    ) -> impl FnMut(&Gaussians, u32) -> Result<f64> + 'b {
        let level = self.level_at(step);
        let objective = self.objective_at(step, psf, level);
        move |model, degree| {
            let mut sum = 0.0;
            for &i in &self.probe {
                let settings = self.settings(degree);
                let view = self.train_view(i, settings.background, level);
                let out = self.device.render(model, &view.camera, &settings)?;
                sum += objective.value(&out.color, &view)? as f64;
            }
            Ok(sum / self.probe.len() as f64)
        }
    }

    /// One step: render a view, score it, backpropagate and update, and let densification
    /// read the screen-space gradients. The first non-finite value stops the run before it
    /// reaches the model or a checkpoint.
    fn step<T: SplatTrainer>(&self, t: &mut T, p: &mut Progress) -> Result<LossParts> {
        let n_views = self.data.train.len();
        let settings = self.step_settings(t.sh_degree(), p.step);
        let level = self.level_at(p.step);
        let view = self.train_view(
            view_index(self.config.seed, p.step, n_views),
            settings.background,
            level,
        );
        let view = view.as_ref();
        let at = |what: &str, cause: &str| {
            TrainError::Invalid(format!(
                "step {}: {what} is not finite (view {}); {cause}. This step reached neither the model nor a checkpoint",
                p.step + 1,
                view.name
            ))
        };
        let (out, saved) = t.render(&view.camera, &settings)?;
        let refine_now = self
            .config
            .refine_psf
            .is_some_and(|r| p.psf.is_some() && level.is_none() && r.updates_at(p.step));
        let (parts, v, psf_gradient) = self
            .objective_at(p.step, p.psf.as_ref(), level)
            .evaluate_with_psf(&out.color, view, refine_now)?;
        if !parts.total.is_finite() {
            return Err(at(
                "the loss",
                "a non-finite pixel in the capture's images or I_ac, a huge --lambda, or an --init scene whose values overflow, is the likely cause",
            ));
        }
        // The final phase of an `--iters auto` run trains at the final position rate.
        let means_lr = if p.stop.end.is_some() {
            self.position_lr.lr_final
        } else {
            self.position_lr.at(p.step)
        };
        let lr = self.config.recipe.lrs.with_means(means_lr);
        let penalty = self.config.penalty_weight_at(p.step);
        let report = t.step(
            saved,
            PixelGradients::color(&v),
            &lr,
            Regularisers {
                opacity: self.config.opacity_reg_at(p.step) * penalty,
                scale: self.config.scale_reg * penalty,
            },
        )?;
        if report.nonfinite_gradient {
            return Err(at(
                "a gradient",
                "a degenerate splat or camera is the likely cause",
            ));
        }
        if report.nonfinite_parameter {
            return Err(at(
                "a parameter after the update",
                "a learning rate too large for the scene is the likely cause",
            ));
        }
        if let (Some(g), Some(psf)) = (psf_gradient, p.psf.as_mut()) {
            tracing::info_span!("PSF update").in_scope(|| psf.update(&g))?;
        }
        let _span = tracing::info_span!("densification statistics").entered();
        self.densify
            .after_backward(&mut p.densify, p.step, &report.means2d, &out);
        Ok(parts)
    }

    /// The hooks after step `p.step`: SH bands, densification, the end of an epoch. Each
    /// takes the host model only when it acts.
    fn hooks<T: SplatTrainer>(
        &self,
        t: &mut T,
        p: &mut Progress,
        on_event: &mut dyn FnMut(Event),
        sh_events: &mut Vec<ShEvent>,
    ) -> Result<()> {
        let step = p.step;
        // SH bands are judged before densification acts on this step: an opacity reset falling
        // on the same step would leave the probes comparing two nearly transparent models, and
        // every band would look worthless.
        if self.sh.acts_at(&p.sh, step) {
            let (model, adam) = t.host_mut()?;
            for event in self.sh.after_step(
                &mut p.sh,
                step,
                model,
                adam,
                &mut self.band_loss(step, p.psf.as_ref()),
            )? {
                sh_events.push(event);
                on_event(Event::Sh { step, event });
            }
        }
        if self.densify.acts_at(step) {
            let (model, adam) = t.host_mut()?;
            if let Some(edit) =
                self.densify
                    .after_step(&mut p.densify, step, model, adam, self.config.seed)?
            {
                on_event(Event::Densified {
                    step,
                    edit,
                    splats: model.len(),
                });
            }
        }
        if step.is_multiple_of(self.data.train.len() as u64) {
            if p.densify.has_unseen() {
                let (model, adam) = t.host_mut()?;
                let done = self.densify.end_of_epoch(
                    &mut p.densify,
                    step,
                    model,
                    adam,
                    self.config.seed,
                )?;
                on_event(Event::Unseen { step, done });
            } else {
                p.densify.start_epoch();
            }
        }
        Ok(())
    }

    /// Evaluation and checkpoints after step `p.step`, when they fall on it.
    fn record<T: SplatTrainer>(
        &self,
        t: &mut T,
        p: &mut Progress,
        parts: &LossParts,
        on_event: &mut dyn FnMut(Event),
    ) -> Result<()> {
        let (config, step) = (self.config, p.step);
        let last = step == self.end(p);
        if last || (config.eval_every > 0 && step % config.eval_every == 0) {
            let (model, _) = t.host()?;
            let settings = self.settings(model.sh_degree);
            let metrics =
                eval::evaluate(model, &self.data.test, &settings, self.device, config.masks)?;
            if let Some(m) = &metrics {
                on_event(Event::Evaluated { step, metrics: m });
            }
            p.log.push(LogRow {
                step,
                seconds: p.train_seconds,
                loss: parts.total,
                train_psnr: parts.psnr,
                test_psnr: metrics.as_ref().map(|m| m.mean_psnr),
                test_ssim: metrics.as_ref().map(|m| m.mean_ssim),
                splats: model.len(),
                sh_degree: model.sh_degree,
            });
            on_event(Event::Logged { rows: &p.log });
        }
        if config.save_at.binary_search(&step).is_ok() {
            let (model, _) = t.host()?;
            on_event(Event::Snapshot { step, model });
        }
        if let Some(path) = self.checkpoint_path
            && config.checkpoint_every > 0
            && (step % config.checkpoint_every == 0 || last)
        {
            let (model, adam) = t.host()?;
            checkpoint::save(path, config, p, model, adam)
                .map_err(|e| checkpoint::not_written(e, path, step))?;
            on_event(Event::Checkpoint { step });
        }
        Ok(())
    }

    /// A stop asked for between steps: the state so far goes to the checkpoint (whatever the
    /// checkpoint cadence), so that `--resume` continues from this very step.
    fn interrupted<T: SplatTrainer>(&self, t: &mut T, p: &Progress) -> TrainError {
        let step = p.step;
        let Some(path) = self.checkpoint_path else {
            return TrainError::Interrupted(format!("training stopped at step {step}"));
        };
        let saved = t
            .host()
            .map_err(TrainError::from)
            .and_then(|(model, adam)| checkpoint::save(path, self.config, p, model, adam));
        match saved {
            Ok(()) => TrainError::Interrupted(format!(
                "training stopped at step {step} of {}; {} holds it: run the same command with --resume to continue",
                self.config.iters,
                path.display()
            )),
            Err(e) => TrainError::Interrupted(format!(
                "training stopped at step {step}, and its checkpoint could not be written ({e})"
            )),
        }
    }

    /// The step the run ends at: the configured count, or sooner where `--iters auto`'s rule
    /// has decided.
    fn end(&self, p: &Progress) -> u64 {
        p.stop
            .end
            .as_ref()
            .map_or(self.config.iters, |(end, _)| (*end).min(self.config.iters))
    }

    /// Steps until the configured count (or the stop rule's end), then the end-of-run pruning
    /// and band tests.
    fn train<T: SplatTrainer>(
        &self,
        mut t: T,
        mut p: Progress,
        on_event: &mut dyn FnMut(Event),
    ) -> Result<(Gaussians, Progress, Vec<ShEvent>, usize)> {
        let mut sh_events = Vec::new();
        while p.step < self.end(&p) {
            if base::interrupt::requested() {
                return Err(self.interrupted(&mut t, &p));
            }
            let started = Instant::now();
            let parts = self.step(&mut t, &mut p)?;
            p.step += 1;
            if let Some(rule) = &self.config.stop
                && let Some((end, reason)) = rule.observe(&mut p.stop, p.step, parts.psnr)
            {
                on_event(Event::Stopping {
                    step: p.step,
                    end: end.min(self.config.iters),
                    reason: &reason,
                });
            }
            self.hooks(&mut t, &mut p, on_event, &mut sh_events)?;
            p.train_seconds += started.elapsed().as_secs_f64();
            on_event(Event::Step {
                step: p.step,
                loss: &parts,
                splats: t.len(),
                sh_degree: t.sh_degree(),
                seconds: p.train_seconds,
            });
            self.record(&mut t, &mut p, &parts, on_event)?;
        }
        let (mut model, mut adam) = t.into_host()?;
        let final_pruned = self.densify.finish(&mut p.densify, &mut model, &mut adam)?;
        if model.is_empty() {
            return Err(TrainError::Invalid(format!(
                "training ended at step {} with no splat left: every one became invisible or was removed (a start far from the scene, or a checkpoint whose values are wrong, is the likely cause)",
                p.step
            )));
        }
        let step = p.step;
        for event in self.sh.finish(
            &mut p.sh,
            &mut model,
            &mut adam,
            &mut self.band_loss(step, p.psf.as_ref()),
        )? {
            sh_events.push(event);
            on_event(Event::Sh { step, event });
        }
        Ok((model, p, sh_events, final_pruned))
    }
}

/// Trains on `data`. With `checkpoint_path`, saves there every `checkpoint_every` steps;
/// with `resume` too, continues from the checkpoint if one exists (same config required).
/// The loop is the same wherever it trains: `device` only picks the [`SplatTrainer`].
pub fn train(
    config: &TrainConfig,
    data: &Dataset,
    device: &Device,
    checkpoint_path: Option<&Path>,
    resume: bool,
    on_event: &mut dyn FnMut(Event),
) -> Result<Outcome> {
    let run = Run::new(config, data, device, checkpoint_path)?;
    let (start, resumed_from) = match checkpoint_path {
        Some(p) if resume && p.exists() => {
            let mut s = checkpoint::load(p)?;
            config::upgrade_fingerprints(&mut s.config, data);
            let diff = config_differences(config, &s.config);
            if !diff.is_empty() {
                return Err(TrainError::file(
                    p,
                    format!("cannot resume with other settings: {}", diff.join("; ")),
                ));
            }
            let from = s.progress.step;
            (s, Some(from))
        }
        _ => (fresh_start(config, data, &run.densify)?, None),
    };
    let State {
        mut progress,
        model,
        adam,
        psf,
        ..
    } = start;
    if let Some(refine) = &config.refine_psf {
        let supplied = data.imaging.as_ref().ok_or_else(|| {
            TrainError::Invalid("--refine-psf needs the capture's PSF grid (aware mode)".into())
        })?;
        progress.psf = Some(PsfRefinement::new(refine, supplied, psf)?);
    }
    let (model, progress, sh_events, final_pruned) = match device {
        Device::Cpu => run.train(CpuTrainer::new(model, adam)?, progress, on_event)?,
        Device::Gpu(gpu) => run.train(GpuTrainer::new(gpu, model, adam)?, progress, on_event)?,
    };
    Ok(Outcome {
        psf: progress
            .psf
            .as_ref()
            .map(|r| (r.supplied().clone(), r.current().clone())),
        psf_warp: progress
            .psf
            .as_ref()
            .and_then(|r| r.warp_params())
            .and_then(|p| psf_refine::WarpSummary::of(&p)),
        settings: run.settings(model.sh_degree),
        model,
        log: progress.log,
        train_seconds: progress.train_seconds,
        final_pruned,
        sh_events,
        resumed_from,
        steps: progress.step,
        stopped: progress.stop.end.as_ref().map(|(end, why)| {
            format!(
                "stopped at step {} of at most {}: {why}, then a final phase at the final position learning rate",
                end.saturating_sub(config.stop.map_or(0, |r| r.final_steps)),
                config.iters
            )
        }),
    })
}
