//! `metasplat demo`: [`metasplat::lab::demo`] with its table printed.

use anyhow::Result;
use metasplat::lab::demo;
pub use metasplat::lab::demo::DemoArgs;
use std::time::Instant;

pub fn run(a: DemoArgs) -> Result<()> {
    let start = Instant::now();
    let report = demo::run(&a, &mut |r| super::train::train_run(r, true), &mut |s| {
        println!("{s}")
    })?;
    let (results, plot) = (&report.runs, &report.plot);
    println!(
        "\nheld-out views of the procedural scene vs the clean images (aware: lambda {}; {}):",
        results
            .iter()
            .find_map(|r| r.1.lambda)
            .map_or("-".to_string(), |l| l.to_string()),
        results
            .iter()
            .find_map(|r| r.1.restorer.clone())
            .unwrap_or_default()
    );
    println!(
        "{:<22} {:>8} {:>7} {:>8} {:>9}",
        "", "PSNR dB", "SSIM", "splats", "train s"
    );
    let observed = results
        .first()
        .and_then(|r| r.1.observed_psnr)
        .unwrap_or(f64::NAN);
    println!("{:<22} {:>8.2}", "aberrated input", observed);
    for (mode, s, _) in results {
        if let Some(m) = &s.metrics {
            println!(
                "{:<22} {:>8.2} {:>7.4} {:>8} {:>9.1}",
                format!("3DGS {mode}"),
                m.mean_psnr,
                m.mean_ssim,
                s.splats,
                s.train_seconds
            );
        }
    }
    for (mode, _, dir) in results {
        println!(
            "{mode}: {} (PLY), {}/test/*_compare.png (photo | render | clean), {}/spiral/",
            dir.join(metasplat::output::PLY_FILE).display(),
            dir.display(),
            dir.display()
        );
    }
    println!(
        "plain against aware: {}; PSF grid picture: {}; total {:.0} s",
        plot.display(),
        report.psf_picture.display(),
        start.elapsed().as_secs_f64()
    );
    Ok(())
}
