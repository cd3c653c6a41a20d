//! `metasplat restorer train|eval` and `metasplat restore`: the aberration-correcting
//! transformer.

use super::progress::{bar, say, step};
use aberration::wiener::{BANK_MEDIAN, bank_constants};
use aberration::{BlurMode, Image, ImagingModel, NoiseModel, PsfGrid, Regularizer, deconvolve};
use anyhow::{Context, Result, bail};
use clap::{Args, Subcommand};
use restore::data::{TrainSet, list_images, load_photo};
use restore::family::LensFamily;
use restore::net::kernels::{Kernels, with_kernels};
use restore::provenance::Lineage;
use restore::train::{Event, Schedule, Start, TrainOptions, TrainRun, ValSet, round_seed, train};
use restore::{Guidance, Preset, Restorer, RestorerConfig, weights};
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(Subcommand)]
pub enum RestorerCommand {
    /// Train the MAFG + STAF restorer on clean photos aberrated on the fly.
    Train(TrainRestorerArgs),
    /// Validation table: best single-K Wiener, median MAFG image, the network.
    Eval(EvalArgs),
    /// Score a restored clip (a folder of frames) against its clean one: per-frame PSNR and
    /// SSIM, and its flicker (how much more consecutive frames differ than the clean ones do).
    EvalVideo(EvalVideoArgs),
}

#[derive(Args)]
pub struct EvalVideoArgs {
    /// The restored clip: a folder of frames, in name order.
    #[arg(long)]
    pub restored: PathBuf,
    /// The clean clip: as many frames of the same size, in name order.
    #[arg(long)]
    pub clean: PathBuf,
}

#[derive(Args)]
pub struct TrainRestorerArgs {
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
    /// Peak AdamW learning rate, in (0, 1].
    #[arg(long, default_value_t = 3e-4, value_parser = metasplat::settings::values::learning_rate, allow_negative_numbers = true)]
    pub lr: f64,
    /// Seed of the network, the crops and the noise.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Validate (and save weights and state) every N steps; 0: at the end only.
    #[arg(long, default_value_t = 250)]
    pub val_every: usize,
    /// Validate on centred crops of this side during training (whole images: 0).
    #[arg(long, default_value_t = 128, value_parser = metasplat::settings::values::val_crop)]
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
    /// Continue the interrupted run that writes `--out` exactly where its last checkpoint left
    /// it (weights, `OUT.state`: optimizer moments, schedule, sampler position); --steps,
    /// --batch, --lr, --seed and --refresh-every must be the run's own (others are refused).
    #[arg(long)]
    pub resume: bool,
    /// Stop after about this many minutes with a checkpoint (continue later with --resume).
    #[arg(long, value_parser = metasplat::settings::values::non_negative, allow_negative_numbers = true)]
    pub minutes: Option<f64>,
    /// Re-aberrate the training photos (new noise, new random PSF positions) every N steps;
    /// 0: never.
    #[arg(long, default_value_t = 200)]
    pub refresh_every: usize,
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

/// How large images are cut for the network.
#[derive(Args)]
pub struct Tiling {
    /// Tile side in px (a multiple of the config's padding unit); default: the largest that
    /// fits the memory budget (512 for `tiny`).
    #[arg(long)]
    pub tile: Option<usize>,
    /// Overlap of neighbouring tiles in px, blended by linear ramps.
    #[arg(long)]
    pub overlap: Option<usize>,
}

impl Tiling {
    fn apply(&self, r: Restorer) -> Result<Restorer> {
        let (tile, overlap) = (
            self.tile.unwrap_or(r.tile),
            self.overlap.unwrap_or(r.overlap),
        );
        r.with_tiling(tile, overlap)
            .with_context(|| format!("--tile {tile} --overlap {overlap}"))
    }
}

/// A trained restorer and the PSF grid it restores through, as `restorer eval` and `restore`
/// load them.
#[derive(Args)]
pub struct Inference {
    /// Restorer weights; without it, the network shipped in the binary
    /// (`restore/weights/tiny.bin`, else the general `family_tiny_2.bin`), when one serves this
    /// PSF grid.
    #[arg(long)]
    pub weights: Option<PathBuf>,
    /// PSF grid (`.npy`, from `psf simulate`) the images were aberrated with.
    #[arg(long)]
    pub psf: PathBuf,
    /// `cpu`, or `vulkan` in a build with `--features vulkan`.
    #[arg(long, default_value = "cpu")]
    pub backend: restore::Compute,
    /// Restore through this grid even when the weights do not cover its lens (to measure them
    /// there); without it such weights are refused, saying what they cover.
    #[arg(long)]
    pub any_grid: bool,
    #[command(flatten)]
    pub tiling: Tiling,
}

impl Inference {
    /// The native PSF grid and the restorer loaded on the chosen backend with its tiling;
    /// without --weights, the shipped one that serves the grid with PSFs `psf_px` wide at the
    /// images' size (None: at any size).
    fn load(&self, psf_px: impl FnOnce(&PsfGrid) -> Option<usize>) -> Result<(PsfGrid, Restorer)> {
        let native = PsfGrid::load_npy(&self.psf)
            .with_context(|| format!("cannot read {}", self.psf.display()))?;
        let psf_px = psf_px(&native);
        let device = self.backend.device().context("--backend")?;
        let net = match (&self.weights, self.any_grid) {
            (Some(w), false) => Restorer::load_on(w, &native, device)
                .with_context(|| format!("--weights with --psf {}", self.psf.display()))?,
            (Some(w), true) => Restorer::load_any_grid_on(w, device)
                .with_context(|| format!("--weights {}", w.display()))?,
            (None, any_grid) => {
                match restore::shipped::for_capture_on(&native, psf_px, device.clone())? {
                    restore::shipped::Choice::Network(net, why, _) => {
                        println!("Using {why}.");
                        *net
                    }
                    restore::shipped::Choice::Declined(why) if any_grid => {
                        let general = restore::shipped::GENERAL;
                        println!(
                            "Using {} outside what it covers (--any-grid): {why}.",
                            general.name
                        );
                        Restorer::from_bytes_any_grid_on(
                            general.bytes,
                            Path::new(general.name),
                            device,
                        )?
                    }
                    restore::shipped::Choice::Declined(why) => bail!(
                        "--weights: none given, and {why} (--psf {}); train one with `metasplat restorer train`, or pass --any-grid to measure it there",
                        self.psf.display()
                    ),
                }
            }
        };
        Ok((native, self.tiling.apply(net)?))
    }

