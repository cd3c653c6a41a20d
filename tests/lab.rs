//! The experiments as library jobs: `experiment psf-mismatch` driven through
//! `metasplat::lab` without the binary, and its report read.

mod common;

use clap::Parser;
use metasplat::lab::psf_mismatch::{self, PsfMismatchArgs};

#[derive(Parser)]
struct Args {
    #[command(flatten)]
    a: PsfMismatchArgs,
}

fn args(flags: &[&str]) -> PsfMismatchArgs {
    Args::parse_from(std::iter::once("psf-mismatch").chain(flags.iter().copied())).a
}

/// A wrong grid (measurement noise of 0.3 of each PSF's peak) in two variants: the report
/// holds every run's figures, the table it wrote, and the grid error; errors that simulate
/// the paper's lens are refused with a grid given, before anything is made.
#[test]
fn psf_mismatch_runs_through_the_library_and_reports() {
    let c = common::small_capture(3);
    let out = c.dir.path().join("exp");
    let common_flags = [
        "--scene",
        common::cli::s(&c.clean),
        "--out",
        common::cli::s(&out),
        "--psf",
        common::cli::s(&c.psf),
        "--downsample",
        "1",
        "--iters",
        "40",
        "--device",
        "cpu",
    ];
    let refused = psf_mismatch::run(
        &args(&[&common_flags[..], &["--errors", "focal:+3"]].concat()),
        &mut |_| {},
    )
    .unwrap_err()
    .to_string();
    assert!(refused.contains("--errors focal:+3"), "{refused}");
    assert!(!out.exists(), "a refused experiment made {}", out.display());

    let mut said = Vec::new();
    let a = args(
        &[
            &common_flags[..],
            &["--errors", "noise:0.3", "--variants", "wrong,iac-only"],
        ]
        .concat(),
    );
    let report = psf_mismatch::run(&a, &mut |s| said.push(s)).unwrap();
    assert_eq!(report.rows.len(), 1);
    assert_eq!(report.rows[0].len(), 2);
    for f in [&report.matched, &report.restored]
        .into_iter()
        .chain(&report.rows[0])
    {
        assert!(f.psnr.is_finite() && f.psnr > 10.0, "{f:?}");
        assert!(f.ssim > 0.0 && f.ssim <= 1.0, "{f:?}");
    }
    assert!(report.grid_errors[0] > 0.05, "{:?}", report.grid_errors);
    assert!(
        report.table.contains("noise 0.3 of peak"),
        "{}",
        report.table
    );
    assert_eq!(
        std::fs::read_to_string(&report.table_path).unwrap(),
        report.table
    );
    assert!(
        said.iter()
            .any(|s| s.contains("with the true grid (matched)")),
        "{said:?}"
    );
    // Every run's folder holds its metrics.
    for run in [
        "run_matched",
        "run_restored",
        "run_noise0.3_wrong",
        "run_noise0.3_iac-only",
    ] {
        assert!(out.join(run).join("metrics.json").is_file(), "{run}");
    }
}

/// The quick demo through the library: both modes trained, aware above plain on the held-out
/// views, the plot and the PSF picture written.
#[test]
fn the_demo_runs_through_the_library_and_aware_beats_plain() {
    use metasplat::lab::demo;
    #[derive(Parser)]
    struct DemoCli {
        #[command(flatten)]
        a: demo::DemoArgs,
    }
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("demo");
    let a = DemoCli::parse_from(["demo", "--quick", "--out", common::cli::s(&out)]).a;
    let report = demo::run(&a, &mut metasplat::run::train_quietly, &mut |_| {}).unwrap();
    let psnr = |k: usize| report.runs[k].1.metrics.as_ref().unwrap().mean_psnr;
    assert_eq!(report.runs.len(), 2);
    assert!(
        psnr(1) > psnr(0) + 0.5,
        "aware {} plain {}",
        psnr(1),
        psnr(0)
    );
    assert!(report.plot.is_file() && report.psf_picture.is_file());
}
