//! One training run, assembled once for every caller (`train`, `demo`, `experiment`, a viewer's
//! live view, library users): the prepared run (inputs checked, capture loaded, config built
//! and recorded) and the run itself with its outputs. What the run is asked to do is a
//! [`RunRequest`] ([`crate::settings`]).

use crate::error::{Result, TrainError};
use crate::output::{self, CHECKPOINT_FILE, RunSummary};
use crate::settings::{LambdaFade, Mode, RestorerChoice, RunRequest};
use crate::splats::device::Device;
use crate::train::config::TrainConfig;
use crate::train::data::{self, Dataset};
use crate::train::{self, Event, Outcome};
use clap::ValueEnum;

/// A run ready to train: the run folder exists and is writable, the capture is loaded (with
/// the `I_ac` images the cache held), and the config is built and written to `config.json`.
pub struct PreparedRun {
    pub request: RunRequest,
    pub data: Dataset,
    pub config: TrainConfig,
    pub device: Device,
    /// Which device renders, and why, as a sentence.
    pub device_note: String,
    /// Where the restorer's images came from or went (the cache), as a sentence, once
    /// [`PreparedRun::restore_iac`] has made them.
    pub cache_note: Option<String>,
    /// The run folder is this run's alone while it is held.
    _lock: base::FolderLock,
}

/// Checks and loads everything a run needs, before any training time is spent.
pub fn prepare(request: &RunRequest) -> Result<PreparedRun> {
    let request = &restartable(request);
    let (data, config, device, device_note) = checked(request)?;
    let out = &request.out;
    let lock = output::prepare_run_dir(out, "train")
        .map_err(|e| e.context(format!("cannot use {} as the run folder", out.display())))?;
    if request.overwrite {
        output::clear_run(out)?;
    }
    output::write_json(&out.join(output::CONFIG_FILE), &config)?;
    Ok(PreparedRun {
        request: request.clone(),
        data,
        config,
        device,
        device_note,
        cache_note: None,
        _lock: lock,
    })
}

/// A run from request to outputs with nothing said: prepared, its missing `I_ac` made, then
/// trained; its summary and training log (an experiment's runs, which report through their own
/// table; a [`crate::lab::Runner`]).
pub fn train_quietly(request: &RunRequest) -> Result<(RunSummary, Vec<train::LogRow>)> {
    let mut prepared = prepare(request)?;
    prepared.restore_iac(&mut |_, _| {})?;
    let (summary, outcome) = prepared.run(&mut |_| {})?;
    Ok((summary, outcome.log))
}

/// Every check [`prepare`] makes, with nothing written: for a caller that makes other
/// outputs before this run starts (an experiment's aberrated copy) and must not make them
/// for a run that would be refused.
pub fn check(request: &RunRequest) -> Result<()> {
    checked(&restartable(request)).map(|_| ())
}

/// `request`, made to start again when its run folder holds a run that stopped before its
/// first checkpoint (killed, or its terminal closed): such a folder has nothing to continue
/// and nothing worth keeping (its `config.json`, and the log of its first evaluations), so
/// neither the same command nor `--resume` is refused for it.
fn restartable(request: &RunRequest) -> RunRequest {
    let out = &request.out;
    let kept: Vec<&str> = output::RUN_FILES
        .iter()
        .copied()
        .filter(|f| out.join(f.trim_end_matches('/')).exists())
        .collect();
    // Splats kept by --save-at are the user's: such a folder is not started again.
    let snapshots = std::fs::read_dir(out)
        .into_iter()
        .flatten()
        .flatten()
        .any(|e| e.file_name().to_str().is_some_and(output::is_snapshot));
    let stopped_early = kept.contains(&output::CONFIG_FILE)
        && !snapshots
        && kept
            .iter()
            .all(|f| [output::CONFIG_FILE, output::LOG_FILE].contains(f));
    let mut request = request.clone();
    if stopped_early && !request.overwrite {
        request.resume = false;
        request.overwrite = true;
    }
    request
}