    /// The files this reads, for the output-aliasing guard.
    fn inputs(&self) -> Vec<(&'static str, &Path)> {
        let mut v = vec![("--psf", self.psf.as_path())];
        if let Some(w) = &self.weights {
            v.push(("--weights", w.as_path()));
        }
        v
    }
}

#[derive(Args)]
pub struct EvalArgs {
    #[command(flatten)]
    pub net: Inference,
    /// Folder of clean validation photos.
    #[arg(long)]
    pub val: PathBuf,
    /// Write per photo here: aberrated, residual-base Wiener, restored and clean side by side.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Blur the photos with the grid's PSFs mapped to this many pixels at each photo's size
    /// (odd; an even number lands on a neighbour); default: the grid's own sensor, G·K px.
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=aberration::resample::MAX_MAPPED_PSF_PX as u64))]
    pub psf_px: Option<u64>,
}

#[derive(Args)]
pub struct RestoreArgs {
    #[command(flatten)]
    pub net: Inference,
    /// The aberrated photo (PNG or JPEG), or a folder of them (the frames of a video, all of
    /// one size): each is restored into --out, a folder, under its own name as PNG.
    #[arg(long = "in")]
    pub input: PathBuf,
    /// Where the restored photo goes (PNG), or the folder the restored frames go to.
    #[arg(long)]
    pub out: PathBuf,
    /// With a folder: keep the frames --out already holds and restore the others (after a
    /// stop).
    #[arg(long)]
    pub resume: bool,
    /// Sensor size (px) the grid was made for; default G·K.
    #[arg(long, value_parser = metasplat::settings::values::sensor_px)]
    pub sensor_px: Option<usize>,
    /// A clean image to report PSNR/SSIM against.
    #[arg(long)]
    pub reference: Option<PathBuf>,
}

pub fn run(c: RestorerCommand) -> Result<()> {
    match c {
        RestorerCommand::Train(a) => run_train(a),
        RestorerCommand::Eval(a) => run_eval(a),
        RestorerCommand::EvalVideo(a) => run_eval_video(a),
    }
}

fn metric(a: &Image, b: &Image) -> Result<(f64, f64)> {
    Ok(aberration::compare(a, b)?)
}

/// Sums of one method's scores over the photos: PSNR and SSIM on RGB, and PSNR on the luma
/// channel, the paper's figure.
#[derive(Clone, Copy, Default)]
struct Score {
    psnr: f64,
    ssim: f64,
    psnr_y: f64,
}

impl Score {
    fn add(&mut self, image: &Image, clean: &Image) -> Result<()> {
        let (p, s) = metric(image, clean)?;
        let mut clamped = image.clone();
        clamped.clamp01();
        self.psnr += p;
        self.ssim += s;
        self.psnr_y += base::metrics::psnr_y_planar(&clamped.data, &clean.data)?;
        Ok(())
    }
}

fn load_folder(dir: &Path, min_side: usize) -> Result<Vec<(String, Image)>> {
    let paths = list_images(dir)?;
    paths
        .iter()
        .map(|p| {
            let name = p
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default();
            Ok((name, load_photo(p, min_side)?))
        })
        .collect()
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
    bail!(
        "--batch {batch}: a training step of config '{}' on {batch} crops of {} px needs about {}, more than three quarters of this machine's {}; {way_out}",
        cfg.name,
        cfg.crop,
        gb(need),
        gb(memory)
    )
}

fn gb(bytes: u64) -> String {
    format!("{:.1} GB", bytes as f64 / 1e9)
}

