//! What every experiment's runs share ([`ExperimentRuns`]): the capture, the aberrated copy
//! made once under `--out`, and the request of each run.

use clap::Args;
use std::path::PathBuf;

use crate::error::{Result, TrainError};
use crate::settings::RunRequest;
use crate::train::config::Mode;
use aberration::optics::SimConfig;

/// Where an experiment reads and writes, flags every experiment has with the same defaults.
#[derive(Args, Clone, Debug)]
pub struct ExperimentPlace {
    /// The clean capture (e.g. the procedural scene, or ../shared/data/llff/fern).
    #[arg(long)]
    pub scene: PathBuf,
    /// The experiment folder: the aberrated copy, every run, the table and the plots.
    #[arg(long)]
    pub out: PathBuf,
    /// The true PSF grid; default: simulate the paper's 9x9 grid.
    #[arg(long)]
    pub psf: Option<PathBuf>,
    /// Use the capture's images_N/ (1: images/), else its images/ shrunk N times at load.
    #[arg(long, default_value_t = 8, value_parser = clap::value_parser!(u32).range(1..=64))]
    pub downsample: u32,
    /// Seed of the aberration noise (and any PSF noise an experiment makes) and of every run.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Where to render: `auto` (a hardware GPU when there is one), `cpu`, or `gpu`.
    #[arg(long, value_enum, default_value_t = crate::splats::device::DeviceChoice::Auto)]
    pub device: crate::splats::device::DeviceChoice,
    /// Replace runs already in --out (otherwise a folder holding a run is refused).
    #[arg(long)]
    pub overwrite: bool,
    /// Continue the runs already in --out from their checkpoints (a finished one is only
    /// evaluated again): an interrupted experiment goes on where it stopped, and a run trained
    /// on its own into its folder (with this experiment's settings) joins the table.
    #[arg(long, conflicts_with = "overwrite")]
    pub resume: bool,
    /// Keep the photos as taken when the cameras have lens distortion (as `train
    /// --keep-distortion`; by default they are undistorted at load).
    #[arg(long)]
    pub keep_distortion: bool,
}

/// What the paper's comparisons (`llff`, `budget`) share: the place, and how every run trains.
#[derive(Args, Clone, Debug)]
pub struct ExperimentRuns {
    #[command(flatten)]
    pub place: ExperimentPlace,
    /// Training steps of every run.
    #[arg(long, default_value_t = 3000, value_parser = clap::value_parser!(u64).range(1..=100_000_000))]
    pub iters: u64,
    /// Densification strategy of every run (as `train --strategy`).
    #[arg(long, value_enum, default_value_t = crate::settings::StrategyChoice::Auto)]
    pub strategy: crate::settings::StrategyChoice,
    /// The first steps of every run at smaller resolutions (as `train --coarse-to-fine`).
    #[arg(long, default_value = "auto")]
    pub coarse_to_fine: crate::settings::CoarseToFine,
    /// What the capture's masks mean to every run (as `train --mask-mode`).
    #[arg(long, value_enum, default_value_t = crate::settings::MaskChoice::Auto)]
    pub mask_mode: crate::settings::MaskChoice,
    /// Also train plain 3DGS on the clean photos with the same settings: the ceiling every
    /// mode is measured against (`--ceiling false` leaves it out).
    #[arg(long, default_value_t = true, action = clap::ArgAction::Set)]
    pub ceiling: bool,
}

