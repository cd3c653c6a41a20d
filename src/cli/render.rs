//! `metasplat render`: the library's job ([`metasplat::jobs::render`]) and what it made.

use anyhow::Result;
use metasplat::jobs::render::{RenderReport, prepare};

pub use metasplat::jobs::render::RenderRequest as RenderArgs;

pub fn run(a: RenderArgs) -> Result<()> {
    let prepared = prepare(&a)?;
    for note in &prepared.notes {
        println!("{note}");
    }
    print_report(&prepared.run()?);
    Ok(())
}

fn print_report(r: &RenderReport) {
    let (w, h) = r.size;
    match r.video {
        Some((fps, ffmpeg)) => println!(
            "{} splats (SH degree {}) rendered to {} frames {w}x{h} and written as {} at {fps} frames per second{} in {:.2} s",
            r.splats,
            r.sh_degree,
            r.frames,
            r.target.display(),
            if ffmpeg { " through ffmpeg" } else { "" },
            r.seconds,
        ),
        None => println!(
            "{} splats (SH degree {}) rendered to {} images {w}x{h} in {:.2} s under {}",
            r.splats,
            r.sh_degree,
            r.frames,
            r.seconds,
            r.target.display()
        ),
    }
    for line in &r.said {
        println!("{line}");
    }
}