fn config_from(a: &TrainRestorerArgs) -> Result<RestorerConfig> {
    let preset = RestorerConfig::preset(a.config);
    let name = preset.name.clone();
    preset
        .with_ablations(a.guidance, a.fixed_k, a.residual_base)
        .map_err(|e| {
            anyhow::anyhow!("--guidance/--fixed-k/--residual-base on config '{name}': {e}")
        })
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
) -> Result<Vec<PsfGrid>> {
    let mut dir = out.as_os_str().to_owned();
    dir.push(".lenses");
    let dir = PathBuf::from(dir);
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let base = aberration::optics::SimConfig::default();
    let pb = bar(count as u64, "lens family");
    let mut lenses = vec![centre.clone()];
    let mut simulated = 0;
    pb.inc(1);
    for i in 1..count {
        let path = dir.join(format!("lens_{i:03}_seed{seed}.npy"));
        let grid = match PsfGrid::load_npy(&path) {
            Ok(g) => g,
            Err(_) => {
                let lens = family.lens(&base, i, seed);
                let g = lens
                    .simulate()
                    .with_context(|| format!("simulating lens {i} of the family"))?;
                g.save_npy(&path)
                    .with_context(|| format!("cannot write {}", path.display()))?;
                simulated += 1;
                g
            }
        };
        lenses.push(grid);
        pb.inc(1);
    }
    pb.finish_and_clear();
    println!(
        "lens family: --psf and {} drawn lenses ({simulated} simulated now, the rest read from {})",
        count - 1,
        dir.display()
    );
    Ok(lenses)
}

