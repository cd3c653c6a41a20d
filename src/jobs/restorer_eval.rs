//! The restorer's validation table as a job: every photo blurred through the grid (at the
//! grid's own scale or at a PSF size asked for), then scored as blurred, through each single-K
//! Wiener filter, through MAFG's median and residual-base filters, and through the network.

use aberration::wiener::{BANK_MEDIAN, bank_constants};
use aberration::{BlurMode, Image, ImagingModel, NoiseModel, PsfGrid, Regularizer, deconvolve};
use restore::Restorer;
use std::path::Path;
use std::time::Instant;

use crate::error::{Result, TrainError};

/// Sums of one method's scores over the photos: PSNR and SSIM on RGB, and PSNR on the luma
/// channel, the paper's figure.
#[derive(Clone, Copy, Debug, Default)]
pub struct Score {
    pub psnr: f64,
    pub ssim: f64,
    pub psnr_y: f64,
}

impl Score {
    pub fn add(&mut self, image: &Image, clean: &Image) -> Result<()> {
        let (p, s) = aberration::compare(image, clean)?;
        let mut clamped = image.clone();
        clamped.clamp01();
        self.psnr += p;
        self.ssim += s;
        self.psnr_y += base::metrics::psnr_y_planar(&clamped.data, &clean.data)?;
        Ok(())
    }
}

/// What [`evaluate`] measured: sums over `photos` (divide by it for means).
#[derive(Clone, Debug)]
pub struct EvalReport {
    pub photos: usize,
    /// The smallest and largest PSF size (px) the photos were blurred with.
    pub mapped_px: (usize, usize),
    pub input: Score,
    /// The best of the single-K Wiener filters, and its K.
    pub best: Score,
    pub best_k: f32,
    pub median: Score,
    /// The bank filter the network's output is added to, its index and K.
    pub base: Score,
    pub base_filter: usize,
    pub network: Score,
    /// The network as [`restore::Restorer::label`] names it.
    pub network_name: String,
    /// Whether the bank's K follows each channel's intensity.
    pub adaptive_k: bool,
    /// The network's time and the photos' megapixels, for its speed.
    pub network_seconds: f64,
    pub megapixels: f64,
    pub tile: usize,
    /// Members of the self-ensemble the network ran with (1: one pass).
    pub ensemble: usize,
}

/// Blurs each photo of `photos` through `native` (its PSFs mapped to `psf_px` at the photo's
/// size, or the grid's own sensor), with the noise of photo `i` seeded by `i`, and scores every
/// method; with `strips`, writes there per photo the blurred photo, the residual base, the
/// network's image and the clean one side by side. `on_photo` is called after each.
pub fn evaluate(
    native: &PsfGrid,
    restorer: &Restorer,
    photos: &[(String, Image)],
    psf_px: Option<usize>,
    strips: Option<&Path>,
    on_photo: &mut dyn FnMut(),
) -> Result<EvalReport> {
    let noise = NoiseModel::default();
    let ks = bank_constants();
    let mut single = vec![Score::default(); ks.len()];
    let (mut input, mut median, mut network) =
        (Score::default(), Score::default(), Score::default());
    let base_filter = restorer.config().residual_base;
    let mut base = Score::default();
    let mut network_seconds = 0.0;
    let mut mapped_px = (usize::MAX, 0);
    for (i, (name, clean)) in photos.iter().enumerate() {
        let sensor = psf_px.map(|px| native.sensor_for_psf_px(clean.width, clean.height, px));
        let model = ImagingModel::new(
            native,
            clean.width,
            clean.height,
            BlurMode::Tiled,
            sensor,
            noise,
        )
        .map_err(|e| TrainError::from(e).context(name.clone()))?;
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
        network_seconds += t.elapsed().as_secs_f64();
        network.add(&restored, clean)?;
        if let Some(dir) = strips {
            std::fs::create_dir_all(dir).map_err(|e| TrainError::io(dir, e))?;
            let stem = Path::new(name)
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default();
            strip(&[&blurred, &bank[base_filter], &restored, clean])
                .save_png(&dir.join(format!("{stem}_abr_base_net_clean.png")))?;
        }
        on_photo();
    }
    if base_filter == BANK_MEDIAN {
        base = median;
    }
    let (jbest, best) = single
        .iter()
        .enumerate()
        .max_by(|a, b| a.1.psnr.total_cmp(&b.1.psnr))
        .expect("13 constants");
    Ok(EvalReport {
        photos: photos.len(),
        mapped_px,
        input,
        best: *best,
        best_k: ks[jbest],
        median,
        base,
        base_filter,
        network,
        network_name: restorer.label(),
        adaptive_k: restorer.config().adaptive_k,
        network_seconds,
        megapixels: photos
            .iter()
            .map(|(_, i)| (i.width * i.height) as f64)
            .sum::<f64>()
            / 1e6,
        tile: restorer.tile,
        ensemble: restorer.ensemble,
    })
}

