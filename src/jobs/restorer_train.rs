//! Training the restorer as a job: [`prepare`] makes every check on the request and reads the
//! PSF grid and the starting weights, writing nothing; [`PreparedRestorerRun::run`] reads the
//! photos, builds the data, trains with its events and returns a [`RestorerReport`].

use aberration::{Image, NoiseModel, PsfGrid};
use clap::Args;
use restore::data::{TrainSet, load_folder, load_pairs};
use restore::family::{LensFamily, ScaleDraw};
use restore::net::kernels::{Kernels, with_kernels};
use restore::provenance::Lineage;
use restore::train::{
    Event, Loss, Schedule, Start, TrainOptions, TrainRun, ValSet, round_seed, train,
};
use restore::{Guidance, Preset, RestorerConfig, weights};
use std::path::{Path, PathBuf};
use std::time::Instant;

use super::refused;
use crate::error::{Result, TrainError};

/// What `restorer train` is asked to do (its flags).
#[derive(Args, Clone, Debug)]
pub struct RestorerTrainRequest {
    /// Folder of clean training photos (aberrated on the fly through --psf).
    #[arg(long, required_unless_present = "pairs")]
    pub images: Option<PathBuf>,
    /// Instead of --images: a folder of captured pairs, `captured/` (photos the lens took)
    /// and `clean/` (the same scenes clean, same file names), as a lab gets by photographing
    /// a display; --psf still feeds the network's Wiener bank.
    #[arg(long, conflicts_with_all = ["images", "family"])]
    pub pairs: Option<PathBuf>,
    /// Folder of clean validation photos (aberrated through --psf), or of captured pairs
    /// (`captured/` and `clean/`).
    #[arg(long)]
    pub val: PathBuf,
    /// The PSF grid (.npy) the training photos are aberrated with on the fly.
    #[arg(long)]
    pub psf: PathBuf,
    /// Network size: tiny, small or paper.
    #[arg(long, value_enum, default_value_t = Preset::Tiny)]
    pub config: Preset,
    /// Weights file to write (updated at every validation).
    #[arg(long)]
    pub out: PathBuf,
    /// Optimiser steps.
    #[arg(long, default_value_t = 2000, value_parser = clap::value_parser!(u64).range(1..=100_000_000))]
    pub steps: u64,
    /// Crops per step.
    #[arg(long, default_value_t = 8, value_parser = clap::value_parser!(u64).range(1..=1024))]
    pub batch: u64,
    /// Side of the square training crops; default: the config's (tiny 64, small 128, paper
    /// 256). A crop's Wiener bank comes from the whole photo whatever its side; a larger crop
    /// lets the network see more of a large PSF's ringing at about the same cost per pixel.
    #[arg(long, value_parser = crate::settings::values::train_crop)]
    pub crop: Option<usize>,
    /// Peak AdamW learning rate, in (0, 1].
    #[arg(long, default_value_t = 3e-4, value_parser = crate::settings::values::learning_rate, allow_negative_numbers = true)]
    pub lr: f64,
    /// Seed of the network, the crops and the noise.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Validate (and save weights and state) every N steps; 0: at the end only.
    #[arg(long, default_value_t = 250)]
    pub val_every: usize,
    /// Validate on centred crops of this side during training (whole images: 0).
    #[arg(long, default_value_t = 128, value_parser = crate::settings::values::val_crop)]
    pub val_crop: usize,
    /// Start from these weights (same config, any PSF grid: fine-tuning to another lens) with
    /// a new optimizer and schedule.
    #[arg(long, conflicts_with = "resume")]
    pub init: Option<PathBuf>,
    /// Train over a family of lenses about the paper's (focal ±5 %, sensor ±5 µm, wavelengths
    /// ±15 nm, rotation ±3°, measured-PSF noise and pedestal), PSF scales of 15-140 px and
    /// noise ×0.5-2, with flips, quarter turns and colour jitter; the weights then serve any
    /// grid of the family. `--psf` is the family's centre (`psf simulate`'s default lens).
    #[arg(long)]
    pub family: bool,
    /// Lenses of the family simulated for the run (each pair draws one); kept in `OUT.lenses/`
    /// so that a resumed or later run simulates none again.
    #[arg(long, default_value_t = 12, value_parser = clap::value_parser!(u64).range(1..=1000), requires = "family")]
    pub lenses: u64,
    /// How each pair's PSF scale is drawn over the family's 15-140 px: `log` (log-uniform,
    /// each doubling equally often) or `linear` (each pixel of side equally often: twice the
    /// share above 85 px, for weights that must gain where the blur is widest).
    #[arg(long, value_enum, default_value_t = ScaleDraw::LogUniform, requires = "family")]
    pub psf_px_draw: ScaleDraw,
    /// The PSF sides (px, `LO-HI`) the pairs are drawn from instead of the family's 15-140,
    /// e.g. `85-140` for weights meant for the widest blur only; the header records the range
    /// and `auto` offers the weights for captures inside it.
    #[arg(long, value_parser = crate::settings::values::psf_px_range, requires = "family")]
    pub psf_px_range: Option<[usize; 2]>,
    /// Continue the interrupted run that writes `--out` exactly where its last checkpoint left
    /// it (weights, `OUT.state`: optimizer moments, schedule, sampler position); --steps,
    /// --batch, --lr, --seed, --refresh-every and --loss must be the run's own (others are
    /// refused).
    #[arg(long)]
    pub resume: bool,
    /// Stop after about this many minutes with a checkpoint (continue later with --resume).
    #[arg(long, value_parser = crate::settings::values::non_negative, allow_negative_numbers = true)]
    pub minutes: Option<f64>,
    /// Re-aberrate the training photos (new noise, new random PSF positions) every N steps;
    /// 0: never.
    #[arg(long, default_value_t = 200)]
    pub refresh_every: usize,
    /// The pixel loss: `l1` (as the paper trains) or `l2`, the mean squared error, whose
    /// optimum PSNR scores highest (a last fine-tune towards it).
    #[arg(long, value_enum, default_value_t = Loss::L1)]
    pub loss: Loss,
    /// How the Wiener bank enters the network; default: the config's (`residual` for tiny and
    /// small, `cross-attention` for paper); `concat` and `single` are ablations.
    #[arg(long, value_enum)]
    pub guidance: Option<Guidance>,
    /// Ablation: fixed Wiener K (no channel intensity in K).
    #[arg(long)]
    pub fixed_k: bool,
    /// The bank filter the network's output is added to (0: K = 1e-2, tiny and small; 6: the
    /// median, paper). Default: the config's.
    #[arg(long)]
    pub residual_base: Option<usize>,
    /// Where to train: `cpu` (burn flex), or `vulkan` in a build with `--features vulkan`.
    #[arg(long, default_value = "cpu")]
    pub backend: restore::Compute,
    /// The network's kernels: `fast`, or the `reference` ones they replaced (to check that
    /// both train alike; slower).
    #[arg(long, value_enum, default_value_t = Kernels::Fast)]
    pub kernels: Kernels,
}

