//! `metasplat psf simulate|show`: the library's jobs ([`metasplat::jobs::psf`]) behind a
//! progress bar, their reports printed.

use super::progress;
use aberration::optics::SimReport;
use anyhow::Result;
use clap::Subcommand;

pub use metasplat::jobs::psf::{ShowRequest as ShowArgs, SimulateRequest as SimulateArgs};

#[derive(Subcommand)]
pub enum PsfCommand {
    /// Simulate the G×G PSF grid from the metalens phase profile and write it as .npy.
    Simulate(SimulateArgs),
    /// Draw a PSF grid file as a picture (log scale, one panel per channel).
    Show(ShowArgs),
}

pub fn run(cmd: PsfCommand) -> Result<()> {
    match cmd {
        PsfCommand::Simulate(a) => {
            let pb = progress::bar(0, "propagating");
            let r = metasplat::jobs::psf::simulate(&a, &|done, total| {
                pb.set_length(total as u64);
                pb.set_position(done as u64);
            });
            pb.finish_and_clear();
            let r = r?;
            println!("wrote {}", r.out.display());
            if let Some(p) = &r.picture {
                println!("wrote {}", p.display());
            }
            print_report(&r.sim);
            Ok(())
        }
        PsfCommand::Show(a) => {
            let (g, k) = metasplat::jobs::psf::show(&a)?;
            println!(
                "{}: {g}x{g} grid of {k} px RGB PSFs; wrote {}",
                a.psf.display(),
                a.out.display()
            );
            Ok(())
        }
    }
}

pub fn print_report(r: &SimReport) {
    println!(
        "simulated {} field angles x 3 wavelengths in {:.1} s",
        r.angles_deg.len(),
        r.seconds
    );
    println!(
        "{:>8}  {:>24}  {:>27}",
        "angle", "power in crop (R G B)", "unit-sum peak (R G B)"
    );
    for (i, a) in r.angles_deg.iter().enumerate() {
        let c = r.crop_power[i];
        let p = r.peak[i];
        println!(
            "{:>7.2}°  {:>7.3} {:>7.3} {:>7.3}   {:>8.5} {:>8.5} {:>8.5}",
            a, c[0], c[1], c[2], p[0], p[1], p[2]
        );
    }
}