fn run_train(a: TrainRestorerArgs) -> Result<()> {
    let (train_flag, train_dir) = match (&a.images, &a.pairs) {
        (_, Some(p)) => ("--pairs", p.as_path()),
        (Some(i), None) => ("--images", i.as_path()),
        (None, None) => bail!("--images or --pairs: name the training photos"),
    };
    let mut inputs = vec![
        (train_flag, train_dir),
        ("--val", a.val.as_path()),
        ("--psf", a.psf.as_path()),
    ];
    if let Some(i) = &a.init {
        inputs.push(("--init", i));
    }
    metasplat::output::guard::refuse_overwrite("--out", &a.out, &inputs)?;
    if a.out.is_dir() {
        bail!(
            "--out {} is a folder; name the weights file to write",
            a.out.display()
        );
    }
    if a.pairs.is_some() && !restore::data::is_pairs_folder(train_dir) {
        bail!(
            "--pairs {}: needs the folders {} and {} inside",
            train_dir.display(),
            restore::data::CAPTURED_DIR,
            restore::data::CLEAN_DIR
        );
    }
    for (flag, dir) in [(train_flag, train_dir), ("--val", a.val.as_path())] {
        if !dir.is_dir() {
            bail!(
                "{flag} {}: {}; name a folder of photos",
                dir.display(),
                if dir.exists() {
                    "is not a folder"
                } else {
                    "not found"
                }
            );
        }
    }
    // Validation on the training photos would measure memory, not restoration.
    if let (Ok(i), Ok(v)) = (train_dir.canonicalize(), a.val.canonicalize())
        && (i.starts_with(&v) || v.starts_with(&i))
    {
        anyhow::bail!(
            "--val {} and {train_flag} {} hold the same photos: validate on photos the network does not train on",
            a.val.display(),
            train_dir.display()
        );
    }
    let device = a.backend.device().context("--backend")?;
    let cfg = config_from(&a)?;
    let native =
        PsfGrid::load_npy(&a.psf).with_context(|| format!("cannot read {}", a.psf.display()))?;
    // A resumed run continues on the grid it was trained for; `--init` starts from weights of
    // any lens (fine-tuning to a user's own grid).
    let load = |p: &Path, grid: Option<&PsfGrid>| {
        let device = device.clone().autodiff();
        weights::load(p, &device, Some(&cfg), grid)
    };
    let mut schedule = Schedule {
        steps: a.steps as usize,
        batch: a.batch as usize,
        lr: a.lr,
        seed: a.seed,
        refresh_every: a.refresh_every,
        ..Default::default()
    };
    // What the weights file's provenance carries over from the weights it started from.
    let lineage;
    let start = if a.resume {
        let (net, header) = load(&a.out, Some(&native)).context("cannot resume")?;
        let (state, record) = restore::train_state::load(&a.out).context("cannot resume")?;
        // A flag that says otherwise than the saved run would be ignored: refuse it, naming
        // each, as `train --resume` does.
        let saved = &state.schedule;
        let changed: Vec<String> = [
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
        ]
        .into_iter()
        .filter(|(_, now, then)| now != then)
        .map(|(flag, now, then)| format!("{flag} {now} (the run has {then})"))
        .collect();
        if !changed.is_empty() {
            bail!(
                "{}: cannot resume with other settings: {}; resume with the run's settings, or start a new run from its weights with --init",
                a.out.display(),
                changed.join(", ")
            );
        }
        if header.family.is_some() != a.family {
            bail!(
                "{}: cannot resume {} --family: the run was made {}",
                a.out.display(),
                if a.family { "with" } else { "without" },
                if header.family.is_some() {
                    "over a lens family"
                } else {
                    "for one grid"
                }
            );
        }
        schedule = state.schedule.clone();
        let s = &schedule;
        if state.step >= s.steps {
            bail!(
                "{}: that run finished ({} of {} steps); continue it with --init {} and a new --out",
                a.out.display(),
                state.step,
                s.steps,
                a.out.display()
            );
        }
        println!(
            "resuming {} at step {} of {} (batch {}, lr {:.1e}, seed {} from the saved state)",
            a.out.display(),
            state.step,
            s.steps,
            s.batch,
            s.lr,
            s.seed
        );
        lineage = Lineage::resumed(header.provenance, state.step);
        Start::Resume(net, Box::new(state), record)
    } else {
        match &a.init {
            Some(p) => {
                let (net, header) = load(p, None)?;
                if let Err(why) = header.serves(&native) {
                    println!(
                        "Fine-tuning {} to --psf {}: {why}",
                        p.display(),
                        a.psf.display()
                    );
                }
                lineage = Lineage::init_from(header.provenance);
                Start::Init(net)
            }
            None => {
                lineage = Lineage::fresh();
                Start::Fresh
            }
        }
    };
    // On the CPU the step lives in this machine's memory (a GPU's is its own).
    if a.backend == restore::Compute::Cpu {
        refuse_training_memory(&cfg, schedule.batch, a.resume)?;
    }
    let (photos, pairs): (Vec<Image>, Vec<(Image, Image)>) = match &a.pairs {
        Some(dir) => (
            vec![],
            restore::data::load_pairs(dir, cfg.crop)?
                .into_iter()
                .map(|(_, captured, clean)| (captured, clean))
                .collect(),
        ),
        None => (
            load_folder(train_dir, cfg.crop)?
                .into_iter()
                .map(|(_, i)| i)
                .collect(),
            vec![],
        ),
    };
    let val_pairs = if restore::data::is_pairs_folder(&a.val) {
        Some(restore::data::load_pairs(&a.val, cfg.crop)?)
    } else {
        None
    };
    let val_photos = match &val_pairs {
        Some(p) => p.iter().map(|(n, _, c)| (n.clone(), c.clone())).collect(),
        None => load_folder(&a.val, cfg.crop)?,
    };
    // A crop no photo can give would silently validate on whole images instead.
    if a.val_crop > 0
        && let Some((name, img)) = val_photos
            .iter()
            .min_by_key(|(_, i)| i.width.min(i.height))
            .filter(|(_, i)| i.width.min(i.height) < a.val_crop)
    {
        anyhow::bail!(
            "--val-crop {}: {} in --val {} is {}x{}; use at most {} px, or 0 to validate on whole photos",
            a.val_crop,
            name,
            a.val.display(),
            img.width,
            img.height,
            img.width.min(img.height)
        );
    }
    let noise = NoiseModel::default();
    if let Some(dir) = a.out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    }
    let family = a.family.then(LensFamily::default);
    let lenses = match &family {
        Some(f) => lens_bank(f, &native, &a.out, a.lenses as usize, a.seed)?,
        None => vec![],
    };
    let first = match &start {
        Start::Resume(_, state, _) => state.step,
        _ => 0,
    };
    let opts = TrainOptions {
        schedule,
        val_every: a.val_every,
        noise,
        compute: a.backend,
        stop_after_seconds: a.minutes.map(|m| m * 60.0),
        family: family.as_ref().and_then(|f| f.record(&lenses)),
        ..Default::default()
    };
    // After a resume, the saved schedule (train() takes it from the state too).
    let s = &opts.schedule;
    let make_set = |round: usize| match &family {
        _ if a.pairs.is_some() => TrainSet::from_pairs(&pairs, &native, &cfg, &|| {}),
        Some(f) => TrainSet::build_family(
            &photos,
            &lenses,
            f,
            &cfg,
            noise,
            round_seed(s.seed, round),
            &|| {},
        ),
        None => TrainSet::build(
            &photos,
            &native,
            &cfg,
            noise,
            round_seed(s.seed, round),
            &|| {},
        ),
    };
    let crop = (a.val_crop > 0).then_some(a.val_crop);
    let (val, vsecs) = step("validation set", || match (&val_pairs, &family) {
        (Some(p), _) => ValSet::from_pairs(p, &native, &cfg, crop),
        (None, Some(_)) => ValSet::build_family(&val_photos, &lenses, &cfg, noise, crop),
        (None, None) => ValSet::build(&val_photos, &native, &cfg, noise, crop),
    });
    let val = val?;
    println!(
        "{}; {} validation {} ({vsecs:.1} s); config '{}', {} parameters",
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
        cfg.name,
        cfg.analytic_params()
    );
    let command = std::env::args().collect::<Vec<_>>().join(" ");
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
        lineage.apply(p, &command)
    };
    let pb = bar(s.steps as u64, "training");
    pb.set_position(first as u64);
    pb.set_message("aberrating the training photos");
    let mut log = Vec::new();
    let mut ema: Option<f32> = None;
    let started = Instant::now();
    let run = TrainRun {
        config: &cfg,
        native: &native,
        pairs: &make_set,
        val: &val,
        options: &opts,
        out: &a.out,
        provenance: &provenance,
    };
    let kernels = a.kernels;
    let (_, last, reached) = with_kernels(kernels, || {
        train(&run, start, &mut |e| match e {
            Event::Pairs {
                round,
                samples,
                seconds,
            } => say(
                &pb,
                format!("round {round}: {samples} training pairs ({seconds:.1} s)"),
            ),
            Event::Step { step, loss, lr } => {
                let e = ema.map_or(loss, |m| 0.95 * m + 0.05 * loss);
                ema = Some(e);
                pb.set_position(step as u64);
                pb.set_message(format!("L1 {e:.4} lr {lr:.1e}"));
            }
            Event::Val {
                step,
                psnr,
                ssim,
                seconds,
            } => {
                say(
                    &pb,
                    format!(
                        "step {step:>6}  {seconds:>7.0} s  val PSNR {psnr:.2} dB  SSIM {ssim:.4}"
                    ),
                );
                log.push((step, seconds, psnr, ssim));
            }
        })
    })?;
    pb.finish_and_clear();
    let secs = started.elapsed().as_secs_f64();
    println!(
        "trained to step {reached} of {} ({} steps in this run) in {:.1} min ({:.2} steps/s); validation (centred {} px crops): PSNR {:.2} dB, SSIM {:.4}; weights: {}, state: {}",
        s.steps,
        reached - first,
        secs / 60.0,
        (reached - first) as f64 / secs,
        a.val_crop,
        last.0,
        last.1,
        a.out.display(),
        restore::train_state::state_path(&a.out).display()
    );
    if reached < s.steps && base::interrupt::requested() {
        anyhow::bail!(
            "interrupted at step {reached} of {}; the weights and the state are saved: continue with the same command and --resume (without --init)",
            s.steps
        );
    }
    if reached < s.steps {
        println!(
            "stopped early (--minutes); continue with the same command and --resume (without --init)"
        );
    }
    Ok(())
}

