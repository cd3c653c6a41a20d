//! `bench step` as a job: the time of each phase of the training loop's own step on a
//! capture, at one or more thread counts, on the device training would use. [`prepare`]
//! checks the flags and reads the capture; [`PreparedStepBench::run`] times the steps (and,
//! with `--refine-psf`, the same steps refining the PSF grid, alternated) and reports them.
//! A measurement, not a test: nothing is written.

use clap::Args;
use std::path::PathBuf;

use super::{median, refused};
use crate::error::{Result, TrainError};
use crate::settings::{CoarseToFine, DataOptions, Iters, TrainSettings};
use crate::splats::device::{Device, DeviceChoice};
use crate::train::config::{Mode, TrainConfig};
use crate::train::data::{self, Dataset};
use crate::train::psf_refine::{PsfModel, PsfRefineConfig};
use crate::train::timing::time_steps;

pub use crate::train::timing::StepTimes;

/// What `bench step` is asked to time (its flags).
#[derive(Args, Clone, Debug)]
pub struct StepBenchRequest {
    /// The capture to train on (an aberrated one for `aware`).
    #[arg(long)]
    pub scene: PathBuf,
    /// Which loss the timed steps train with.
    #[arg(long, value_enum, default_value_t = Mode::Aware)]
    pub mode: Mode,
    /// A splat scene to start from (e.g. a trained run's PLY); default: the capture's points.
    #[arg(long)]
    pub ply: Option<PathBuf>,
    /// Training steps timed at each thread count.
    #[arg(long, default_value_t = 20, value_parser = clap::value_parser!(u64).range(1..=100_000))]
    pub steps: u64,
    /// Thread counts to time, in order.
    #[arg(long, value_delimiter = ',', default_values_t = [1usize, 2], value_parser = clap::value_parser!(usize))]
    pub threads: Vec<usize>,
    /// Where to train: as `train --device` (`auto`, `cpu`, `gpu`).
    #[arg(long, value_enum, default_value_t = DeviceChoice::Auto)]
    pub device: DeviceChoice,
    /// Also time the same steps with `--refine-psf` updating the PSF grid on every step (aware
    /// mode), side by side: what refining the PSF adds to a step.
    #[arg(long)]
    pub refine_psf: bool,
    #[command(flatten)]
    pub data: DataOptions,
}

/// The capture read and the run configured, ready to be timed.
pub struct PreparedStepBench {
    request: StepBenchRequest,
    data: Dataset,
    config: TrainConfig,
    device: Device,
    /// What will be timed, and on which device, as a sentence.
    pub note: String,
}

/// Per thread count, the refined steps beside plain aware ones (medians of alternated rounds,
/// milliseconds).
#[derive(Clone, Debug)]
pub struct RefinementRow {
    pub threads: usize,
    pub aware_ms: f64,
    pub refined_ms: f64,
    pub gradient_ms: f64,
    pub update_ms: f64,
    /// The default refinement's interval: the share of a step it adds is
    /// `(gradient + update) / every / aware`.
    pub every: u64,
}

/// What was timed.
#[derive(Clone, Debug)]
pub struct StepBenchReport {
    /// One per thread count, in the order asked.
    pub runs: Vec<StepTimes>,
    /// With `--refine-psf`.
    pub refinement: Vec<RefinementRow>,
}

/// Every flag checked (thread counts, `--refine-psf` outside aware mode, an empty `--ply`)
/// before the capture is read; then the device chosen and the run configured as `train`
/// would at this many steps, at the capture's own size (coarse to fine would make the first
/// measured steps smaller ones).
pub fn prepare(a: &StepBenchRequest) -> Result<PreparedStepBench> {
    if a.threads.iter().any(|&t| t == 0 || t > 1024) {
        return refused("--threads: thread counts are 1 to 1024".into());
    }
    if a.refine_psf && a.mode != Mode::Aware {
        return refused("--refine-psf: only aware steps blur through the PSF grid".into());
    }
    let initial = match &a.ply {
        Some(p) => {
            let g = splat::formats::files::read_splats(p)
                .map_err(|e| TrainError::from(e).context(format!("--ply {}", p.display())))?;
            if g.is_empty() {
                return refused(format!("--ply {}: the scene has no splats", p.display()));
            }
            Some(g)
        }
        None => None,
    };
    let (device, device_note) = Device::choose(a.device)?;
    let mut data = data::load(&a.scene, a.mode, &a.data)
        .map_err(|e| e.context(format!("cannot load the scene {}", a.scene.display())))?;
    data.initial = initial;
    let settings = TrainSettings {
        mode: a.mode,
        iters: Iters::Steps(a.steps),
        eval_every: Some(0),
        checkpoint_every: Some(0),
        coarse_to_fine: CoarseToFine::Off,
        ..TrainSettings::default()
    };
    let config = TrainConfig::build(&settings, a.data.seed, &data);
    let note = format!(
        "{} training steps of mode {} (λ {}) at {}x{} ({} views), the training loop's own step. {device_note}",
        a.steps,
        a.mode,
        config.lambda,
        data.width,
        data.height,
        data.train.len()
    );
    Ok(PreparedStepBench {
        request: a.clone(),
        data,
        config,
        device,
        note,
    })
}

impl PreparedStepBench {
    /// Times the steps at every thread count after one untimed step (page faults and lazy
    /// set-up are not a phase), then, with `--refine-psf`, the refined ones.
    pub fn run(self) -> Result<StepBenchReport> {
        let (a, data, config, device) = (&self.request, &self.data, &self.config, &self.device);
        let warm = TrainConfig {
            iters: 1,
            ..config.clone()
        };
        time_steps(data, &warm, device, a.threads[0])?;
        let runs = a
            .threads
            .iter()
            .map(|&t| time_steps(data, config, device, t))
            .collect::<Result<Vec<_>>>()?;
        let refinement = if a.refine_psf {
            self.refinement()?
        } else {
            Vec::new()
        };
        Ok(StepBenchReport { runs, refinement })
    }

    /// The same steps with the PSF grid refined on every step, beside plain aware ones, three
    /// alternated rounds per thread count.
    fn refinement(&self) -> Result<Vec<RefinementRow>> {
        let (a, data, config, device) = (&self.request, &self.data, &self.config, &self.device);
        let defaults = PsfRefineConfig::for_iters(a.steps, PsfModel::Warp);
        let refining = TrainConfig {
            refine_psf: Some(PsfRefineConfig {
                from: 0,
                every: 1,
                ..defaults
            }),
            ..config.clone()
        };
        let mut rows = Vec::new();
        for &threads in &a.threads {
            let (mut plain, mut refined, mut gradient, mut update) =
                (Vec::new(), Vec::new(), Vec::new(), Vec::new());
            for _ in 0..3 {
                plain.push(time_steps(data, config, device, threads)?.step);
                let r = time_steps(data, &refining, device, threads)?;
                gradient.push(r.phase("PSF gradient"));
                update.push(r.phase("PSF update"));
                refined.push(r.step);
            }
            rows.push(RefinementRow {
                threads,
                aware_ms: median(plain),
                refined_ms: median(refined),
                gradient_ms: median(gradient),
                update_ms: median(update),
                every: defaults.every,
            });
        }
        Ok(rows)
    }
}
