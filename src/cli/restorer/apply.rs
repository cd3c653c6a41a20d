//! `metasplat restore`: the library's job ([`metasplat::jobs::restore`]) with its progress
//! and what it made.

use anyhow::Result;
use indicatif::{ProgressBar, ProgressStyle};
use metasplat::jobs::restore::{RestoreEvent, RestoreReport, Restored, run};

pub use metasplat::jobs::restore::RestoreRequest as RestoreArgs;

pub fn run_restore(a: RestoreArgs) -> Result<()> {
    let mut spinner: Option<ProgressBar> = None;
    let report = run(&a, &mut |e| {
        if let Some(s) = spinner.take() {
            s.finish_and_clear();
        }
        match e {
            RestoreEvent::Said(line) => println!("{line}"),
            RestoreEvent::Restoring => {
                let s = ProgressBar::new_spinner();
                s.set_style(
                    ProgressStyle::with_template("{spinner} {msg} {elapsed}")
                        .expect("static template"),
                );
                s.set_message("restoring");
                s.enable_steady_tick(std::time::Duration::from_millis(120));
                spinner = Some(s);
            }
            RestoreEvent::Frame {
                done,
                total,
                name,
                left,
            } => {
                let name = if name.is_empty() {
                    String::new()
                } else {
                    format!(" ({name})")
                };
                println!("frame {done} of {total}{name} restored; about {left:.0} s left");
            }
        }
    });
    if let Some(s) = spinner.take() {
        s.finish_and_clear();
    }
    print_report(&report?);
    Ok(())
}

fn print_report(r: &RestoreReport) {
    let (w, h) = r.size;
    let (network, out) = (&r.network, r.out.display());
    match r.kind {
        Restored::Video(fps) => println!(
            "restored {} frames {w}x{h} with '{network}' in {:.1} s and wrote {out} at {fps} frames per second",
            r.frames, r.seconds
        ),
        Restored::Frames | Restored::Gif => println!(
            "restored {} frames {w}x{h} with '{network}' in {:.1} s -> {out}",
            r.frames, r.seconds
        ),
        Restored::Photo => {
            print!(
                "restored {w}x{h} with '{network}' in {:.2} s -> {out}",
                r.seconds
            );
            if let Some([p0, p1, s0, s1]) = r.against_reference {
                print!("; PSNR {p0:.2} -> {p1:.2} dB, SSIM {s0:.4} -> {s1:.4}");
            }
            println!();
        }
    }
}