/// What a restorer run tells while it works.
pub enum RestorerEvent<'a> {
    /// A sentence on what the run trains on (the lens family, the data).
    Said(String),
    /// Lenses of the family ready, of `total` (simulated or read back).
    Lenses { done: usize, total: usize },
    /// A phase without a count begins (the CLI shows a spinner until the next event).
    Phase(&'static str),
    /// Training begins at step `first` of `steps`.
    Training { first: usize, steps: usize },
    /// The training loop's own events.
    Step(&'a Event),
}

/// How a run ended.
#[derive(Clone, Debug)]
pub struct RestorerReport {
    /// The step it started from and the step it reached, of `steps`.
    pub first: usize,
    pub reached: usize,
    pub steps: usize,
    pub seconds: f64,
    /// The last validation: PSNR (dB) and SSIM, on centred crops of `val_crop` px (0: whole).
    pub val: (f64, f64),
    pub val_crop: usize,
    /// Every validation of this run: step, seconds, PSNR, SSIM.
    pub log: Vec<(usize, f64, f64, f64)>,
    pub weights: PathBuf,
    pub state: PathBuf,
}

impl RestorerReport {
    /// Whether it stopped before its last step (`--minutes`).
    pub fn stopped_early(&self) -> bool {
        self.reached < self.steps
    }
}

/// A checked request, its grid and its starting point: nothing written yet.
pub struct PreparedRestorerRun {
    request: RestorerTrainRequest,
    train_dir: PathBuf,
    config: RestorerConfig,
    native: PsfGrid,
    schedule: Schedule,
    start: Start,
    lineage: Lineage,
    /// Sentences on how the run starts (a resume, fine-tuning to another lens).
    pub notes: Vec<String>,
    command: String,
    /// Held until the run ends: a second run writing the same `--out` (its weights, state
    /// and lens bank) is refused instead of interleaving its checkpoints with this one's.
    _lock: base::FolderLock,
}

/// Every check on `request`, before a photo is read or anything written; the PSF grid and
/// the starting weights are read. `command` is recorded in the weights' provenance.
pub fn prepare(request: &RestorerTrainRequest, command: &str) -> Result<PreparedRestorerRun> {
    let train_dir = checked_inputs(request)?;
    let device = request
        .backend
        .device()
        .map_err(|e| TrainError::from(e).context("--backend"))?;
    let config = config_from(request)?;
    let native = PsfGrid::load_npy(&request.psf).map_err(|e| {
        TrainError::from(e).context(format!("cannot read {}", request.psf.display()))
    })?;
    let mut schedule = Schedule {
        steps: request.steps as usize,
        batch: request.batch as usize,
        lr: request.lr,
        seed: request.seed,
        refresh_every: request.refresh_every,
        loss: request.loss,
        ..Default::default()
    };
    let mut notes = Vec::new();
    let (start, lineage) = starting_point(
        request,
        &config,
        &native,
        &device,
        &mut schedule,
        &mut notes,
    )?;
    // On the CPU the step lives in this machine's memory (a GPU's is its own).
    if request.backend == restore::Compute::Cpu {
        refuse_training_memory(&config, schedule.batch, request.resume)?;
    }
    // Last of the checks, so a refused request leaves nothing behind but `--out`'s folder.
    let lock = base::FolderLock::beside(&request.out, "restorer train")?;
    Ok(PreparedRestorerRun {
        request: request.clone(),
        train_dir,
        config,
        native,
        schedule,
        start,
        lineage,
        notes,
        command: command.to_string(),
        _lock: lock,
    })
}

/// The machine's memory (`MemTotal`), where the system says (Linux).
fn physical_memory() -> Option<u64> {
    let info = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = info.lines().find(|l| l.starts_with("MemTotal:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}

/// Refuses, before a photo is read, a batch whose training step would not fit in three
/// quarters of the machine's memory (the estimate bounds a step from above; see
/// [`RestorerConfig::training_bytes`]): such a run would be killed by the system, saying
/// nothing, after the photos were aberrated.
fn refuse_training_memory(cfg: &RestorerConfig, batch: usize, resumed: bool) -> Result<()> {
    let Some(memory) = physical_memory() else {
        return Ok(());
    };
    let budget = memory / 4 * 3;
    let need = cfg.training_bytes(batch, cfg.crop);
    if need <= budget {
        return Ok(());
    }
    let fits = (1..batch)
        .rev()
        .find(|&b| cfg.training_bytes(b, cfg.crop) <= budget);
    let way_out = match (fits, resumed) {
        (_, true) => "the batch is the saved run's: continue on a machine with more memory, or start again with --init and a smaller --batch".to_string(),
        (Some(b), false) => format!("use --batch {b} or less, or a smaller --config"),
        (None, false) => "even one crop does not fit: use a smaller --config".to_string(),
    };
    Err(TrainError::Invalid(format!(
        "--batch {batch}: a training step of config '{}' on {batch} crops of {} px needs about {}, more than three quarters of this machine's {}; {way_out}",
        cfg.name,
        cfg.crop,
        gb(need),
        gb(memory)
    )))
}

fn gb(bytes: u64) -> String {
    format!("{:.1} GB", bytes as f64 / 1e9)
}

fn config_from(a: &RestorerTrainRequest) -> Result<RestorerConfig> {
    let mut preset = RestorerConfig::preset(a.config);
    let name = preset.name.clone();
    if let Some(side) = a.crop {
        // The config's own check (its downsampling levels and attention windows divide the
        // side), named by the flag that set it.
        preset.crop = side;
        preset
            .validate()
            .map_err(|e| TrainError::Invalid(format!("--crop {side}: {e}")))?;
    }
    preset
        .with_ablations(a.guidance, a.fixed_k, a.residual_base)
        .map_err(|e| {
            TrainError::Invalid(format!(
                "--guidance/--fixed-k/--residual-base on config '{name}': {e}"
            ))
        })
}

/// Every check on the flags and folders, before anything is read: returns the training
/// photos' folder.
fn checked_inputs(a: &RestorerTrainRequest) -> Result<PathBuf> {
    let (train_flag, train_dir) = match (&a.images, &a.pairs) {
        (_, Some(p)) => ("--pairs", p.as_path()),
        (Some(i), None) => ("--images", i.as_path()),
        (None, None) => return refused("--images or --pairs: name the training photos".into()),
    };
    let mut inputs = vec![
        (train_flag, train_dir),
        ("--val", a.val.as_path()),
        ("--psf", a.psf.as_path()),
    ];
    if let Some(i) = &a.init {
        inputs.push(("--init", i));
    }
    crate::output::guard::refuse_overwrite("--out", &a.out, &inputs)?;
    if a.out.is_dir() {
        return refused(format!(
            "--out {} is a folder; name the weights file to write",
            a.out.display()
        ));
    }
    if a.pairs.is_some() && !restore::data::is_pairs_folder(train_dir) {
        return refused(format!(
            "--pairs {}: needs the folders {} and {} inside",
            train_dir.display(),
            restore::data::CAPTURED_DIR,
            restore::data::CLEAN_DIR
        ));
    }
    for (flag, dir) in [(train_flag, train_dir), ("--val", a.val.as_path())] {
        if !dir.is_dir() {
            return refused(format!(
                "{flag} {}: {}; name a folder of photos",
                dir.display(),
                if dir.exists() {
                    "is not a folder"
                } else {
                    "not found"
                }
            ));
        }
    }
    // Validation on the training photos would measure memory, not restoration.
    if let (Ok(i), Ok(v)) = (train_dir.canonicalize(), a.val.canonicalize())
        && (i.starts_with(&v) || v.starts_with(&i))
    {
        return refused(format!(
            "--val {} and {train_flag} {} hold the same photos: validate on photos the network does not train on",
            a.val.display(),
            train_dir.display()
        ));
    }
    Ok(train_dir.to_path_buf())
}

/// Each flag of `schedule` that differs from the saved run's, as `--flag now (the run has
/// then)`.
fn changed_settings(schedule: &Schedule, saved: &Schedule) -> Vec<String> {
    [
        (
            "--steps",
            schedule.steps.to_string(),
            saved.steps.to_string(),
        ),
        (
            "--batch",
            schedule.batch.to_string(),
            saved.batch.to_string(),
        ),
        (
            "--lr",
            format!("{:e}", schedule.lr),
            format!("{:e}", saved.lr),
        ),
        ("--seed", schedule.seed.to_string(), saved.seed.to_string()),
        (
            "--refresh-every",
            schedule.refresh_every.to_string(),
            saved.refresh_every.to_string(),
        ),
        ("--loss", value_name(schedule.loss), value_name(saved.loss)),
    ]
    .into_iter()
    .filter(|(_, now, then)| now != then)
    .map(|(flag, now, then)| format!("{flag} {now} (the run has {then})"))
    .collect()
}

/// Where the run starts: a fresh network, `--init` weights of any lens (fine-tuning), or the
/// saved run (`--resume`, whose schedule replaces `schedule`, each flag that says otherwise
/// refused); with what the weights file's provenance carries over from the weights it
/// started from. What it decides goes to `notes`.
fn starting_point(
    a: &RestorerTrainRequest,
    cfg: &RestorerConfig,
    native: &PsfGrid,
    device: &restore::Device,
    schedule: &mut Schedule,
    notes: &mut Vec<String>,
) -> Result<(Start, Lineage)> {
    // A resumed run continues on the grid it was trained for; `--init` starts from weights of
    // any lens (fine-tuning to a user's own grid).
    let device = device.clone().autodiff();
    let load = |p: &Path, grid: Option<&PsfGrid>| weights::load(p, &device, Some(cfg), grid);
    if !a.resume {
        return Ok(match &a.init {
            Some(p) => {
                // Into this run's network: the weights' own bank K and residual base may
                // differ (the network relearns what it adds to the new base).
                let (net, header) = weights::load_into(p, &device, cfg)?;
                if !cfg.same_network(&header.config) {
                    notes.push(format!(
                        "Fine-tuning {} (config '{}') as '{}': the bank's K or the residual \
                         base differs from the weights'",
                        p.display(),
                        header.config.name,
                        cfg.name
                    ));
                }
                if let Err(why) = header.serves(native) {
                    notes.push(format!(
                        "Fine-tuning {} to --psf {}: {why}",
                        p.display(),
                        a.psf.display()
                    ));
                }
                (Start::Init(net), Lineage::init_from(header.provenance))
            }
            None => (Start::Fresh, Lineage::fresh()),
        });
    }
    let cannot = |e: restore::RestoreError| TrainError::from(e).context("cannot resume");
    let (net, header) = load(&a.out, Some(native)).map_err(cannot)?;
    let (state, record) = restore::train_state::load(&a.out).map_err(cannot)?;
    // A flag that says otherwise than the saved run would be ignored: refuse it, naming
    // each, as `train --resume` does.
    let mut changed = changed_settings(schedule, &state.schedule);
    // The crop side is the network config's field, recorded in the weights' header.
    if header.config.crop != cfg.crop {
        changed.push(format!(
            "--crop {} (the run has {})",
            cfg.crop, header.config.crop
        ));
    }
    let out = a.out.display();
    if !changed.is_empty() {
        return refused(format!(
            "{out}: cannot resume with other settings: {}; resume with the run's settings, or start a new run from its weights with --init",
            changed.join(", ")
        ));
    }
    if header.family.is_some() != a.family {
        return refused(format!(
            "{out}: cannot resume {} --family: the run was made {}",
            if a.family { "with" } else { "without" },
            if header.family.is_some() {
                "over a lens family"
            } else {
                "for one grid"
            }
        ));
    }
    if let Some(saved) = &header.family {
        let drawn = serde_json::from_value::<LensFamily>(saved.drawn.clone()).ok();
        if let Some(d) = &drawn
            && d.psf_px_draw != a.psf_px_draw
        {
            return refused(format!(
                "{out}: cannot resume with --psf-px-draw {}: the run draws its PSF scales {}",
                value_name(a.psf_px_draw),
                value_name(d.psf_px_draw),
            ));
        }
        let asked = family_of(a).psf_px;
        if let Some(d) = drawn.filter(|d| d.psf_px != asked) {
            return refused(format!(
                "{out}: cannot resume with --psf-px-range {}-{}: the run draws its PSF scales over {}-{} px",
                asked[0], asked[1], d.psf_px[0], d.psf_px[1],
            ));
        }
    }
    *schedule = state.schedule.clone();
    let s = &*schedule;
    if state.step >= s.steps {
        return refused(format!(
            "{out}: that run finished ({} of {} steps); continue it with --init {out} and a new --out",
            state.step, s.steps,
        ));
    }
    notes.push(format!(
        "resuming {out} at step {} of {} (batch {}, lr {:.1e}, seed {} from the saved state)",
        state.step, s.steps, s.batch, s.lr, s.seed
    ));
    let lineage = Lineage::resumed(header.provenance, state.step);
    Ok((Start::Resume(net, Box::new(state), record), lineage))
}

/// The family `--family` trains over: issue 51's, its scales drawn as `--psf-px-draw` says.
fn family_of(a: &RestorerTrainRequest) -> LensFamily {
    let base = LensFamily::default();
    LensFamily {
        psf_px_draw: a.psf_px_draw,
        psf_px: a.psf_px_range.unwrap_or(base.psf_px),
        ..base
    }
}

/// A flag value as the command line spells it (`linear`, `l2`).
fn value_name<T: clap::ValueEnum + std::fmt::Debug>(v: T) -> String {
    v.to_possible_value()
        .map_or_else(|| format!("{v:?}"), |p| p.get_name().to_string())
}

/// The lenses a family run draws from: `centre` (the `--psf` grid) and `count - 1` lenses
/// drawn about the paper's, simulated once and kept in `OUT.lenses/` (a file there that does
/// not load is simulated again).
fn lens_bank(
    family: &LensFamily,
    centre: &PsfGrid,
    out: &Path,
    count: usize,
    seed: u64,
    on_event: &mut dyn FnMut(RestorerEvent),
) -> Result<Vec<PsfGrid>> {
    let mut dir = out.as_os_str().to_owned();
    dir.push(".lenses");
    let dir = PathBuf::from(dir);
    std::fs::create_dir_all(&dir).map_err(|e| TrainError::io(&dir, e))?;
    let base = aberration::optics::SimConfig::default();
    let mut lenses = vec![centre.clone()];
    let mut simulated = 0;
    on_event(RestorerEvent::Lenses {
        done: 1,
        total: count,
    });
    for i in 1..count {
        // Each lens takes most of a minute to simulate: a stop asked for here must not wait
        // for the whole bank (what is simulated is kept and read again by the same command).
        if base::interrupt::requested() {
            return Err(TrainError::Interrupted(format!(
                "while simulating the lens family ({i} of {count} ready, kept in {}): nothing trained yet; the same command reads them again",
                dir.display()
            )));
        }
        let path = dir.join(format!("lens_{i:03}_seed{seed}.npy"));
        let grid = match PsfGrid::load_npy(&path) {
            Ok(g) => g,
            Err(_) => {
                let g = family.lens(&base, i, seed).simulate().map_err(|e| {
                    TrainError::from(e).context(format!("simulating lens {i} of the family"))
                })?;
                g.save_npy(&path).map_err(|e| {
                    TrainError::from(e).context(format!("cannot write {}", path.display()))
                })?;
                simulated += 1;
                g
            }
        };
        lenses.push(grid);
        on_event(RestorerEvent::Lenses {
            done: i + 1,
            total: count,
        });
    }
    on_event(RestorerEvent::Said(format!(
        "lens family: --psf and {} drawn lenses ({simulated} simulated now, the rest read from {})",
        count - 1,
        dir.display()
    )));
    Ok(lenses)
}

/// The validation photos (clean, with their names) and, for a pairs folder, the pairs.
type ValPhotos = (Vec<(String, Image)>, Option<Vec<(String, Image, Image)>>);

impl PreparedRestorerRun {
    /// The validation photos and pairs, refusing a `--val-crop` no photo can give (it would
    /// silently validate on whole images instead).
    fn val_photos(&self) -> Result<ValPhotos> {
        let a = &self.request;
        let pairs = if restore::data::is_pairs_folder(&a.val) {
            Some(load_pairs(&a.val, self.config.crop)?)
        } else {
            None
        };
        let photos = match &pairs {
            Some(p) => p.iter().map(|(n, _, c)| (n.clone(), c.clone())).collect(),
            None => load_folder(&a.val, self.config.crop)?,
        };
        if a.val_crop > 0
            && let Some((name, img)) = photos
                .iter()
                .min_by_key(|(_, i)| i.width.min(i.height))
                .filter(|(_, i)| i.width.min(i.height) < a.val_crop)
        {
            return refused(format!(
                "--val-crop {}: {} in --val {} is {}x{}; use at most {} px, or 0 to validate on whole photos",
                a.val_crop,
                name,
                a.val.display(),
                img.width,
                img.height,
                img.width.min(img.height)
            ));
        }
        Ok((photos, pairs))
    }

    /// Reads the photos, builds the training and validation data and trains, saving weights
    /// and state at every validation; a stop asked for (Ctrl-C) is an
    /// [`TrainError::Interrupted`] saying how to continue.
    pub fn run(self, on_event: &mut dyn FnMut(RestorerEvent)) -> Result<RestorerReport> {
        let (a, cfg, native) = (&self.request, &self.config, &self.native);
        let (photos, pairs): (Vec<Image>, Vec<(Image, Image)>) = match &a.pairs {
            Some(dir) => (
                vec![],
                load_pairs(dir, cfg.crop)?
                    .into_iter()
                    .map(|(_, captured, clean)| (captured, clean))
                    .collect(),
            ),
            None => (
                load_folder(&self.train_dir, cfg.crop)?
                    .into_iter()
                    .map(|(_, i)| i)
                    .collect(),
                vec![],
            ),
        };
        let (val_photos, val_pairs) = self.val_photos()?;
        let noise = NoiseModel::default();
        if let Some(dir) = a.out.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(|e| TrainError::io(dir, e))?;
        }
        let family = a.family.then(|| family_of(a));
        let lenses = match &family {
            Some(f) => lens_bank(f, native, &a.out, a.lenses as usize, a.seed, on_event)?,
            None => vec![],
        };
        let first = match &self.start {
            Start::Resume(_, state, _) => state.step,
            _ => 0,
        };
        let opts = TrainOptions {
            schedule: self.schedule.clone(),
            val_every: a.val_every,
            noise,
            compute: a.backend,
            stop_after_seconds: a.minutes.map(|m| m * 60.0),
            family: family.as_ref().and_then(|f| f.record(&lenses)),
            ..Default::default()
        };
        let s = &opts.schedule;
        let make_set = |round: usize| match &family {
            _ if a.pairs.is_some() => TrainSet::from_pairs(&pairs, native, cfg, &|| {}),
            Some(f) => TrainSet::build_family(
                &photos,
                &lenses,
                f,
                cfg,
                noise,
                round_seed(s.seed, round),
                &|| {},
            ),
            None => TrainSet::build(
                &photos,
                native,
                cfg,
                noise,
                round_seed(s.seed, round),
                &|| {},
            ),
        };
        on_event(RestorerEvent::Phase("validation set"));
        let built = Instant::now();
        let crop = (a.val_crop > 0).then_some(a.val_crop);
        let val = match (&val_pairs, &family) {
            (Some(p), _) => ValSet::from_pairs(p, native, cfg, crop),
            (None, Some(_)) => ValSet::build_family(&val_photos, &lenses, cfg, noise, crop),
            (None, None) => ValSet::build(&val_photos, native, cfg, noise, crop),
        }?;
        on_event(RestorerEvent::Said(format!(
            "{}; {} validation {} ({:.1} s); config '{}', {} parameters, training crops of {} px",
            if a.pairs.is_some() {
                format!("{} captured pairs", pairs.len())
            } else {
                format!(
                    "{} training photos, aberrated {}",
                    photos.len(),
                    if s.refresh_every > 0 {
                        format!("again every {} steps", s.refresh_every)
                    } else {
                        "once for the whole run".into()
                    }
                )
            },
            val.names.len(),
            if val_pairs.is_some() {
                "pairs"
            } else {
                "photos"
            },
            built.elapsed().as_secs_f64(),
            cfg.name,
            cfg.analytic_params(),
            cfg.crop
        )));
        let command = &self.command;
        let provenance = |step: usize, seconds: f64, m: (f64, f64)| {
            let p = serde_json::json!({
                "command": command,
                "steps": step,
                "batch": s.batch,
                "seed": s.seed,
                "seconds": seconds,
                "threads": rayon::current_num_threads(),
                "train_photos": photos.len().max(pairs.len()),
                "captured_pairs": a.pairs.is_some(),
                "val_psnr": m.0,
                "val_ssim": m.1,
                "val_crop": a.val_crop,
            });
            self.lineage.apply(p, command)
        };
        on_event(RestorerEvent::Training {
            first,
            steps: s.steps,
        });
        let mut log = Vec::new();
        let started = Instant::now();
        let run = TrainRun {
            config: cfg,
            native,
            pairs: &make_set,
            val: &val,
            options: &opts,
            out: &a.out,
            provenance: &provenance,
        };
        let (_, last, reached) = with_kernels(a.kernels, || {
            train(&run, self.start, &mut |e| {
                if let Event::Val {
                    step,
                    psnr,
                    ssim,
                    seconds,
                    ..
                } = e
                {
                    log.push((step, seconds, psnr, ssim));
                }
                on_event(RestorerEvent::Step(&e));
            })
        })?;
        if reached < s.steps && base::interrupt::requested() {
            return Err(TrainError::Interrupted(format!(
                "at step {reached} of {}; the weights and the state are saved: continue with the same command and --resume (without --init)",
                s.steps
            )));
        }
        Ok(RestorerReport {
            first,
            reached,
            steps: s.steps,
            seconds: started.elapsed().as_secs_f64(),
            val: last,
            val_crop: a.val_crop,
            log,
            weights: a.out.clone(),
            state: restore::train_state::state_path(&a.out),
        })
    }
}