impl EvalReport {
    /// The PSF sizes, `57 px` or `19-23 px`.
    pub fn scale(&self) -> String {
        match self.mapped_px {
            (a, b) if a == b => format!("{a} px"),
            (a, b) => format!("{a}-{b} px"),
        }
    }

    /// The table's rows: each method and its mean PSNR, SSIM and PSNR on Y.
    pub fn rows(&self) -> Vec<(String, f64, f64, f64)> {
        let ks = bank_constants();
        let kind = if self.adaptive_k { "adaptive" } else { "fixed" };
        let mut rows = vec![
            ("aberrated input".to_string(), self.input),
            (
                format!("Wiener, best single K = {:.2e}", self.best_k),
                self.best,
            ),
            (
                format!("median MAFG Wiener ({kind} K {:.2e})", ks[BANK_MEDIAN]),
                self.median,
            ),
            (format!("network ({})", self.network_name), self.network),
        ];
        if self.base_filter != BANK_MEDIAN {
            rows.insert(
                3,
                (
                    format!(
                        "MAFG Wiener filter {}, the network's residual base ({kind} K {:.2e})",
                        self.base_filter, ks[self.base_filter]
                    ),
                    self.base,
                ),
            );
        }
        let n = self.photos as f64;
        rows.into_iter()
            .map(|(m, s)| (m, s.psnr / n, s.ssim / n, s.psnr_y / n))
            .collect()
    }

    /// The table in Markdown.
    pub fn table(&self) -> String {
        let mut t =
            String::from("| method | PSNR (dB) | SSIM | PSNR on Y (dB) |\n|---|---:|---:|---:|");
        for (m, p, s, y) in self.rows() {
            t.push_str(&format!("\n| {m} | {p:.2} | {s:.4} | {y:.2} |"));
        }
        t
    }

    /// The network against the filters, and its speed.
    pub fn summary(&self) -> String {
        let n = self.photos as f64;
        let net = self.network.psnr;
        format!(
            "network: {:+.2} dB over the best single-K Wiener, {:+.2} dB over the median Wiener image, {:+.2} dB over its residual base (filter {}); inference {:.0} ms per megapixel ({} threads, tiles {} px, {} pass{} a photo)",
            (net - self.best.psnr) / n,
            (net - self.median.psnr) / n,
            (net - self.base.psnr) / n,
            self.base_filter,
            1000.0 * self.network_seconds / self.megapixels,
            rayon::current_num_threads(),
            self.tile,
            self.ensemble,
            if self.ensemble == 1 { "" } else { "es" },
        )
    }
}

/// Images side by side.
fn strip(images: &[&Image]) -> Image {
    let (w, h) = (images[0].width, images[0].height);
    Image::from_fn(w * images.len(), h, |x, y| {
        let img = images[x / w];
        std::array::from_fn(|c| img.get(x % w, y, c))
    })
}
