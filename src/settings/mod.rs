//! The settings a user can give, as clap arguments: what a run is asked to do
//! ([`RunRequest`]), how to train ([`TrainSettings`]) and how a capture is read
//! ([`DataOptions`]). They sit below everything else in the root crate: the config, the data
//! and the run read them, and they read nothing of those.
//!
//! Each default exists once: in the clap attribute of its field here, or, where it depends
//! on the capture, in [`crate::train::config::TrainConfig::build`].

pub mod imaging;
pub mod values;

use std::path::PathBuf;

use clap::{Args, FromArgMatches};

use serde::{Deserialize, Serialize};

use crate::splats::device::DeviceChoice;

/// The paper's three rows.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Mode {
    /// "3D-GS + Ours": `L(PSF ⊛ render, I_abr) + λ·L(render, I_ac)`.
    Aware,
    /// "3D-GS w/ Ours": plain 3DGS on the restored images `I_ac`.
    Restored,
    /// "3D-GS": plain 3DGS on the aberrated images.
    Plain,
}

impl Mode {
    pub const ALL: [Mode; 3] = [Mode::Plain, Mode::Restored, Mode::Aware];

    pub fn needs_psf(self) -> bool {
        self != Mode::Plain
    }

    pub fn name(self) -> &'static str {
        match self {
            Mode::Aware => "aware",
            Mode::Restored => "restored",
            Mode::Plain => "plain",
        }
    }
}

impl std::fmt::Display for Mode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

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

/// How long a run trains (`--iters`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Iters {
    /// Until training stops paying ([`crate::train::stop`]), with schedules made for a
    /// length that follows the number of views ([`crate::train::config::auto_horizon`]).
    Auto,
    /// Exactly this many steps.
    Steps(u64),
}

impl Iters {
    /// The step count, when one was given.
    pub fn steps(self) -> Option<u64> {
        match self {
            Iters::Auto => None,
            Iters::Steps(n) => Some(n),
        }
    }
}

impl std::str::FromStr for Iters {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s.trim() {
            "auto" => Ok(Iters::Auto),
            n => match n.parse::<u64>() {
                Ok(n) if (1..=100_000_000).contains(&n) => Ok(Iters::Steps(n)),
                _ => Err(format!(
                    "'{s}' is not auto or a step count from 1 to 100000000"
                )),
            },
        }
    }
}

/// `--coarse-to-fine`: whether the first steps train at smaller resolutions, how many, and
/// for how many steps each.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CoarseToFine {
    /// Two levels where densification grows the splats from the capture's points (the
    /// adaptive strategy); none for MCMC, which starts at its budget ([`TrainConfig::build`]).
    ///
    /// [`TrainConfig::build`]: crate::train::config::TrainConfig::build
    Auto,
    Off,
    /// The first steps `2^levels` times smaller, halving the factor at each level, `steps`
    /// steps per level (None: a tenth of the schedule).
    Levels {
        levels: u32,
        steps: Option<u64>,
    },
}

/// Levels of `--coarse-to-fine on`, and of `auto` where it applies.
pub const DEFAULT_COARSE_LEVELS: u32 = 2;

impl CoarseToFine {
    /// The levels asked for on a run whose densification is MCMC (`mcmc`) or not: `auto`
    /// gives none to MCMC, which starts at its budget (smaller views save little of its step,
    /// and at 1000 steps the all-around scene lost 0.4 dB with them).
    pub fn levels_for(self, mcmc: bool) -> u32 {
        match self {
            CoarseToFine::Off => 0,
            CoarseToFine::Auto if mcmc => 0,
            CoarseToFine::Auto => DEFAULT_COARSE_LEVELS,
            CoarseToFine::Levels { levels, .. } => levels,
        }
    }

    /// Steps per level when given (None: a tenth of the schedule).
    pub fn steps(self) -> Option<u64> {
        match self {
            CoarseToFine::Levels { steps, .. } => steps,
            _ => None,
        }
    }
}

