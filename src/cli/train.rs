//! `metasplat train`: an aberrated capture in, a clean splat scene out.

use std::path::Path;

use anyhow::Result;
use indicatif::{ProgressBar, ProgressStyle};
use metasplat::output::{self, RunSummary};
use metasplat::run;
use metasplat::settings::MaskUse;
use metasplat::settings::RunRequest;
use metasplat::train::{self, Event};

/// Makes the run's missing `I_ac` images with a bar of views done and time left (a line
/// every tenth of them away from a terminal).
fn restore_iac(prepared: &mut run::PreparedRun, quiet: bool) -> metasplat::Result<()> {
    let total = prepared.data.pending.len();
    if total == 0 {
        return prepared.restore_iac(&mut |_, _| {});
    }
    let pb = if quiet {
        ProgressBar::hidden()
    } else {
        super::progress::bar(total as u64, "I_ac")
    };
    let lines = pb.is_hidden() && !quiet;
    let start = std::time::Instant::now();
    let every = total.div_ceil(10).max(1);
    prepared.restore_iac(&mut |done, total| {
        pb.set_position(done as u64);
        if lines && done > 0 && (done % every == 0 || done == total) {
            let secs = start.elapsed().as_secs_f64();
            let left = secs / done as f64 * (total - done) as f64;
            let left = if done < total {
                format!(", about {left:.0} s left")
            } else {
                String::new()
            };
            println!("I_ac: {done} of {total} training views restored in {secs:.0} s{left}.");
        }
    })?;
    pb.finish_and_clear();
    Ok(())
}

/// A run's progress as `train` shows it: a bar whose message follows the steps, a line for
/// each rare event, and away from a terminal (nohup, a batch queue: the bar hidden) a line
/// per evaluation, so the log can be followed.
struct Shown {
    pb: ProgressBar,
    lines: bool,
    iters: u64,
    last_test: Option<f64>,
    /// The latest routine edit (a band kept, densification), shown in the bar's message.
    last_edit: String,
    /// Step, loss, training PSNR, splats and seconds of the latest step.
    last_step: (u64, f64, f64, usize, f64),
}

impl Shown {
    fn new(quiet: bool, mode: metasplat::settings::Mode, iters: u64) -> Self {
        let pb = if quiet {
            ProgressBar::hidden()
        } else {
            ProgressBar::new(iters)
        };
        pb.set_style(
            ProgressStyle::with_template(
                "{prefix:>8} [{bar:30}] {pos}/{len} {msg} {per_sec} ETA {eta}",
            )
            .expect("static template")
            .progress_chars("=> "),
        );
        pb.set_prefix(mode.to_string());
        Self {
            lines: pb.is_hidden() && !quiet,
            pb,
            iters,
            last_test: None,
            last_edit: String::new(),
            last_step: (0, 0.0, 0.0, 0, 0.0),
        }
    }

    /// The bar after a step: its position, and every tenth step the losses and the count.
    fn stepped(
        &mut self,
        step: u64,
        loss: &metasplat::train::objective::LossParts,
        splats: usize,
        sh: u32,
        seconds: f64,
    ) {
        self.last_step = (step, loss.total as f64, loss.psnr, splats, seconds);
        self.pb.set_position(step);
        if step.is_multiple_of(10) {
            let parts = match loss.restored {
                Some(r) => format!("L_abr {:.4} L_ac {r:.4}", loss.main),
                None => format!("loss {:.4}", loss.total),
            };
            let test = self
                .last_test
                .map_or(String::new(), |p: f64| format!(" test {p:.2} dB"));
            self.pb.set_message(format!(
                "{parts} train {:.2} dB{test} | {splats} splats SH{sh}{}",
                loss.psnr, self.last_edit
            ));
        }
    }

    /// An evaluation: kept for the bar, and a line of its own away from a terminal.
    fn evaluated(&mut self, step: u64, metrics: &metasplat::train::eval::Metrics) {
        self.last_test = Some(metrics.mean_psnr);
        if self.lines {
            let (at, loss, train_db, splats, seconds) = self.last_step;
            let rate = if seconds > 0.0 {
                at as f64 / seconds
            } else {
                0.0
            };
            println!(
                "Step {step} of {}: loss {loss:.4}, train {train_db:.2} dB, held-out {:.2} dB (SSIM {:.4}), {splats} splats, {rate:.1} steps/s.",
                self.iters, metrics.mean_psnr, metrics.mean_ssim
            );
        }
    }