/// Makes (once) the aberrated copy of `scene` under `out`, simulating the PSF grid when none
/// is given, and returns its path with the lock that keeps `out` this experiment's alone.
fn aberrated_capture(
    scene: &std::path::Path,
    out: &std::path::Path,
    psf: Option<&std::path::Path>,
    downsample: u32,
    seed: u64,
    keep_distortion: bool,
    say: &mut dyn FnMut(String),
) -> Result<(PathBuf, base::FolderLock)> {
    let mut inputs = vec![("--scene", scene)];
    if let Some(p) = psf {
        inputs.push(("--psf", p));
    }
    crate::output::guard::refuse_overwrite("--out", out, &inputs)?;
    crate::output::guard::refuse_file_as_folder("--out", out)?;
    // Every input is read and checked before --out is made: the capture (unless an earlier
    // run already made the aberrated copy) and the PSF grid given.
    let aberrated = out.join("aberrated");
    let capture = if aberrated.join(scenes::aberrated::RECORD_FILE).exists() {
        refuse_other_copy(
            &aberrated,
            scene,
            &psf.map_or(out.join("psf.npy"), Into::into),
            seed,
            keep_distortion,
        )?;
        None
    } else {
        crate::output::guard::refuse_aberrated_source("--scene", scene)?;
        let opened =
            |e: TrainError| e.context(format!("cannot open the scene {}", scene.display()));
        let options = scenes::OpenOptions {
            resolution: scenes::Resolution::Downsample(downsample),
            undistort: !keep_distortion,
            ..Default::default()
        };
        let capture = scenes::open(scene, &options).map_err(|e| opened(e.into()))?;
        if capture.split.train.is_empty() {
            return Err(TrainError::Invalid(format!(
                "--scene {}: {} view(s) leave no training views once every {}th is held out for testing; use a capture with more views",
                scene.display(),
                capture.len(),
                scenes::LLFFHOLD
            )));
        }
        capture.check_images().map_err(|e| opened(e.into()))?;
        Some(capture)
    };
    if let Some(p) = psf {
        aberration::PsfGrid::load_npy(p)?;
    }
    std::fs::create_dir_all(out).map_err(|e| TrainError::io(out, e))?;
    let lock = base::FolderLock::folder(out, "experiment")?;
    let psf_path = match psf {
        Some(p) => p.to_path_buf(),
        None => {
            let path = out.join("psf.npy");
            if !path.exists() {
                say("simulating the paper's PSF grid".into());
                let (psf, report) =
                    aberration::optics::simulate_grid(&SimConfig::default(), &|_, _| {})?;
                say(format!(
                    "simulated {} field angles x 3 wavelengths in {:.1} s",
                    report.angles_deg.len(),
                    report.seconds
                ));
                psf.save_npy(&path)?;
            }
            path
        }
    };
    if let Some(capture) = capture {
        let options = scenes::AberrateOptions {
            seed,
            ..Default::default()
        };
        let made = scenes::make_aberrated(&capture, &psf_path, &aberrated, &options, &|| {})?;
        say(format!(
            "aberrated {} images {}x{} ({} px PSFs): {:.2} dB vs clean{}",
            made.images,
            made.width,
            made.height,
            made.psf_px,
            made.mean_psnr,
            if made.masked {
                "; masked: composited over black outside the masks before the blur"
            } else {
                ""
            }
        ));
    }
    Ok((aberrated, lock))
}

/// Refuses an aberrated copy, made by an earlier experiment into the same --out, that is not
/// the one this experiment asks for (another capture, noise seed or PSF grid): its runs would
/// train on other photos than the ones named, and the table would mix them.
fn refuse_other_copy(
    aberrated: &std::path::Path,
    scene: &std::path::Path,
    psf: &std::path::Path,
    seed: u64,
    keep_distortion: bool,
) -> Result<()> {
    let Some(record) = scenes::aberrated::AberrationRecord::read(aberrated)? else {
        return Ok(());
    };
    // The record keeps the source as given: from another working folder it may not resolve,
    // and then it cannot be told apart.
    let same_place =
        |a: &std::path::Path, b: &std::path::Path| match (a.canonicalize(), b.canonicalize()) {
            (Ok(a), Ok(b)) => a == b,
            _ => true,
        };
    let mut differs = Vec::new();
    if !same_place(std::path::Path::new(&record.source), scene) {
        differs.push(format!(
            "from {}, not --scene {}",
            record.source,
            scene.display()
        ));
    }
    if record.seed != seed {
        differs.push(format!("with --seed {}, not {seed}", record.seed));
    }
    if let (Some(want), Ok(bytes)) = (&record.psf_checksum, std::fs::read(psf))
        && !base::hash::names(want, &bytes)
    {
        differs.push(format!("through another PSF grid than {}", psf.display()));
    }
    // Only a capture with distortion is undistorted, so only a copy that was undistorted
    // can tell.
    if record.undistorted && keep_distortion {
        differs.push("from undistorted photos, not with --keep-distortion".to_string());
    }
    if differs.is_empty() {
        return Ok(());
    }
    Err(TrainError::Invalid(format!(
        "{} was made by an earlier experiment {}: this one would train on other photos than it names; use another --out, or delete {} to make it again",
        aberrated.display(),
        differs.join(", "),
        aberrated.display()
    )))
}