impl std::str::FromStr for CoarseToFine {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        let bad = || {
            format!(
                "'{s}' is not auto, off, on, LEVELS (1 to 4) or LEVELS:STEPS (steps per level, 1 to 100000000)"
            )
        };
        let (levels, steps) = match s.trim() {
            "auto" => return Ok(CoarseToFine::Auto),
            "off" => return Ok(CoarseToFine::Off),
            "on" => (DEFAULT_COARSE_LEVELS, None),
            t => {
                let (l, n) = match t.split_once(':') {
                    Some((l, n)) => (l, Some(n)),
                    None => (t, None),
                };
                let levels = l.trim().parse::<u32>().map_err(|_| bad())?;
                let steps = n
                    .map(|n| n.trim().parse::<u64>().map_err(|_| bad()))
                    .transpose()?;
                (levels, steps)
            }
        };
        if !(1..=4).contains(&levels) || steps.is_some_and(|n| !(1..=100_000_000).contains(&n)) {
            return Err(bad());
        }
        Ok(CoarseToFine::Levels { levels, steps })
    }
}

impl std::fmt::Display for CoarseToFine {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            CoarseToFine::Auto => f.write_str("auto"),
            CoarseToFine::Off => f.write_str("off"),
            CoarseToFine::Levels {
                levels,
                steps: None,
            } => write!(f, "{levels}"),
            CoarseToFine::Levels {
                levels,
                steps: Some(n),
            } => write!(f, "{levels}:{n}"),
        }
    }
}

impl std::fmt::Display for Iters {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Iters::Auto => f.write_str("auto"),
            Iters::Steps(n) => write!(f, "{n}"),
        }
    }
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

/// The background colour asked for.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Background {
    Auto,
    Colour([f32; 3]),
    /// A new colour every training step; the run's renders use `auto`'s.
    Random,
}

impl std::str::FromStr for Background {
    type Err = String;

    /// `auto`, `random` or a [`values::colour`].
    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim() {
            "auto" => Ok(Background::Auto),
            "random" => Ok(Background::Random),
            _ => values::colour(s).map(Background::Colour),
        }
    }
}

/// What the capture's masks mean, as asked for.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum MaskChoice {
    /// `object` for a capture with object masks (a folder of them, `transforms.json`'s
    /// `mask_path` or the photos' alpha), `loss` for the border undistortion leaves alone.
    Auto,
    /// Pixels outside a mask leave the loss.
    Loss,
    /// The object alone, on the background.
    Object,
}

/// The densification strategy asked for.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum StrategyChoice {
    Auto,
    Adaptive,
    Mcmc,
}