/// The inputs read and checked, the config built; no folder made.
fn checked(request: &RunRequest) -> Result<(Dataset, TrainConfig, Device, String)> {
    refuse_unused_settings(request)?;
    let out = &request.out;
    let mut inputs = vec![("--scene", request.scene.as_path())];
    if let Some(p) = &request.data.psf {
        inputs.push(("--psf", p));
    }
    if let RestorerChoice::Weights(w) = &request.data.restorer {
        inputs.push(("--restorer", w));
    }
    if let Some(i) = &request.training.init {
        inputs.push(("--init", i));
    }
    let mut inputs = crate::output::guard::Inputs::of(&inputs);
    inputs.refuse("--out", out)?;
    crate::output::guard::refuse_file_as_folder("--out", out)?;
    check_run_folder(request)?;
    let (device, device_note) = Device::choose(request.device)?;
    // Every input is checked before the run folder is made.
    // I_ac is read from (and, once the run folder exists, written to) a cache: the capture's,
    // else the run's own (`iac_cache::for_run`), unless the caller shares one between runs.
    let mut data_options = request.data.clone();
    data_options
        .iac_cache
        .get_or_insert_with(|| crate::train::iac_cache::for_run(&request.scene, out));
    let mut data = data::load_cached(&request.scene, request.training.mode, &data_options)
        .map_err(|e| e.context(format!("cannot load the scene {}", request.scene.display())))?;
    if let Some(path) = &request.training.init {
        let g = splat::formats::files::read_splats(path)
            .map_err(|e| TrainError::from(e).context(format!("--init {}", path.display())))?;
        if g.is_empty() {
            return Err(TrainError::file(path, "--init: the scene has no splats"));
        }
        data.initial = Some(g);
    }
    if request.training.mask_mode != crate::settings::MaskChoice::Auto
        && !crate::train::config::has_object_masks(&data)
    {
        return Err(TrainError::file(
            &request.scene,
            format!(
                "--mask-mode {}: the capture has no object masks (masks_N/ beside images_N/, masks/, or a frame's mask_path in transforms.json){}",
                request
                    .training
                    .mask_mode
                    .to_possible_value()
                    .map_or(String::new(), |v| v.get_name().to_string()),
                if data.masks_from_undistortion {
                    "; its masks are only the border undistortion left"
                } else {
                    ""
                }
            ),
        ));
    }
    // The photos the capture's model names, wherever they are.
    inputs.add_capture(&data.capture);
    inputs.refuse("--out", out)?;
    let mut config = TrainConfig::build(&request.training, request.data.seed, &data);
    let ckpt = out.join(CHECKPOINT_FILE);
    let saved = if request.resume {
        Some(crate::train::checkpoint::load_config(&ckpt)?)
    } else {
        None
    };
    if let Some(saved) = &saved {
        // A run of `--iters auto` ends by its rule: it resumes as such, and a fixed-length run
        // is not turned into one.
        match (saved.stop.is_some(), config.stop.is_some()) {
            (true, false) => {
                return Err(TrainError::file(
                    &ckpt,
                    format!(
                        "--iters {}: the run was made with --iters auto, which ends it when training stops paying; resume it with --iters auto",
                        request.training.iters
                    ),
                ));
            }
            (false, true) => {
                return Err(TrainError::file(
                    &ckpt,
                    format!(
                        "--iters auto: the run has {} steps; resume it with --iters {} (or a larger count to extend it)",
                        saved.iters, saved.iters
                    ),
                ));
            }
            _ => {}
        }
    }
    if let Some(saved) = saved.as_ref().filter(|s| s.stop.is_none()) {
        // `--resume --iters N` past the run's length extends it: the settings are the run's,
        // built for the length its schedules were made for, and only the length grows.
        let base = saved.schedule_iters.unwrap_or(saved.iters);
        if config.iters < saved.iters {
            return Err(TrainError::file(
                &ckpt,
                format!(
                    "--iters {}: the run has {} steps; --resume can extend a run (a larger --iters), not shorten it",
                    config.iters, saved.iters
                ),
            ));
        }
        if config.iters != base {
            let settings = crate::settings::TrainSettings {
                iters: crate::settings::Iters::Steps(base),
                ..request.training.clone()
            };
            let iters = config.iters;
            config = TrainConfig::build(&settings, request.data.seed, &data);
            config.iters = iters;
            config.schedule_iters = Some(base);
        }
    }
    // An `--iters auto` run resumes with the schedules it was made for, where this version
    // would make them for another length (restored mode's horizon grew from 150 to 200 steps
    // per view): refused as changed settings, the run could not be finished.
    if let Some(base) = saved
        .as_ref()
        .filter(|s| s.stop.is_some())
        .and_then(|s| s.schedule_iters)
        && config.schedule_iters != Some(base)
    {
        config = TrainConfig::build_with_horizon(
            &request.training,
            request.data.seed,
            &data,
            Some(base),
        );
    }
    // `--coarse-to-fine auto` resumes a run as it was made: one made at full size (before
    // coarse to fine existed, or with it off) stays so, instead of being refused as changed.
    if let Some(saved) = &saved
        && request.training.coarse_to_fine == crate::settings::CoarseToFine::Auto
    {
        config.coarse = saved.coarse.clone();
    }
    if let Some(&last) = config.save_at.last()
        && last > config.iters
    {
        return Err(TrainError::Invalid(format!(
            "--save-at {last}: the run has only {} steps",
            config.iters
        )));
    }
    if let Some(g) = &data.initial
        && g.len() > config.max_splats
        && let Some(path) = &request.training.init
    {
        return Err(TrainError::file(
            path,
            format!(
                "--init holds {} splats, more than the run's budget of {}: pass --max-splats {} (or more) to train them all",
                g.len(),
                config.max_splats,
                g.len()
            ),
        ));
    }
    // A resume with other settings (or on another capture) is refused before config.json is
    // replaced. The lock below is not held yet, so the checkpoint is read again by the run.
    if let Some(saved) = &saved {
        let diff = crate::train::config_differences(&config, saved);
        if !diff.is_empty() {
            return Err(TrainError::file(
                &ckpt,
                format!("cannot resume with other settings: {}", diff.join("; ")),
            ));
        }
    }
    config.decisions = crate::train::decisions::explain(&config, &request.training, &data);
    Ok((data, config, device, device_note))
}