fn run_eval(a: EvalArgs) -> Result<()> {
    if let Some(out) = &a.out {
        let mut inputs = a.net.inputs();
        inputs.push(("--val", a.val.as_path()));
        metasplat::output::guard::refuse_overwrite("--out", out, &inputs)?;
        metasplat::output::guard::refuse_file_as_folder("--out", out)?;
    }
    // Blurred to one scale, the photos are restored by the shipped network for it.
    let (native, restorer) = a.net.load(|_| a.psf_px.map(|p| p as usize | 1))?;
    let photos = load_folder(&a.val, 1)?;
    let noise = NoiseModel::default();
    let ks = bank_constants();
    // Single fixed K candidates: the bank's constants.
    let mut single = vec![Score::default(); ks.len()];
    let (mut input, mut median, mut net) = (Score::default(), Score::default(), Score::default());
    let base_filter = restorer.config().residual_base;
    let mut base = Score::default();
    let mut net_secs = 0.0;
    let mut mapped_px = (usize::MAX, 0);
    let pb = bar(photos.len() as u64, "evaluating");
    for (i, (name, clean)) in photos.iter().enumerate() {
        let sensor = a
            .psf_px
            .map(|px| native.sensor_for_psf_px(clean.width, clean.height, px as usize));
        let model = ImagingModel::new(
            &native,
            clean.width,
            clean.height,
            BlurMode::Tiled,
            sensor,
            noise,
        )
        .with_context(|| format!("{name} in --val {}", a.val.display()))?;
        let k = model.psf().size();
        mapped_px = (mapped_px.0.min(k), mapped_px.1.max(k));
        let blurred = model.capture(clean, 0x5EED_0000 + i as u64)?;
        input.add(&blurred, clean)?;
        let bank = restore::data::bank_images(&blurred, model.psf(), restorer.config().adaptive_k)?;
        median.add(&bank[BANK_MEDIAN], clean)?;
        if base_filter != BANK_MEDIAN {
            base.add(&bank[base_filter], clean)?;
        }
        for (j, &k) in ks.iter().enumerate() {
            let img = deconvolve(&blurred, model.psf(), Regularizer::Fixed(k))?;
            single[j].add(&img, clean)?;
        }
        let t = Instant::now();
        let restored = restorer.restore_bank(&bank);
        net_secs += t.elapsed().as_secs_f64();
        net.add(&restored, clean)?;
        if let Some(dir) = &a.out {
            std::fs::create_dir_all(dir)
                .with_context(|| format!("cannot create {}", dir.display()))?;
            let stem = Path::new(name)
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default();
            strip(&[&blurred, &bank[base_filter], &restored, clean])
                .save_png(&dir.join(format!("{stem}_abr_base_net_clean.png")))?;
        }
        pb.inc(1);
    }
    pb.finish_and_clear();
    if base_filter == BANK_MEDIAN {
        base = median;
    }
    let n = photos.len() as f64;
    let (jbest, best) = single
        .iter()
        .enumerate()
        .max_by(|a, b| a.1.psnr.total_cmp(&b.1.psnr))
        .expect("13 constants");
    let kind = if restorer.config().adaptive_k {
        "adaptive"
    } else {
        "fixed"
    };
    let mut rows = vec![
        ("aberrated input".to_string(), input),
        (format!("Wiener, best single K = {:.2e}", ks[jbest]), *best),
        (
            format!("median MAFG Wiener ({kind} K {:.2e})", ks[BANK_MEDIAN]),
            median,
        ),
        (format!("network ({})", restorer.config().name), net),
    ];
    if base_filter != BANK_MEDIAN {
        rows.insert(
            3,
            (
                format!(
                    "MAFG Wiener filter {base_filter}, the network's residual base ({kind} K {:.2e})",
                    ks[base_filter]
                ),
                base,
            ),
        );
    }
    let scale = if mapped_px.0 == mapped_px.1 {
        format!("{} px", mapped_px.0)
    } else {
        format!("{}-{} px", mapped_px.0, mapped_px.1)
    };
    println!(
        "{} validation photos, {}; PSFs of {scale} at the photos' size ({})",
        photos.len(),
        a.val.display(),
        match a.psf_px {
            Some(px) => format!("--psf-px {px}"),
            None => "the grid's own sensor".into(),
        }
    );
    println!("| method | PSNR (dB) | SSIM | PSNR on Y (dB) |\n|---|---:|---:|---:|");
    for (name, r) in &rows {
        println!(
            "| {name} | {:.2} | {:.4} | {:.2} |",
            r.psnr / n,
            r.ssim / n,
            r.psnr_y / n
        );
    }
    let mp: f64 = photos
        .iter()
        .map(|(_, i)| (i.width * i.height) as f64)
        .sum::<f64>()
        / 1e6;
    println!(
        "network: {:+.2} dB over the best single-K Wiener, {:+.2} dB over the median Wiener image, {:+.2} dB over its residual base (filter {base_filter}); inference {:.0} ms per megapixel ({} threads, tiles {} px)",
        (net.psnr - best.psnr) / n,
        (net.psnr - median.psnr) / n,
        (net.psnr - base.psnr) / n,
        1000.0 * net_secs / mp,
        rayon::current_num_threads(),
        restorer.tile
    );
    Ok(())
}

