//! One training run, assembled once for every caller (`train`, `demo`, `experiment`, a viewer's
//! live view, library users): the request with every setting a user can give, the prepared
//! run (capture loaded, config built and recorded) and the run itself with its outputs.
//!
//! Each default exists once: in the clap attribute of its field here or in
//! [`DataOptions`], or, where it depends on the capture, in [`TrainConfig::build`].

use std::path::PathBuf;

use clap::{Args, FromArgMatches};

use crate::device::{Device, DeviceChoice};
use crate::error::{Result, TrainError};
use crate::outputs::{self, CHECKPOINT_FILE, RunSummary};
use crate::train::config::{Mode, TrainConfig};
use crate::train::data::{self, DataOptions, Dataset};
use crate::train::{self, Event, Outcome};

/// What a run is asked to do: where from, where to, and how.
#[derive(Args, Clone, Debug)]
pub struct RunRequest {
    /// Capture directory (LLFF or COLMAP); an aberrated capture from `scene aberrate` carries
    /// its PSF grid and clean images.
    #[arg(long)]
    pub scene: PathBuf,
    /// Run folder (created; checkpoint, PLY, metrics, renders).
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub data: DataOptions,
    #[command(flatten)]
    pub training: TrainSettings,
    /// Continue from RUN/checkpoint.bin (same settings required).
    #[arg(long, conflicts_with = "overwrite")]
    pub resume: bool,
    /// Replace the run already in the run folder (its PLY, checkpoint, metrics and renders).
    #[arg(long)]
    pub overwrite: bool,
    /// Spiral frames to render at the end.
    #[arg(long, default_value_t = 30, value_parser = clap::value_parser!(u32).range(0..=10_000))]
    pub spiral: u32,
    /// Where to render: `auto` (a hardware GPU when there is one), `cpu`, or `gpu` (any
    /// adapter, software ones included). Results do not depend on it.
    #[arg(long, value_enum, default_value_t = DeviceChoice::Auto)]
    pub device: DeviceChoice,
}

/// A setting the capture decides unless the user does.
#[derive(clap::ValueEnum, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Toggle {
    #[default]
    Auto,
    On,
    Off,
}

/// When aware's λ falls to zero (`--lambda-fade`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum LambdaFade {
    #[default]
    Auto,
    Never,
    End,
    /// Falls from the first step to zero at this one.
    Step(u64),
    /// Holds until the first step, falls to zero at the second.
    Range(u64, u64),
}

impl std::str::FromStr for LambdaFade {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s.trim() {
            "auto" => Ok(LambdaFade::Auto),
            "never" => Ok(LambdaFade::Never),
            "end" => Ok(LambdaFade::End),
            n => {
                let bad = || format!("'{s}' is not auto, never, end, a step or FROM:TO steps");
                match n.split_once(':') {
                    Some((a, b)) => match (a.trim().parse(), b.trim().parse()) {
                        (Ok(a), Ok(b)) if a <= b => Ok(LambdaFade::Range(a, b)),
                        _ => Err(bad()),
                    },
                    None => n.parse().map(LambdaFade::Step).map_err(|_| bad()),
                }
            }
        }
    }
}

impl std::fmt::Display for LambdaFade {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            LambdaFade::Auto => f.write_str("auto"),
            LambdaFade::Never => f.write_str("never"),
            LambdaFade::End => f.write_str("end"),
            LambdaFade::Step(n) => write!(f, "{n}"),
            LambdaFade::Range(a, b) => write!(f, "{a}:{b}"),
        }
    }
}