/// How to train; what is left unset is derived from the capture in [`TrainConfig::build`].
#[derive(Args, Clone, Debug)]
pub struct TrainSettings {
    /// aware (the paper: L_abr + λ·L(render, I_ac)), restored (I_ac only) or plain 3DGS on
    /// the photos.
    #[arg(long, value_enum, default_value_t = Mode::Aware)]
    pub mode: Mode,
    /// Weight of L(render, I_ac) in aware mode; default 0.75 (the paper's) with a trained
    /// restorer, 0.25 with the Wiener stand-in.
    #[arg(long, value_parser = crate::settings::values::weight, allow_negative_numbers = true)]
    pub lambda: Option<f32>,
    /// When λ falls linearly to zero: `auto` (by the end of densification with the Wiener
    /// stand-in and no --lambda given, else never), `never`, `end` (the last step), a step, or
    /// FROM:TO (held until FROM, zero at TO).
    #[arg(long, default_value_t = LambdaFade::Auto)]
    pub lambda_fade: LambdaFade,
    /// Training steps, or `auto` (the default): until the training views stop improving
    /// (after densification, then a short final phase), with schedules made for 150 steps per
    /// training view, 200 in restored mode (1000 to 7000). A number means exactly that many steps.
    #[arg(long, default_value_t = Iters::Auto)]
    pub iters: Iters,
    /// Splat budget; default: one per two pixels of a view, twice that for a capture whose
    /// cameras surround the scene.
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=100_000_000))]
    pub max_splats: Option<u64>,
    /// Highest spherical-harmonics degree the splats may use (0 to 3).
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u32).range(0..=3))]
    pub max_sh_degree: u32,
    /// Reset opacities as 3DGS does: `auto` (default) when the cameras surround the scene
    /// (all-around captures, where it clears floaters), not for forward-facing ones (the paper
    /// turned it off for LLFF); `on` (or the bare flag) or `off`.
    #[arg(long, value_enum, default_value_t = Toggle::Auto, num_args = 0..=1, default_missing_value = "on")]
    pub opacity_reset: Toggle,
    /// How splats are added and removed: `auto` (mcmc when the capture has no SfM points and
    /// training starts from random ones, else adaptive), `adaptive` (3DGS's clone, split and
    /// prune on screen-space gradients, with opacity resets), or `mcmc` (3DGS as Markov chain
    /// Monte Carlo: transparent splats are moved onto opaque ones, new ones grow 5 % at a time
    /// up to the budget, with position noise and opacity and scale penalties).
    #[arg(long, value_enum, default_value_t = StrategyChoice::Auto)]
    pub strategy: StrategyChoice,
    /// Weight of a mean-opacity penalty: splats that no training view needs (floaters seen
    /// only against a black background) fade and are pruned or moved; 0 turns it off
    /// (default: 0.01 with mcmc, 0 with adaptive). Against one loss term: aware mode, whose
    /// loss has two, weighs it by 1 + λ.
    #[arg(long, value_parser = crate::settings::values::weight, allow_negative_numbers = true)]
    pub opacity_reg: Option<f32>,
    /// Weight of a mean-scale penalty, which keeps splats small unless the images need them
    /// large (default: 0.01 with mcmc, 0 with adaptive; by 1 + λ in aware mode, as above).
    #[arg(long, value_parser = crate::settings::values::weight, allow_negative_numbers = true)]
    pub scale_reg: Option<f32>,
    /// Colour behind the splats, in training and in the run's renders: `auto` (for a capture
    /// taken all around an object, the median colour of the photos' borders, where its
    /// backdrop shows; black otherwise), `black`, `white`, `R,G,B` in [0, 1], or `random`
    /// (a seeded colour each training step, so that no pixel can be matched by showing the
    /// background through splats; renders and evaluation use `auto`'s colour).
    #[arg(long, default_value = "auto", value_parser = str::parse::<Background>)]
    pub background: Background,
    /// What a capture's masks mean: `object` (the object alone: the photos are composited
    /// over the background outside their masks, empty space is learnt as empty, and the
    /// exported splats hold the object only; the background is then black, or the colour a
    /// `scene aberrate` copy was composited over, unless --background names one), `loss`
    /// (pixels outside leave the loss: what shows there is unknown), or `auto` (object for
    /// a capture with object masks, loss for the border undistortion leaves).
    #[arg(long, value_enum, default_value_t = MaskChoice::Auto)]
    pub mask_mode: MaskChoice,
    /// An SH band stays when dropping it raises the training loss by at least this fraction
    /// (default 0.001); 0 keeps every band that lowers it at all.
    #[arg(long, value_parser = crate::settings::values::non_negative, allow_negative_numbers = true)]
    pub sh_min_gain: Option<f64>,
    /// Held-out evaluation every N steps (default: 10 times per run).
    #[arg(long)]
    pub eval_every: Option<u64>,
    /// Checkpoint every N steps (default: 5 times per run).
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=100_000_000))]
    pub checkpoint_every: Option<u64>,
    /// Also keep the splats at these steps, as `point_cloud_STEP.ply` in the run folder
    /// (e.g. 1000,3000; INRIA's `--save_iterations`).
    #[arg(long, value_delimiter = ',', value_parser = clap::value_parser!(u64).range(1..=100_000_000))]
    pub save_at: Vec<u64>,
    /// Start from this splat scene (.ply, .glb or .spz) instead of the capture's points.
    #[arg(long)]
    pub init: Option<PathBuf>,
    /// Learn a correction of the PSF grid with the splats (aware mode), for a lens whose PSFs
    /// were measured or simulated a little off: `warp` (the bare flag: seven numbers, per
    /// colour a scale of the PSFs varying over the field, and a rotation) or `free` (every
    /// PSF value). Writes the refined grid as psf_refined.npy and a picture of it beside the
    /// supplied one.
    #[arg(long, value_enum, num_args = 0..=1, default_missing_value = "warp")]
    pub refine_psf: Option<crate::train::psf_refine::PsfModel>,
    /// Train the first steps at smaller resolutions, with a splat budget that follows the
    /// pixel count: `auto` (default: on where densification grows the splats from the
    /// capture's points, off for MCMC, which starts at its budget), `off`, `on` (two levels: 4
    /// then 2 times smaller, each for a tenth of the schedule), `LEVELS` (the first steps
    /// 2^LEVELS times smaller, halving at each level) or `LEVELS:STEPS` (steps per level).
    /// Levels whose shorter side would fall under 32 px are left out. The photos, `I_ac`,
    /// masks and the PSF grid are shrunk alike; evaluation stays at full size.
    #[arg(long, default_value = "auto")]
    pub coarse_to_fine: CoarseToFine,
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