/// Refuses a list flag that names one value twice: both would train into one run folder.
pub fn refuse_repeats<T: PartialEq + std::fmt::Display>(flag: &str, values: &[T]) -> Result<()> {
    for (i, v) in values.iter().enumerate() {
        if values[..i].contains(v) {
            return Err(TrainError::Invalid(format!(
                "{flag} names {v} twice: each value trains one run into its own folder, so name it once"
            )));
        }
    }
    Ok(())
}

impl ExperimentRuns {
    /// The aberrated copy of the capture the runs train on (made once under --out); `say`
    /// hears what was made.
    pub fn aberrated(&self, say: &mut dyn FnMut(String)) -> Result<(PathBuf, base::FolderLock)> {
        aberrated_capture(
            &self.place.scene,
            &self.place.out,
            self.place.psf.as_deref(),
            self.place.downsample,
            self.place.seed,
            self.place.keep_distortion,
            say,
        )
    }

    /// Refuses, before the aberrated copy or the PSF grid is made, a ceiling run that would
    /// be refused once they are.
    pub fn check_ceiling(&self, request: &RunRequest) -> Result<()> {
        crate::run::check(request).map_err(|e| {
            e.context(format!(
                "the ceiling run (plain 3DGS on the clean photos of {}) would be refused",
                self.place.scene.display()
            ))
        })
    }

    /// Plain 3DGS on the clean capture (`--scene` itself) into `run_dir`, with the settings
    /// every other run has.
    pub fn ceiling_run(&self, run_dir: PathBuf) -> RunRequest {
        let mut args = self.run(&self.place.scene, run_dir, Mode::Plain);
        args.data.iac_cache = None;
        args
    }

    /// A run of `mode` on the aberrated capture into `run_dir`.
    pub fn run(&self, aberrated: &std::path::Path, run_dir: PathBuf, mode: Mode) -> RunRequest {
        let (resume, overwrite) = match (
            self.place.resume,
            run_dir.join(crate::output::CHECKPOINT_FILE).exists(),
        ) {
            (true, true) => (true, false),
            // A run stopped before its first checkpoint left nothing to continue: it starts
            // again.
            (true, false) => (false, run_dir.exists()),
            (false, _) => (false, self.place.overwrite),
        };
        let mut args = RunRequest::new(aberrated, run_dir);
        args.data.downsample = self.place.downsample;
        args.data.seed = self.place.seed;
        args.data.keep_distortion = self.place.keep_distortion;
        // The runs restore the same views: one I_ac cache serves them all.
        args.data.iac_cache = Some(self.place.out.join(crate::train::iac_cache::CACHE_DIR));
        args.device = self.place.device;
        args.overwrite = overwrite;
        args.resume = resume;
        args.training.mode = mode;
        args.training.iters = crate::settings::Iters::Steps(self.iters);
        args.training.strategy = self.strategy;
        args.training.mask_mode = self.mask_mode;
        args.training.coarse_to_fine = self.coarse_to_fine;
        args
    }
}