/// Refuses a setting the mode never reads: a `--restorer` file plain mode would not open
/// (and so not check), a λ only aware mode weighs. Accepted, they would be recorded as the
/// run's settings and block a `--resume` that leaves them out.
fn refuse_unused_settings(request: &RunRequest) -> Result<()> {
    let t = &request.training;
    let unused = |flag: String, users: &str| {
        Err(TrainError::Invalid(format!(
            "{flag}: only {users} use it, and this run's --mode is {}",
            t.mode
        )))
    };
    if t.mode != Mode::Aware {
        if let Some(l) = t.lambda {
            return unused(format!("--lambda {l}"), "aware runs");
        }
        if t.lambda_fade != LambdaFade::Auto {
            return unused("--lambda-fade".into(), "aware runs");
        }
        if t.refine_psf.is_some() {
            return unused("--refine-psf".into(), "aware runs");
        }
    }
    if t.mode == Mode::Plain && request.data.restorer != RestorerChoice::Auto {
        return unused("--restorer".into(), "restored and aware runs");
    }
    Ok(())
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
    let existing = output::RUN_FILES.iter().find(|f| out.join(f).exists());
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
    /// Makes the `I_ac` images the cache did not hold, caching each in the run's cache as it
    /// is made ([`Dataset::restore_pending`]); `on_view(done, total)` follows the views. The
    /// slow part of loading, so it runs once the inputs are checked and the folder is held.
    pub fn restore_iac(&mut self, on_view: &mut dyn FnMut(usize, usize)) -> Result<()> {
        if self.data.pending.is_empty() && self.cache_note.is_some() {
            return Ok(());
        }
        let report = self.data.restore_pending(on_view)?;
        self.cache_note = report.sentence(self.data.cache_dir());
        Ok(())
    }

    /// Trains (resuming if asked), then writes the run folder: PLY, metrics, log, renders and
    /// the PSNR-vs-time plot. `I_ac` not yet made is made first ([`Self::restore_iac`]).
    pub fn run(&mut self, on_event: &mut dyn FnMut(Event)) -> Result<(RunSummary, Outcome)> {
        if !self.data.pending.is_empty() {
            self.restore_iac(&mut |_, _| {})?;
        }
        let out = &self.request.out;
        let ckpt = out.join(CHECKPOINT_FILE);
        // Snapshots (`--save-at`) are kept here; one that cannot be written fails the run
        // once its other outputs are written.
        let mut snapshot_failure = None;
        let mut events = |e: Event| {
            // The log file grows with the run, so `tail -f` follows it; only a cache of what
            // the run writes at its end, so a failure here is not the run's.
            if let Event::Logged { rows } = &e {
                let _ = output::write_log_csv(&out.join(output::LOG_FILE), rows);
            }
            if let Event::Snapshot { step, model } = &e {
                let path = out.join(output::snapshot_file(*step));
                if let Err(err) = splat::formats::ply::write_ply(&path, model)
                    && snapshot_failure.is_none()
                {
                    snapshot_failure = Some(TrainError::from(err));
                }
            }
            on_event(e);
        };
        let outcome = train::train(
            &self.config,
            &self.data,
            &self.device,
            Some(&ckpt),
            self.request.resume,
            &mut events,
        )?;
        let summary = output::write_run(
            out,
            &self.data,
            &self.config,
            &outcome,
            self.request.spiral as usize,
            &self.device,
        )
        .and_then(|s| output::plot_log(out, &outcome.log, s.observed_psnr).map(|_| s))
        .map_err(|e| match e {
            // Stopped while the outputs were written: the trained splats are in the last
            // checkpoint, and a resume only writes the files.
            TrainError::Interrupted(why) if ckpt.is_file() => TrainError::Interrupted(format!(
                "{why}: training had finished, and {} holds it; the same command with --resume writes the run's files",
                ckpt.display()
            )),
            e => e.context(format!("cannot write the run folder {}", out.display())),
        })?;
        if let Some(e) = snapshot_failure {
            return Err(e.context("cannot keep the splats --save-at asked for"));
        }
        Ok((summary, outcome))
    }
}