/// Images side by side.
fn strip(images: &[&Image]) -> Image {
    let (w, h) = (images[0].width, images[0].height);
    Image::from_fn(w * images.len(), h, |x, y| {
        let img = images[x / w];
        std::array::from_fn(|c| img.get(x % w, y, c))
    })
}

pub fn run_restore(a: RestoreArgs) -> Result<()> {
    if a.input.is_dir() {
        return run_restore_folder(a);
    }
    if is_gif(&a.input) {
        return run_restore_gif(a);
    }
    if super::video::is_ffmpeg_video(&a.input) {
        return run_restore_video(a);
    }
    if a.resume {
        bail!(
            "--resume: only a folder of frames (--in DIR) is restored in parts; {} is one photo",
            a.input.display()
        );
    }
    let mut inputs = a.net.inputs();
    inputs.push(("--in", a.input.as_path()));
    if let Some(r) = &a.reference {
        inputs.push(("--reference", r));
    }
    metasplat::output::guard::refuse_overwrite("--out", &a.out, &inputs)?;
    metasplat::output::guard::refuse_unwritable_image("--out", &a.out)?;
    let blurred =
        Image::load(&a.input).with_context(|| format!("cannot read {}", a.input.display()))?;
    let (native, restorer) = a
        .net
        .load(|n| Some(n.mapped_size(blurred.width, blurred.height, a.sensor_px)))?;
    let psf = native
        .for_image(blurred.width, blurred.height, a.sensor_px)
        .with_context(|| super::sensor_flag(a.sensor_px, &a.net.psf))?;
    if !restorer.header.fits_psf_px(psf.size()) {
        let [lo, hi] = restorer.header.trained_psf_px.unwrap_or([0, 0]);
        println!(
            "warning: the network was trained on {lo}-{hi} px PSFs; this photo's are {} px",
            psf.size()
        );
    }
    let (restored, secs) = step("restoring", || restorer.restore(&blurred, &psf));
    let restored = restored?;
    restored
        .save_png(&a.out)
        .with_context(|| format!("cannot write {}", a.out.display()))?;
    print!(
        "restored {}x{} with '{}' in {secs:.2} s -> {}",
        blurred.width,
        blurred.height,
        restorer.config().name,
        a.out.display()
    );
    if let Some(r) = &a.reference {
        let clean = Image::load(r).with_context(|| format!("cannot read {}", r.display()))?;
        if (clean.width, clean.height) != (blurred.width, blurred.height) {
            bail!(
                "{}: {}x{} does not match the input's {}x{}",
                r.display(),
                clean.width,
                clean.height,
                blurred.width,
                blurred.height
            );
        }
        let (p0, s0) = metric(&blurred, &clean)?;
        let (p1, s1) = metric(&restored, &clean)?;
        print!("; PSNR {p0:.2} -> {p1:.2} dB, SSIM {s0:.4} -> {s1:.4}");
    }
    println!();
    Ok(())
}

