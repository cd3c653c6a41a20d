//! `metasplat restorer eval` and `restorer eval-video`: validation tables.

use crate::cli::progress::bar;
use aberration::Image;
use anyhow::{Context, Result};
use clap::Args;
use metasplat::jobs::restorer_eval::evaluate;
use restore::data::load_folder;
use std::path::{Path, PathBuf};

use metasplat::jobs::restorer_net::Inference;

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
pub struct EvalVideoArgs {
    /// The restored clip: a folder of frames, in name order.
    #[arg(long)]
    pub restored: PathBuf,
    /// The clean clip: as many frames of the same size, in name order.
    #[arg(long)]
    pub clean: PathBuf,
}

pub(crate) fn run_eval(a: EvalArgs) -> Result<()> {
    if let Some(out) = &a.out {
        let mut inputs = a.net.inputs();
        inputs.push(("--val", a.val.as_path()));
        metasplat::output::guard::refuse_overwrite("--out", out, &inputs)?;
        metasplat::output::guard::refuse_file_as_folder("--out", out)?;
    }
    let psf_px = a.psf_px.map(|p| p as usize | 1);
    // Blurred to one scale, the photos are restored by the shipped network for it.
    let (native, restorer, said) = a.net.load(|_| psf_px)?;
    if let Some(line) = said {
        println!("{line}");
    }
    let photos = load_folder(&a.val, 1)?;
    let pb = bar(photos.len() as u64, "evaluating");
    let report = evaluate(
        &native,
        &restorer,
        &photos,
        a.psf_px.map(|p| p as usize),
        a.out.as_deref(),
        &mut || pb.inc(1),
    )
    .with_context(|| format!("--val {}", a.val.display()))?;
    pb.finish_and_clear();
    println!(
        "{} validation photos, {}; PSFs of {} at the photos' size ({})",
        report.photos,
        a.val.display(),
        report.scale(),
        match a.psf_px {
            Some(px) => format!("--psf-px {px}"),
            None => "the grid's own sensor".into(),
        }
    );
    println!("{}", report.table());
    println!("{}", report.summary());
    Ok(())
}

pub(crate) fn run_eval_video(a: EvalVideoArgs) -> Result<()> {
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
        let (p, s) = aberration::compare(r, c)?;
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
