//! `metasplat restorer train`: checks, the run's start (fresh, `--init` or `--resume`), the
//! training data and the loop with its progress.

use crate::cli::progress::{bar, say, step};
use aberration::{Image, NoiseModel, PsfGrid};
use anyhow::{Context, Result, bail};
use clap::Args;
use restore::data::TrainSet;
use restore::family::LensFamily;
use restore::net::kernels::{Kernels, with_kernels};
use restore::provenance::Lineage;
use restore::train::{Event, Schedule, Start, TrainOptions, TrainRun, ValSet, round_seed, train};
use restore::{Guidance, Preset, RestorerConfig, weights};
use std::path::{Path, PathBuf};
use std::time::Instant;

use super::network::load_folder;

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

/// Every check on the flags and folders, before anything is read: returns the training
/// photos' flag and folder.
fn checked_inputs(a: &TrainRestorerArgs) -> Result<(&'static str, &Path)> {
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
    Ok((train_flag, train_dir))
}

/// Where the run starts: a fresh network, `--init` weights of any lens (fine-tuning), or the
/// saved run (`--resume`, whose schedule replaces `schedule`, each flag that says otherwise
/// refused); with what the weights file's provenance carries over from the weights it
/// started from.
fn starting_point(
    a: &TrainRestorerArgs,
    cfg: &RestorerConfig,
    native: &PsfGrid,
    device: &restore::Device,
    schedule: &mut Schedule,
) -> Result<(Start, Lineage)> {
    // A resumed run continues on the grid it was trained for; `--init` starts from weights of
    // any lens (fine-tuning to a user's own grid).
    let load = |p: &Path, grid: Option<&PsfGrid>| {
        let device = device.clone().autodiff();
        weights::load(p, &device, Some(cfg), grid)
    };
    let lineage;
    let start = if a.resume {
        let (net, header) = load(&a.out, Some(native)).context("cannot resume")?;
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
        *schedule = state.schedule.clone();
        let s = &*schedule;
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
                if let Err(why) = header.serves(native) {
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
    Ok((start, lineage))
}

pub(crate) fn run_train(a: TrainRestorerArgs) -> Result<()> {
    let (_, train_dir) = checked_inputs(&a)?;
    let device = a.backend.device().context("--backend")?;
    let cfg = config_from(&a)?;
    let native =
        PsfGrid::load_npy(&a.psf).with_context(|| format!("cannot read {}", a.psf.display()))?;
    let mut schedule = Schedule {
        steps: a.steps as usize,
        batch: a.batch as usize,
        lr: a.lr,
        seed: a.seed,
        refresh_every: a.refresh_every,
        ..Default::default()
    };
    let (start, lineage) = starting_point(&a, &cfg, &native, &device, &mut schedule)?;
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