/// `restore --in DIR`: every photo of a folder (a video's frames), through the restorer the
/// grid and the frames' size call for, into the folder `--out` under the same names as PNG.
/// Each frame is written whole as it is done; a stop (Ctrl-C) keeps the frames done, and
/// `--resume` restores the others.
fn run_restore_folder(a: RestoreArgs) -> Result<()> {
    if a.reference.is_some() {
        bail!("--reference: a folder of frames is restored without one (score a frame alone)");
    }
    let io = super::frames::FrameFolders::check(
        &a.input,
        &a.out,
        (!a.resume).then_some("--resume keeps the frames done and restores the others"),
        &a.net.inputs(),
    )?;
    let (frames, size) = (&io.frames, io.size);
    let (w, h) = (size.0 as usize, size.1 as usize);
    let (native, restorer) = a.net.load(|n| Some(n.mapped_size(w, h, a.sensor_px)))?;
    let psf = native
        .for_image(w, h, a.sensor_px)
        .with_context(|| super::sensor_flag(a.sensor_px, &a.net.psf))?;
    io.make_out()?;
    let todo: Vec<&PathBuf> = frames.iter().filter(|f| !io.target(f).exists()).collect();
    let kept = frames.len() - todo.len();
    if kept > 0 {
        println!(
            "--resume: {kept} of {} frames were restored before; restoring the other {}.",
            frames.len(),
            todo.len()
        );
    }
    let start = std::time::Instant::now();
    for (done, f) in todo.iter().enumerate() {
        if base::interrupt::requested() {
            return Err(metasplat::TrainError::Interrupted(format!(
                "restoring stopped after {} of {} frames; they are kept in {}: the same command with --resume restores the others",
                kept + done,
                frames.len(),
                a.out.display()
            ))
            .into());
        }
        let blurred = Image::load(f).with_context(|| format!("cannot read {}", f.display()))?;
        let restored = restorer.restore(&blurred, &psf)?;
        let target = io.target(f);
        restored
            .save_png(&target)
            .with_context(|| format!("cannot write {}", target.display()))?;
        println!(
            "frame {} of {} ({}) restored; about {:.0} s left",
            kept + done + 1,
            frames.len(),
            f.file_name().unwrap_or_default().to_string_lossy(),
            super::frames::time_left(start.elapsed().as_secs_f64(), done + 1, todo.len())
        );
    }
    println!(
        "restored {} frames {}x{} with '{}' in {:.1} s -> {}",
        todo.len(),
        size.0,
        size.1,
        restorer.config().name,
        start.elapsed().as_secs_f64(),
        a.out.display()
    );
    Ok(())
}

fn run_eval_video(a: EvalVideoArgs) -> Result<()> {
    let read = |flag: &str, dir: &Path| -> Result<(Vec<PathBuf>, Vec<Image>)> {
        let paths = scenes::images::list_images(dir)
            .with_context(|| format!("{flag} {}", dir.display()))?;
        let frames = paths
            .iter()
            .map(|p| Image::load(p).with_context(|| format!("{flag}: cannot read {}", p.display())))
            .collect::<Result<Vec<_>>>()?;
        Ok((paths, frames))
    };
    let (names, restored) = read("--restored", &a.restored)?;
    let (_, clean) = read("--clean", &a.clean)?;
    let flicker =
        restore::video::flicker(&restored, &clean).context("--restored against --clean")?;
    println!("| frame | PSNR (dB) | SSIM |");
    println!("|---|---:|---:|");
    let (mut p_sum, mut s_sum) = (0.0, 0.0);
    for ((name, r), c) in names.iter().zip(&restored).zip(&clean) {
        let (p, s) = metric(r, c)?;
        p_sum += p;
        s_sum += s;
        println!(
            "| {} | {p:.2} | {s:.4} |",
            name.file_name().unwrap_or_default().to_string_lossy()
        );
    }
    let n = restored.len() as f64;
    println!("| mean | {:.2} | {:.4} |", p_sum / n, s_sum / n);
    println!(
        "flicker: consecutive restored frames differ by {:.5} more (mean absolute difference, [0, 1] units) than the clean ones ({:.5}); 0 is as steady as the clean clip",
        flicker,
        restore::video::frame_to_frame(&clean)
    );
    println!(
        "temporal error: {:.5} (mean absolute difference of the restored and the clean frame-to-frame changes; 0 where the restored clip changes as the clean one does, whatever its error within a frame)",
        restore::video::temporal_error(&restored, &clean)?
    );
    Ok(())
}

fn is_gif(p: &Path) -> bool {
    p.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("gif"))
}

