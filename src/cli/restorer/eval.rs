//! `metasplat restorer eval` and `restorer eval-video`: validation tables.

use crate::cli::progress::bar;
use aberration::wiener::{BANK_MEDIAN, bank_constants};
use aberration::{BlurMode, Image, ImagingModel, NoiseModel, Regularizer, deconvolve};
use anyhow::{Context, Result};
use clap::Args;
use std::path::{Path, PathBuf};
use std::time::Instant;

use super::network::{Inference, Score, metric};
use restore::data::load_folder;

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
    // Blurred to one scale, the photos are restored by the shipped network for it.
    let (native, restorer) = a.net.load(|_| a.psf_px.map(|p| p as usize | 1))?;
    let photos = load_folder(&a.val, 1)?;
    let noise = NoiseModel::default();
    let ks = bank_constants();
    // Single fixed K candidates: the bank's constants.
    let mut single = vec![Score::default(); ks.len()];
    let (mut input, mut median, mut net) = (Score::default(), Score::default(), Score::default());
    let base_filter = restorer.config().residual_base;
    let mut base = Score::default();
    let mut net_secs = 0.0;
    let mut mapped_px = (usize::MAX, 0);
    let pb = bar(photos.len() as u64, "evaluating");
    for (i, (name, clean)) in photos.iter().enumerate() {
        let sensor = a
            .psf_px
            .map(|px| native.sensor_for_psf_px(clean.width, clean.height, px as usize));
        let model = ImagingModel::new(
            &native,
            clean.width,
            clean.height,
            BlurMode::Tiled,
            sensor,
            noise,
        )
        .with_context(|| format!("{name} in --val {}", a.val.display()))?;
        let k = model.psf().size();
        mapped_px = (mapped_px.0.min(k), mapped_px.1.max(k));
        let blurred = model.capture(clean, 0x5EED_0000 + i as u64)?;
        input.add(&blurred, clean)?;
        let bank = restore::data::bank_images(&blurred, model.psf(), restorer.config().adaptive_k)?;
        median.add(&bank[BANK_MEDIAN], clean)?;
        if base_filter != BANK_MEDIAN {
            base.add(&bank[base_filter], clean)?;
        }
        for (j, &k) in ks.iter().enumerate() {
            let img = deconvolve(&blurred, model.psf(), Regularizer::Fixed(k))?;
            single[j].add(&img, clean)?;
        }
        let t = Instant::now();
        let restored = restorer.restore_bank(&bank);
        net_secs += t.elapsed().as_secs_f64();
        net.add(&restored, clean)?;
        if let Some(dir) = &a.out {
            std::fs::create_dir_all(dir)
                .with_context(|| format!("cannot create {}", dir.display()))?;
            let stem = Path::new(name)
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default();
            strip(&[&blurred, &bank[base_filter], &restored, clean])
                .save_png(&dir.join(format!("{stem}_abr_base_net_clean.png")))?;
        }
        pb.inc(1);
    }
    pb.finish_and_clear();
    if base_filter == BANK_MEDIAN {
        base = median;
    }
    let n = photos.len() as f64;
    let (jbest, best) = single
        .iter()
        .enumerate()
        .max_by(|a, b| a.1.psnr.total_cmp(&b.1.psnr))
        .expect("13 constants");
    let kind = if restorer.config().adaptive_k {
        "adaptive"
    } else {
        "fixed"
    };
    let mut rows = vec![
        ("aberrated input".to_string(), input),
        (format!("Wiener, best single K = {:.2e}", ks[jbest]), *best),
        (
            format!("median MAFG Wiener ({kind} K {:.2e})", ks[BANK_MEDIAN]),
            median,
        ),
        (format!("network ({})", restorer.config().name), net),
    ];
    if base_filter != BANK_MEDIAN {
        rows.insert(
            3,
            (
                format!(
                    "MAFG Wiener filter {base_filter}, the network's residual base ({kind} K {:.2e})",
                    ks[base_filter]
                ),
                base,
            ),
        );
    }
    let scale = if mapped_px.0 == mapped_px.1 {
        format!("{} px", mapped_px.0)
    } else {
        format!("{}-{} px", mapped_px.0, mapped_px.1)
    };
    println!(
        "{} validation photos, {}; PSFs of {scale} at the photos' size ({})",
        photos.len(),
        a.val.display(),
        match a.psf_px {
            Some(px) => format!("--psf-px {px}"),
            None => "the grid's own sensor".into(),
        }
    );
    println!("| method | PSNR (dB) | SSIM | PSNR on Y (dB) |\n|---|---:|---:|---:|");
    for (name, r) in &rows {
        println!(
            "| {name} | {:.2} | {:.4} | {:.2} |",
            r.psnr / n,
            r.ssim / n,
            r.psnr_y / n
        );
    }
    let mp: f64 = photos
        .iter()
        .map(|(_, i)| (i.width * i.height) as f64)
        .sum::<f64>()
        / 1e6;
    println!(
        "network: {:+.2} dB over the best single-K Wiener, {:+.2} dB over the median Wiener image, {:+.2} dB over its residual base (filter {base_filter}); inference {:.0} ms per megapixel ({} threads, tiles {} px)",
        (net.psnr - best.psnr) / n,
        (net.psnr - median.psnr) / n,
        (net.psnr - base.psnr) / n,
        1000.0 * net_secs / mp,
        rayon::current_num_threads(),
        restorer.tile
    );
    Ok(())
}

/// Images side by side.
fn strip(images: &[&Image]) -> Image {
    let (w, h) = (images[0].width, images[0].height);
    Image::from_fn(w * images.len(), h, |x, y| {
        let img = images[x / w];
        std::array::from_fn(|c| img.get(x % w, y, c))
    })
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
        let (p, s) = metric(r, c)?;
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