/// Where the user wants `I_ac` to come from.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum RestorerChoice {
    /// The shipped transformer when it was trained for the capture's PSF grid, else the
    /// Wiener image (and every output says which).
    Auto,
    /// The Wiener filter with `metasplat deconvolve`'s default constant.
    Wiener,
    /// Transformer weights from a file (refused if trained for another PSF grid).
    Weights(PathBuf),
}

impl std::str::FromStr for RestorerChoice {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        Ok(match s {
            "auto" => Self::Auto,
            "wiener" => Self::Wiener,
            _ if s.is_empty() => return Err("empty restorer".into()),
            path => Self::Weights(PathBuf::from(path)),
        })
    }
}

/// How a capture is read for training (the defaults are the command line's).
#[derive(clap::Args, Clone, Debug)]
pub struct DataOptions {
    /// Use images_N/ (1: images/); a capture without it has its images/ shrunk N times at
    /// load by the area filter. Left out: images_8/ when the capture has it, else the folder
    /// it has.
    #[arg(long, default_value_t = 8, hide_default_value = true, value_parser = clap::value_parser!(u32).range(1..=64))]
    pub downsample: u32,
    /// Every N-th view is held out for evaluation (0: none).
    #[arg(long, default_value_t = scenes::LLFFHOLD, value_parser = crate::settings::values::llffhold, allow_negative_numbers = true)]
    pub llffhold: usize,
    /// PSF grid .npy; must match the capture's own psf.npy when it has one.
    #[arg(long)]
    pub psf: Option<PathBuf>,
    /// Source of I_ac: `auto` (the shipped transformer when trained for this PSF grid, else
    /// the Wiener image), `wiener`, or a restorer weights file.
    #[arg(long, default_value = "auto")]
    pub restorer: RestorerChoice,
    /// Seed of the initial points, the view order and densification.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Train on the photos as taken even when the capture's cameras have lens distortion
    /// (by default they are undistorted at load onto the pinhole camera of the same
    /// intrinsics, the camera the renderer draws).
    #[arg(long)]
    pub keep_distortion: bool,
    /// A folder of cached `I_ac` images to read (and, for a run, to fill): see
    /// [`crate::train::iac_cache`].
    #[arg(skip)]
    pub iac_cache: Option<PathBuf>,
    /// A PSF grid the run takes for the capture's own: what a user whose calibration is off
    /// believes (the mis-calibration experiment). The blur of `L_abr` and `I_ac` both use it,
    /// unless [`Self::restorer_psf`] says otherwise.
    #[arg(skip)]
    pub assumed_psf: Option<PathBuf>,
    /// The grid `I_ac` is restored through, when it is not the blur's (the experiment's split
    /// of what a wrong grid costs through `L_abr` and through `I_ac`).
    #[arg(skip)]
    pub restorer_psf: Option<PathBuf>,
}

impl Default for DataOptions {
    fn default() -> Self {
        parse_args(&[])
    }
}

/// What masks mean, as a run records it (`config.json`'s `masks`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum MaskUse {
    /// Pixels outside a mask leave the loss: what shows there is unknown, not empty.
    Loss,
    /// The object alone: outside its mask every view shows the background.
    Object,
}

impl std::fmt::Display for MaskUse {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            MaskUse::Loss => "loss",
            MaskUse::Object => "object",
        })
    }
}