/// How to train; what is left unset is derived from the capture in [`TrainConfig::build`].
#[derive(Args, Clone, Debug)]
pub struct TrainSettings {
    #[arg(long, value_enum, default_value_t = Mode::Aware)]
    pub mode: Mode,
    /// Weight of L(render, I_ac) in aware mode; default 0.75 (the paper's) with a trained
    /// restorer, 0.25 with the Wiener stand-in.
    #[arg(long, value_parser = crate::flags::weight, allow_negative_numbers = true)]
    pub lambda: Option<f32>,
    /// When λ falls linearly to zero: `auto` (by the end of densification with the Wiener
    /// stand-in and no --lambda given, else never), `never`, `end` (the last step), a step, or
    /// FROM:TO (held until FROM, zero at TO).
    #[arg(long, default_value_t = LambdaFade::Auto)]
    pub lambda_fade: LambdaFade,
    #[arg(long, default_value_t = 7000, value_parser = clap::value_parser!(u64).range(1..=100_000_000))]
    pub iters: u64,
    /// Splat budget; default: one per two pixels of a view, twice that for a capture whose
    /// cameras surround the scene.
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=100_000_000))]
    pub max_splats: Option<u64>,
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u32).range(0..=3))]
    pub max_sh_degree: u32,
    /// Reset opacities as 3DGS does: `auto` (default) when the cameras surround the scene
    /// (all-around captures, where it clears floaters), not for forward-facing ones (the paper
    /// turned it off for LLFF); `on` (or the bare flag) or `off`.
    #[arg(long, value_enum, default_value_t = Toggle::Auto, num_args = 0..=1, default_missing_value = "on")]
    pub opacity_reset: Toggle,
    /// Weight of a mean-opacity penalty: splats that no training view needs (floaters seen
    /// only against a black background) fade and are pruned; 0 turns it off.
    #[arg(long, default_value_t = 0.0, value_parser = crate::flags::weight, allow_negative_numbers = true)]
    pub opacity_reg: f32,
    /// An SH band stays when dropping it raises the training loss by at least this fraction
    /// (default 0.001); 0 keeps every band that lowers it at all.
    #[arg(long, value_parser = crate::flags::non_negative, allow_negative_numbers = true)]
    pub sh_min_gain: Option<f64>,
    /// Held-out evaluation every N steps (default: 10 times per run).
    #[arg(long)]
    pub eval_every: Option<u64>,
    /// Checkpoint every N steps (default: 5 times per run).
    #[arg(long)]
    pub checkpoint_every: Option<u64>,
    /// Start from this splat scene (.ply, .glb or .spz) instead of the capture's points.
    #[arg(long)]
    pub init: Option<PathBuf>,
}

/// Parses `args` into `T` alone: the defaults of its clap attributes, with `args` on top.
/// The attributes are static, so failing here is a programming error (a test covers it).
pub fn parse_args<T: Args + FromArgMatches>(args: &[&std::ffi::OsStr]) -> T {
    let cmd = T::augment_args(clap::Command::new("defaults").no_binary_name(true));
    let matches = cmd
        .try_get_matches_from(args)
        .expect("the arguments' own defaults parse");
    T::from_arg_matches(&matches).expect("the arguments' own defaults parse")
}

impl Default for TrainSettings {
    fn default() -> Self {
        parse_args(&[])
    }
}

impl RunRequest {
    /// A request with every default, as `metasplat train --scene SCENE --out OUT` makes it.
    pub fn new(scene: impl Into<PathBuf>, out: impl Into<PathBuf>) -> Self {
        let (scene, out) = (scene.into(), out.into());
        parse_args(&[
            "--scene".as_ref(),
            scene.as_os_str(),
            "--out".as_ref(),
            out.as_os_str(),
        ])
    }
}

/// A run ready to train: the run folder exists and is writable, the capture is loaded, and
/// the config is built and written to `config.json`.
pub struct PreparedRun {
    pub request: RunRequest,
    pub data: Dataset,
    pub config: TrainConfig,
    pub device: Device,
    /// Which device renders, and why, as a sentence.
    pub device_note: String,
    /// Where the restorer's images came from or went (the cache), as a sentence.
    pub cache_note: Option<String>,
}

