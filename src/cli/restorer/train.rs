//! `metasplat restorer train`: the library's job ([`metasplat::jobs::restorer_train`]) with a
//! progress bar and its report.

use crate::cli::progress::{bar, say};
use anyhow::Result;
use indicatif::{ProgressBar, ProgressStyle};
use metasplat::jobs::restorer_train::{RestorerEvent, RestorerReport, prepare};
use restore::train::Event;

pub use metasplat::jobs::restorer_train::RestorerTrainRequest as TrainRestorerArgs;

/// What the terminal shows of a run: a bar for the lens family, a spinner for a phase, a bar
/// for the steps with the smoothed loss.
#[derive(Default)]
struct Shown {
    pb: Option<ProgressBar>,
    ema: Option<f32>,
}

impl Shown {
    fn say(&self, line: String) {
        match &self.pb {
            Some(pb) => say(pb, line),
            None => println!("{line}"),
        }
    }

    fn replace(&mut self, pb: Option<ProgressBar>) {
        if let Some(old) = self.pb.take() {
            old.finish_and_clear();
        }
        self.pb = pb;
    }

    fn show(&mut self, e: RestorerEvent) {
        match e {
            RestorerEvent::Said(line) => self.say(line),
            RestorerEvent::Lenses { done, total } => {
                if done <= 1 {
                    self.replace(Some(bar(total as u64, "lens family")));
                }
                if let Some(pb) = &self.pb {
                    pb.set_position(done as u64);
                }
                if done == total {
                    self.replace(None);
                }
            }
            RestorerEvent::Phase(what) => {
                let pb = ProgressBar::new_spinner();
                pb.set_style(
                    ProgressStyle::with_template("{spinner} {msg} {elapsed}")
                        .expect("static template"),
                );
                pb.set_message(what);
                pb.enable_steady_tick(std::time::Duration::from_millis(120));
                self.replace(Some(pb));
            }
            RestorerEvent::Training { first, steps } => {
                let pb = bar(steps as u64, "training");
                pb.set_position(first as u64);
                pb.set_message("aberrating the training photos");
                self.replace(Some(pb));
            }
            RestorerEvent::Step(e) => self.step(e),
        }
    }

    fn step(&mut self, e: &Event) {
        match *e {
            Event::Pairs {
                round,
                samples,
                seconds,
            } => self.say(format!(
                "round {round}: {samples} training pairs ({seconds:.1} s)"
            )),
            Event::Step { step, loss, lr } => {
                let e = self.ema.map_or(loss, |m| 0.95 * m + 0.05 * loss);
                self.ema = Some(e);
                if let Some(pb) = &self.pb {
                    pb.set_position(step as u64);
                    pb.set_message(format!("L1 {e:.4} lr {lr:.1e}"));
                }
            }
            Event::Val {
                step,
                psnr,
                ssim,
                seconds,
                ref groups,
            } => {
                let by_group = groups
                    .iter()
                    .map(|(name, p)| format!("{name} {p:.2}"))
                    .collect::<Vec<_>>()
                    .join(", ");
                self.say(format!(
                    "step {step:>6}  {seconds:>7.0} s  val PSNR {psnr:.2} dB  SSIM {ssim:.4}{}",
                    if by_group.is_empty() {
                        String::new()
                    } else {
                        format!("  ({by_group})")
                    }
                ))
            }
        }
    }
}

fn print_report(r: &RestorerReport) {
    println!(
        "trained to step {} of {} ({} steps in this run) in {:.1} min ({:.2} steps/s); validation ({}): PSNR {:.2} dB, SSIM {:.4}; weights: {}, state: {}",
        r.reached,
        r.steps,
        r.reached - r.first,
        r.seconds / 60.0,
        (r.reached - r.first) as f64 / r.seconds,
        match r.val_crop {
            0 => "whole photos".to_string(),
            side => format!("centred {side} px crops"),
        },
        r.val.0,
        r.val.1,
        r.weights.display(),
        r.state.display()
    );
    if r.stopped_early() {
        println!(
            "stopped early (--minutes); continue with the same command and --resume (without --init)"
        );
    }
}

pub(crate) fn run_train(a: TrainRestorerArgs) -> Result<()> {
    let command = std::env::args().collect::<Vec<_>>().join(" ");
    let prepared = prepare(&a, &command)?;
    for note in &prepared.notes {
        println!("{note}");
    }
    let mut shown = Shown::default();
    let report = prepared.run(&mut |e| shown.show(e));
    shown.replace(None);
    print_report(&report?);
    Ok(())
}