    fn on(&mut self, e: Event) {
        let pb = &self.pb;
        match e {
            Event::Step {
                step,
                loss,
                splats,
                sh_degree,
                seconds,
            } => self.stepped(step, loss, splats, sh_degree, seconds),
            Event::Evaluated { step, metrics } => self.evaluated(step, metrics),
            // A band that stays is routine; one raised or dropped changes the model.
            Event::Sh {
                step,
                event: event @ train::sh::ShEvent::Kept { .. },
            } => self.last_edit = format!(" | step {step}: {event}"),
            Event::Sh { step, event } => {
                super::progress::say(pb, format!("Step {step}: {event}."));
            }
            Event::Densified { step, edit, .. } => {
                self.last_edit = format!(" | step {step}: {edit}");
            }
            Event::Unseen { step, done } => {
                self.last_edit = format!(" | step {step}: {done}");
            }
            Event::Checkpoint { .. } | Event::Logged { .. } => {}
            Event::Stopping { step, end, reason } => {
                pb.set_length(end);
                super::progress::say(
                    pb,
                    format!("Step {step}: {reason}; a final phase to step {end}."),
                );
            }
            Event::Snapshot { step, .. } => {
                super::progress::say(pb, format!("Step {step}: kept the splats (--save-at)."));
            }
        }
    }
}

/// Trains one run and writes its folder; shared by `train`, `experiment` and `demo`, which
/// differ only in what they print. Returns what went into `metrics.json` and the training log.
pub fn train_run(
    a: &RunRequest,
    quiet: bool,
) -> metasplat::Result<(RunSummary, Vec<train::LogRow>)> {
    let mut prepared = run::prepare(a)?;
    let (data, config) = (&prepared.data, &prepared.config);
    let t = &a.training;
    if !quiet {
        println!(
            "{} views {}x{} ({} train, {} test), {} initial points, mode {}, {}, budget {} splats",
            data.capture.len(),
            data.width,
            data.height,
            data.train.len(),
            data.test.len(),
            if data.initial.is_none() && data.points.len() > config.max_splats {
                format!(
                    "{} (a random {} of them, the budget)",
                    data.points.len(),
                    config.max_splats
                )
            } else {
                data.points.len().to_string()
            },
            t.mode,
            match &config.stop {
                Some(_) => format!("up to {} steps (--iters auto)", config.iters),
                None => format!("{} steps", config.iters),
            },
            config.max_splats
        );
        println!("{}", prepared.device_note);
        for d in &config.decisions {
            println!("{d}");
        }
    }

    restore_iac(&mut prepared, quiet)?;
    if let Some(note) = prepared.cache_note.as_ref().filter(|_| !quiet) {
        println!("{note}");
    }

    let mut shown = Shown::new(quiet, t.mode, prepared.config.iters);
    let mut on_event = |e: Event| shown.on(e);
    let (summary, outcome) = prepared.run(&mut on_event)?;
    shown.pb.finish_and_clear();
    if !quiet {
        print_summary(&a.out, &summary, &outcome);
        print_outputs(&a.out, &a.scene, a.data.downsample, summary.splats);
    }
    Ok((summary, outcome.log))
}

fn print_summary(dir: &Path, s: &RunSummary, outcome: &train::Outcome) {
    if let Some(from) = outcome.resumed_from {
        println!("resumed from step {from}");
    }
    match &s.metrics {
        Some(m) => print_metrics(s, m),
        None => println!(
            "not evaluated: {}",
            s.not_evaluated.as_deref().unwrap_or("no metrics")
        ),
    }
    if let Some(why) = &s.stopped {
        println!("--iters auto: {why}.");
    }
    println!(
        "{} steps in {:.1} s; {} splats ({:.1} MB, SH degree {}); {} never-visible splats dropped at the end; wrote {}",
        s.iters,
        s.train_seconds,
        s.splats,
        s.model_bytes as f64 / 1e6,
        s.sh_degree,
        outcome.final_pruned,
        dir.join(output::PLY_FILE).display()
    );
    if let Some(change) = s.psf_change {
        println!(
            "The refined PSF grid moved {:.2} % from the supplied one (mean over grid cells of the relative L2 distance): {} and {} (supplied above, refined below).",
            100.0 * change,
            dir.join(output::PSF_REFINED_FILE).display(),
            dir.join(output::PSF_REFINED_PICTURE).display()
        );
        if let Some(w) = &s.psf_warp {
            println!("Learnt: {}.", w.sentence());
        }
    }
}