/// Checks and loads everything a run needs, before any training time is spent.
pub fn prepare(request: &RunRequest) -> Result<PreparedRun> {
    let out = &request.out;
    let mut inputs = vec![("--scene", request.scene.as_path())];
    if let Some(p) = &request.data.psf {
        inputs.push(("--psf", p));
    }
    if let data::RestorerChoice::Weights(w) = &request.data.restorer {
        inputs.push(("--restorer", w));
    }
    if let Some(i) = &request.training.init {
        inputs.push(("--init", i));
    }
    crate::guard::refuse_overwrite("--out", out, &inputs)?;
    check_run_folder(request)?;
    let (device, device_note) = Device::choose(request.device)?;
    // Every input is checked before the run folder is made.
    // I_ac is read from (and, once the run folder exists, written to) a cache: the run's own
    // unless the caller shares one between runs.
    let mut data_options = request.data.clone();
    let cache_dir = data_options
        .iac_cache
        .get_or_insert_with(|| out.join(crate::train::iac_cache::CACHE_DIR))
        .clone();
    let mut data = data::load(&request.scene, request.training.mode, &data_options)
        .map_err(|e| e.context(format!("cannot load the scene {}", request.scene.display())))?;
    if let Some(path) = &request.training.init {
        let g = splat::files::read_splats(path)
            .map_err(|e| TrainError::from(e).context(format!("--init {}", path.display())))?;
        if g.is_empty() {
            return Err(TrainError::file(path, "--init: the scene has no splats"));
        }
        data.initial = Some(g);
    }
    outputs::prepare_run_dir(out)
        .map_err(|e| e.context(format!("cannot use {} as the run folder", out.display())))?;
    if request.overwrite {
        outputs::clear_run(out)?;
    }
    let config = TrainConfig::build(&request.training, request.data.seed, &data);
    outputs::write_json(&out.join(outputs::CONFIG_FILE), &config)?;
    let restored = data.train.iter().filter(|v| v.restored.is_some()).count();
    let cache_note = match data.cache_restored(&cache_dir) {
        Some(failure) => Some(failure),
        None if restored > 0 => {
            let fresh = data.restored_fresh.len();
            let dir = cache_dir.display();
            Some(if fresh == restored {
                format!("I_ac: restored all {restored} training views and cached them in {dir}.")
            } else if fresh == 0 {
                format!("I_ac: read all {restored} training views from the cache in {dir}.")
            } else {
                format!(
                    "I_ac: restored {fresh} of {restored} training views; the others came from the cache in {dir}."
                )
            })
        }
        None => None,
    };
    Ok(PreparedRun {
        request: request.clone(),
        data,
        config,
        device,
        device_note,
        cache_note,
    })
}

/// A run folder that holds a run is continued (`--resume`) or replaced (`--overwrite`), never
/// mixed with a new one; `--resume` needs a checkpoint to continue.
fn check_run_folder(request: &RunRequest) -> Result<()> {
    let out = &request.out;
    let ckpt = out.join(CHECKPOINT_FILE);
    if request.resume && !ckpt.exists() {
        return Err(TrainError::file(
            out,
            format!("--resume: there is no {CHECKPOINT_FILE} to continue"),
        ));
    }
    let existing = outputs::RUN_FILES.iter().find(|f| out.join(f).exists());
    if let Some(f) = existing
        && !request.resume
        && !request.overwrite
    {
        return Err(TrainError::file(
            out,
            format!(
                "the folder already holds a run ({f}): continue it with --resume or replace it with --overwrite"
            ),
        ));
    }
    Ok(())
}

impl PreparedRun {
    /// Trains (resuming if asked), then writes the run folder: PLY, metrics, log, renders and
    /// the PSNR-vs-time plot.
    pub fn run(&self, on_event: &mut dyn FnMut(Event)) -> Result<(RunSummary, Outcome)> {
        let out = &self.request.out;
        let ckpt = out.join(CHECKPOINT_FILE);
        let outcome = train::train(
            &self.config,
            &self.data,
            &self.device,
            Some(&ckpt),
            self.request.resume,
            on_event,
        )?;
        let summary = outputs::write_run(
            out,
            &self.data,
            &self.config,
            &outcome,
            self.request.spiral as usize,
            &self.device,
        )
        .and_then(|s| outputs::plot_log(out, &outcome.log).map(|_| s))
        .map_err(|e| e.context(format!("cannot write the run folder {}", out.display())))?;
        Ok((summary, outcome))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_come_from_the_arguments() {
        let r = RunRequest::new("scene", "run");
        assert_eq!(r.scene, PathBuf::from("scene"));
        assert_eq!(r.training.mode, Mode::Aware);
        assert_eq!(r.training.iters, 7000);
        assert_eq!(r.data.downsample, DataOptions::default().downsample);
        assert_eq!(r.data.llffhold, scenes::LLFFHOLD);
        let t: TrainSettings = parse_args(&["--iters".as_ref(), "12".as_ref()]);
        assert_eq!(t.iters, 12);
        assert_eq!(t.max_sh_degree, TrainSettings::default().max_sh_degree);
    }
}