/// Opens a capture at `images_{downsample}` (every 8th image held out; photos undistorted
/// at load unless `keep_distortion`), naming it on failure.
pub fn open_scene(
    dir: &std::path::Path,
    downsample: u32,
    keep_distortion: bool,
) -> crate::Result<scenes::Capture> {
    let options = scenes::OpenOptions {
        resolution: scenes::Resolution::Downsample(downsample),
        undistort: !keep_distortion,
        ..Default::default()
    };
    scenes::open(dir, &options).map_err(|e| {
        crate::TrainError::from(e).context(format!("cannot open the scene {}", dir.display()))
    })
}

/// The downsample to open `dir` at: the one given, else `images_8/` as LLFF captures are
/// usually trained at, else the least downsampled folder the capture has (`images/` for the
/// captures the demo and `scene procedural` write), with a sentence saying the choice.
pub fn downsample_for(dir: &std::path::Path, given: Option<u32>) -> (u32, Option<String>) {
    if let Some(d) = given {
        return (d, None);
    }
    let found = scenes::capture::image_downsamples(dir);
    let d = if found.contains(&8) {
        8
    } else {
        found.first().copied().unwrap_or(8)
    };
    let said = format!(
        "Using {}/ of {}.",
        scenes::llff::image_folder_name(d),
        dir.display()
    );
    (d, Some(said))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_background_is_auto_random_or_a_colour() {
        assert_eq!("auto".parse(), Ok(Background::Auto));
        assert_eq!(" random".parse(), Ok(Background::Random));
        assert_eq!("white".parse(), Ok(Background::Colour([1.0; 3])));
        assert!("randomly".parse::<Background>().is_err());
        assert!("0,0,2".parse::<Background>().is_err());
    }

    #[test]
    fn defaults_come_from_the_arguments() {
        let r = RunRequest::new("scene", "run");
        assert_eq!(r.scene, PathBuf::from("scene"));
        assert_eq!(r.training.mode, Mode::Aware);
        assert_eq!(r.training.iters, Iters::Auto);
        assert_eq!(r.data.downsample, DataOptions::default().downsample);
        assert_eq!(r.data.llffhold, scenes::LLFFHOLD);
        let t: TrainSettings = parse_args(&["--iters".as_ref(), "12".as_ref()]);
        assert_eq!(t.iters, Iters::Steps(12));
        let t: TrainSettings = parse_args(&["--iters".as_ref(), "auto".as_ref()]);
        assert_eq!(t.iters, Iters::Auto);
        for bad in ["0", "-3", "soon", "100000001"] {
            assert!(bad.parse::<Iters>().is_err(), "{bad}");
        }
        assert_eq!(t.max_sh_degree, TrainSettings::default().max_sh_degree);
    }

    #[test]
    fn coarse_to_fine_reads_auto_off_on_levels_and_steps() {
        let read = |s: &str| s.parse::<CoarseToFine>();
        let c = |levels, steps| CoarseToFine::Levels { levels, steps };
        assert_eq!(TrainSettings::default().coarse_to_fine, CoarseToFine::Auto);
        assert_eq!(read("auto"), Ok(CoarseToFine::Auto));
        assert_eq!(read("off"), Ok(CoarseToFine::Off));
        assert_eq!(read("on"), Ok(c(2, None)));
        assert_eq!(read("3"), Ok(c(3, None)));
        assert_eq!(read("1:250"), Ok(c(1, Some(250))));
        for bad in ["0", "5", "2:0", "2:", ":5", "x", "-1", "2:1e3"] {
            let e = read(bad).expect_err(bad);
            assert!(e.contains(bad) && e.contains("LEVELS:STEPS"), "{e}");
        }
        let mcmc = [false, true];
        assert_eq!(mcmc.map(|m| CoarseToFine::Auto.levels_for(m)), [2, 0]);
        assert_eq!(mcmc.map(|m| CoarseToFine::Off.levels_for(m)), [0, 0]);
        assert_eq!(mcmc.map(|m| c(3, Some(9)).levels_for(m)), [3, 3]);
        assert_eq!(
            (c(3, Some(9)).steps(), CoarseToFine::Auto.steps()),
            (Some(9), None)
        );
        for ok in ["auto", "off", "on", "3", "1:250"] {
            assert_eq!(read(ok).unwrap().to_string().parse(), read(ok), "{ok}");
        }
    }
}