/// The held-out views' table (PSNR, SSIM, and inside the masks for object captures) and
/// what they were scored against.
fn print_metrics(s: &RunSummary, m: &metasplat::train::eval::Metrics) {
    let in_mask = |p: Option<f64>| p.map_or(String::new(), |p| format!(" {p:>11.2}"));
    let header = if m.on_object.is_some() {
        " in the mask"
    } else {
        ""
    };
    println!("{:<16} {:>8} {:>7}{header}", "test view", "PSNR", "SSIM");
    for v in &m.views {
        println!(
            "{:<16} {:>8.2} {:>7.4}{}",
            v.name,
            v.psnr,
            v.ssim,
            in_mask(v.psnr_in_mask)
        );
    }
    println!(
        "{:<16} {:>8.2} {:>7.4}{}",
        "mean",
        m.mean_psnr,
        m.mean_ssim,
        in_mask(m.on_object.as_ref().map(|o| o.mean_psnr_in_mask))
    );
    match &m.on_object {
        Some(o) => {
            let [r, g, b] = o.background;
            println!(
                "(rendered test views vs {}, on the object: both over {r:.3},{g:.3},{b:.3} outside its masks{}; and inside the masks alone)",
                m.against,
                if o.masks == MaskUse::Loss {
                    ", the render composited as the reference is"
                } else {
                    ", the render as drawn"
                }
            )
        }
        None if m.sourced_pixels => println!(
            "(rendered test views vs {}, PSNR over the pixels their masks keep: undistortion's border and transparent pixels have no reference)",
            m.against
        ),
        None => println!("(rendered test views vs {})", m.against),
    }
    if let Some(o) = s.observed_psnr {
        println!(
            "(observed images vs clean: {o:.2} dB{})",
            s.observed_psnr_in_mask
                .map_or(String::new(), |p| format!(", {p:.2} dB in the masks"))
        );
    }
}

fn size(bytes: u64) -> String {
    match bytes {
        b if b < 1_000 => format!("{b} B"),
        b if b < 1_000_000 => format!("{:.1} kB", b as f64 / 1e3),
        b => format!("{:.1} MB", b as f64 / 1e6),
    }
}

/// What the run folder holds, and the command to look at the result.
fn print_outputs(dir: &Path, scene: &Path, downsample: u32, splats: usize) {
    let mut entries: Vec<_> = std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .filter(|e| !e.file_name().to_string_lossy().starts_with('.'))
        .collect();
    entries.sort_by_key(|e| e.file_name());
    let listed: Vec<String> = entries
        .iter()
        .map(|e| {
            let name = e.file_name().to_string_lossy().into_owned();
            let path = e.path();
            if path.is_dir() {
                let n = std::fs::read_dir(&path).map_or(0, |d| d.count());
                format!("{name}/ ({n} files)")
            } else {
                let bytes = e.metadata().map_or(0, |m| m.len());
                if name == output::PLY_FILE && splats > 0 {
                    format!(
                        "{name} ({}, {} B per splat)",
                        size(bytes),
                        bytes / splats as u64
                    )
                } else {
                    format!("{name} ({})", size(bytes))
                }
            }
        })
        .collect();
    println!(
        "The run folder {} holds {}.",
        dir.display(),
        listed.join(", ")
    );
    println!(
        "Look at the result: metasplat view {} --scene {} --downsample {downsample} --run {}",
        shell_word(&dir.join(output::PLY_FILE)),
        shell_word(scene),
        shell_word(dir)
    );
}

/// `path` as one word a POSIX shell reads back unchanged, so a suggested command can be
/// pasted as it is: plain when it holds only safe characters, else in single quotes.
fn shell_word(path: &std::path::Path) -> String {
    let text = path.display().to_string();
    let safe = |c: char| c.is_ascii_alphanumeric() || "/._-+,:@%=".contains(c);
    if !text.is_empty() && text.chars().all(safe) {
        text
    } else {
        format!("'{}'", text.replace('\'', "'\\''"))
    }
}

pub fn run(a: RunRequest) -> Result<()> {
    train_run(&a, false)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::shell_word;

    /// The shell itself reads each word back as the path it was made from.
    #[test]
    fn a_suggested_path_survives_the_shell() {
        for path in ["runs/plain", "runs/e3 ü", "it's here", "a$b`c\"d", "-x/*"] {
            let word = shell_word(std::path::Path::new(path));
            let out = std::process::Command::new("sh")
                .arg("-c")
                .arg(format!("printf %s {word}"))
                .output()
                .unwrap();
            assert_eq!(String::from_utf8(out.stdout).unwrap(), path, "{word}");
        }
        assert_eq!(shell_word(std::path::Path::new("runs/plain")), "runs/plain");
    }
}