/// `restore --in clip.gif --out restored.gif`: every frame of an animated GIF through the
/// restorer its size calls for, written as one GIF with the input's frame times (without
/// ffmpeg). A stop (Ctrl-C) between frames writes nothing.
fn run_restore_gif(a: RestoreArgs) -> Result<()> {
    use image::AnimationDecoder;
    if a.resume || a.reference.is_some() {
        bail!("--resume and --reference: a GIF is restored whole, without either");
    }
    if !is_gif(&a.out) {
        bail!(
            "--out {}: a GIF is restored into a .gif (restore its frames as a folder with --in DIR for PNG frames)",
            a.out.display()
        );
    }
    let mut inputs = a.net.inputs();
    inputs.push(("--in", a.input.as_path()));
    metasplat::output::guard::refuse_overwrite("--out", &a.out, &inputs)?;
    let file =
        base::input::open(&a.input).with_context(|| format!("--in {}", a.input.display()))?;
    let decoder = image::codecs::gif::GifDecoder::new(std::io::BufReader::new(file))
        .with_context(|| format!("--in {}: not a GIF", a.input.display()))?;
    let frames = decoder
        .into_frames()
        .collect_frames()
        .with_context(|| format!("--in {}: cannot decode its frames", a.input.display()))?;
    let Some(first) = frames.first() else {
        bail!("--in {}: the GIF has no frames", a.input.display());
    };
    let (w, h) = (
        first.buffer().width() as usize,
        first.buffer().height() as usize,
    );
    base::limits::check_image_pixels(w as u32, h as u32)
        .map_err(|p| anyhow::anyhow!("--in {}: {p}", a.input.display()))?;
    let (native, restorer) = a.net.load(|n| Some(n.mapped_size(w, h, a.sensor_px)))?;
    let psf = native
        .for_image(w, h, a.sensor_px)
        .with_context(|| super::sensor_flag(a.sensor_px, &a.net.psf))?;
    let start = std::time::Instant::now();
    let mut out = Vec::with_capacity(frames.len());
    for (i, f) in frames.iter().enumerate() {
        if base::interrupt::requested() {
            return Err(metasplat::TrainError::Interrupted(format!(
                "restoring stopped after {i} of {} frames; nothing was written",
                frames.len()
            ))
            .into());
        }
        let rgba = f.buffer();
        let blurred = Image::from_fn(w, h, |x, y| {
            let p = rgba.get_pixel(x as u32, y as u32).0;
            [p[0], p[1], p[2]].map(|v| v as f32 / 255.0)
        });
        let restored = restorer.restore(&blurred, &psf)?;
        let rgb = restored.to_rgb8();
        let rgba = image::RgbaImage::from_fn(w as u32, h as u32, |x, y| {
            let p = rgb.get_pixel(x, y).0;
            image::Rgba([p[0], p[1], p[2], 255])
        });
        out.push(image::Frame::from_parts(rgba, 0, 0, f.delay()));
        println!(
            "frame {} of {} restored; about {:.0} s left",
            i + 1,
            frames.len(),
            super::frames::time_left(start.elapsed().as_secs_f64(), i + 1, frames.len())
        );
    }
    let mut bytes = Vec::new();
    {
        let mut encoder = image::codecs::gif::GifEncoder::new_with_speed(&mut bytes, 10);
        encoder.set_repeat(image::codecs::gif::Repeat::Infinite)?;
        encoder.encode_frames(out)?;
    }
    base::write_bytes_atomically(&a.out, &bytes)
        .with_context(|| format!("cannot write {}", a.out.display()))?;
    println!(
        "restored {} frames {w}x{h} with '{}' in {:.1} s -> {}",
        frames.len(),
        restorer.config().name,
        start.elapsed().as_secs_f64(),
        a.out.display()
    );
    Ok(())
}

/// `restore --in clip.mp4 --out restored.mp4` (or `.gif`): the clip's frames through ffmpeg
/// into `OUT.parts/input/`, restored into `OUT.parts/restored/` ([`run_restore_folder`]), and
/// encoded at the clip's rate into `--out`; the parts folder goes when the video is written.
/// A stop keeps the frames done there, and `--resume` continues.
fn run_restore_video(a: RestoreArgs) -> Result<()> {
    if a.reference.is_some() {
        bail!("--reference: a video is restored without one (score it with restorer eval-video)");
    }
    let Some(ffmpeg) = super::video::on_path("ffmpeg") else {
        bail!(
            "--in {}: reading a video needs ffmpeg, which is not on the PATH; install it, or restore the clip as a .gif or as a folder of frames (--in DIR --out DIR)",
            a.input.display()
        );
    };
    let format = super::video::format_for_flag("--out", &a.out)?;
    let mut inputs = a.net.inputs();
    inputs.push(("--in", a.input.as_path()));
    metasplat::output::guard::refuse_overwrite("--out", &a.out, &inputs)?;
    let parts = PathBuf::from(format!("{}.parts", a.out.display()));
    if parts.exists() && !a.resume {
        bail!(
            "--out {}: {} holds the frames of an earlier run; --resume continues it",
            a.out.display(),
            parts.display()
        );
    }
    let (input_dir, restored_dir) = (parts.join("input"), parts.join("restored"));
    for d in [&input_dir, &restored_dir] {
        std::fs::create_dir_all(d).with_context(|| format!("cannot make {}", d.display()))?;
    }
    let rate_file = parts.join("fps");
    let fps = match std::fs::read_to_string(&rate_file)
        .ok()
        .and_then(|t| t.trim().parse::<f64>().ok())
    {
        Some(fps) if scenes::images::list_images(&input_dir).is_ok() => fps,
        _ => {
            println!(
                "Reading the frames of {} with {}.",
                a.input.display(),
                ffmpeg.display()
            );
            let fps = super::video::decode(&ffmpeg, &a.input, &input_dir)?;
            base::write_bytes_atomically(&rate_file, fps.to_string().as_bytes())
                .with_context(|| format!("cannot write {}", rate_file.display()))?;
            fps
        }
    };
    let out = a.out.clone();
    run_restore_folder(RestoreArgs {
        input: input_dir,
        out: restored_dir.clone(),
        resume: true,
        reference: None,
        ..a
    })?;
    let frames = scenes::images::list_images(&restored_dir)?;
    super::video::encode(&format, &frames, fps, &out)?;
    std::fs::remove_dir_all(&parts)
        .with_context(|| format!("cannot remove {}", parts.display()))?;
    println!(
        "wrote {} ({} frames at {fps} frames per second)",
        out.display(),
        frames.len()
    );
    Ok(())
}
