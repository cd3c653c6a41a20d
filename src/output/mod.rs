//! Everything a finished run leaves in its folder: the PLY, metrics, the log, test-view
//! renders beside their clean and aberrated images, and the spiral frames; where outputs may
//! go ([`guard`]), the plots ([`plot`]) and what the viewer reads from a run ([`view`]).

pub mod guard;
pub(crate) mod plot;
pub mod video;
pub mod view;

use std::path::{Path, PathBuf};

use aberration::image::save_rgb8_png;
use glam::Vec3;
use rayon::prelude::*;
use serde::Serialize;

use crate::error::{Result, TrainError};
use crate::splats::convert::{pixels_to_image, save_pixels, splat_camera};
use crate::splats::device::Device;
use crate::train::config::TrainConfig;
use crate::train::data::Dataset;
use crate::train::eval::{self, Metrics};
use crate::train::{LogRow, Outcome};

pub const PLY_FILE: &str = "point_cloud.ply";
pub const METRICS_FILE: &str = "metrics.json";
pub const LOG_FILE: &str = "train_log.csv";
pub const CHECKPOINT_FILE: &str = "checkpoint.bin";
pub const CONFIG_FILE: &str = "config.json";
pub const PSNR_PLOT: &str = "psnr_vs_time.png";
/// The refined PSF grid (`--refine-psf`), at the images' scale, in the paper's layout.
pub const PSF_REFINED_FILE: &str = "psf_refined.npy";
/// The supplied grid above the refined one.
pub const PSF_REFINED_PICTURE: &str = "psf_refined.png";
/// Everything a run writes into its folder (folders end in `/`).
pub const RUN_FILES: [&str; 10] = [
    PSF_REFINED_FILE,
    PSF_REFINED_PICTURE,
    PLY_FILE,
    CHECKPOINT_FILE,
    METRICS_FILE,
    LOG_FILE,
    CONFIG_FILE,
    PSNR_PLOT,
    "test/",
    "spiral/",
];

/// The splats kept after `step` (`--save-at`).
pub fn snapshot_file(step: u64) -> String {
    format!("point_cloud_{step}.ply")
}

/// Whether `name` is a file [`snapshot_file`] names.
pub fn is_snapshot(name: &str) -> bool {
    name.strip_prefix("point_cloud_")
        .and_then(|r| r.strip_suffix(".ply"))
        .is_some_and(|n| !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit()))
}

/// Removes a previous run's outputs from `dir` (`--overwrite`), and nothing else.
pub fn clear_run(dir: &Path) -> Result<()> {
    for entry in std::fs::read_dir(dir).into_iter().flatten().flatten() {
        let name = entry.file_name();
        if name.to_str().is_some_and(is_snapshot) {
            let p = entry.path();
            std::fs::remove_file(&p).map_err(|e| TrainError::io(&p, e))?;
        }
    }
    for f in RUN_FILES {
        let p = dir.join(f.trim_end_matches('/'));
        let r = if f.ends_with('/') {
            std::fs::remove_dir_all(&p)
        } else {
            std::fs::remove_file(&p)
        };
        match r {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                return Err(TrainError::io(&p, e));
            }
            _ => {}
        }
    }
    Ok(())
}

/// Creates the run folder, takes it for this process alone (a second writer is refused until
/// the returned lock is dropped) and proves it writable before any training time is spent; a
/// killed run's temporary files and staging folders in it are removed. `command` names the
/// writer for the message a second one gets.
pub fn prepare_run_dir(dir: &Path, command: &str) -> Result<base::FolderLock> {
    std::fs::create_dir_all(dir).map_err(|e| TrainError::io(dir, e))?;
    let lock = base::FolderLock::folder(dir, command)?;
    base::remove_orphans(dir);
    // Named as our temporaries are, so a run killed right here leaves nothing the next run
    // in this folder does not remove.
    let probe = dir.join(format!("{}write-test", base::temp_prefix()));
    std::fs::write(&probe, b"ok")
        .map_err(|e| TrainError::file(dir, format!("not writable: {e}")))?;
    let _ = std::fs::remove_file(&probe);
    Ok(lock)
}

pub fn write_json(path: &Path, value: &impl Serialize) -> Result<()> {
    let text =
        serde_json::to_string_pretty(value).map_err(|e| TrainError::file(path, e.to_string()))?;
    base::write_bytes_atomically(path, (text + "\n").as_bytes())
        .map_err(|e| TrainError::io(path, e))
}

pub fn write_log_csv(path: &Path, log: &[LogRow]) -> Result<()> {
    let opt = |v: Option<f64>| v.map_or(String::new(), |v| format!("{v:.4}"));
    let mut text =
        String::from("step,seconds,loss,train_psnr,test_psnr,test_ssim,splats,sh_degree\n");
    for r in log {
        text += &format!(
            "{},{:.3},{:.6},{:.4},{},{},{},{}\n",
            r.step,
            r.seconds,
            r.loss,
            r.train_psnr,
            opt(r.test_psnr),
            opt(r.test_ssim),
            r.splats,
            r.sh_degree
        );
    }
    base::write_bytes_atomically(path, text.as_bytes()).map_err(|e| TrainError::io(path, e))
}

/// `metrics.json`.
#[derive(Clone, Debug, Serialize)]
pub struct RunSummary {
    pub mode: String,
    /// Steps trained (with `--iters auto`, where the rule ended the run).
    pub iters: u64,
    /// With `--iters auto`: when and why training stopped paying.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub stopped: Option<String>,
    pub train_seconds: f64,
    pub splats: usize,
    pub model_bytes: usize,
    pub sh_degree: u32,
    pub restorer: Option<String>,
    /// Weight of `L(render, I_ac)` (aware mode only).
    pub lambda: Option<f32>,
    /// Why there are no metrics, when there are none.
    pub not_evaluated: Option<String>,
    pub metrics: Option<Metrics>,
    /// Mean PSNR of the observed (aberrated) test images against the clean ones.
    pub observed_psnr: Option<f64>,
    /// The same inside the held-out views' object masks (a run scored on the object).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub observed_psnr_in_mask: Option<f64>,
    /// With `--refine-psf`: how far the refined grid moved from the supplied one (mean over
    /// grid cells of the relative L2 distance).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub psf_change: Option<f64>,
    /// With `--refine-psf warp`: the warp learnt.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub psf_warp: Option<crate::train::psf_refine::WarpSummary>,
}

impl RunSummary {
    /// Mean held-out PSNR and SSIM; NaN for a run that was not evaluated (a table cell that
    /// says so rather than a number).
    pub fn psnr_ssim(&self) -> (f64, f64) {
        self.metrics
            .as_ref()
            .map_or((f64::NAN, f64::NAN), |m| (m.mean_psnr, m.mean_ssim))
    }
}

/// The white gutter between the pictures of a comparison strip, in pixels.
const GAP: u32 = 6;

/// Images side by side with a white gutter.
fn side_by_side(images: &[&[Vec3]], width: u32, height: u32) -> image::RgbImage {
    let gap = GAP;
    let mut out = image::RgbImage::from_pixel(
        images.len() as u32 * (width + gap) - gap,
        height,
        image::Rgb([255, 255, 255]),
    );
    for (i, px) in images.iter().enumerate() {
        let mut img = pixels_to_image(px, width, height);
        img.clamp01();
        image::imageops::replace(
            &mut out,
            &img.to_rgb8(),
            (i as u32 * (width + gap)) as i64,
            0,
        );
    }
    out
}

/// Writes the whole run folder and returns what went into `metrics.json`.
pub fn write_run(
    dir: &Path,
    data: &Dataset,
    config: &TrainConfig,
    outcome: &Outcome,
    spiral_frames: usize,
    device: &Device,
) -> Result<RunSummary> {
    let model = &outcome.model;
    splat::formats::ply::write_ply(dir.join(PLY_FILE), model)?;
    write_log_csv(&dir.join(LOG_FILE), &outcome.log)?;
    let metrics = eval::evaluate(model, &data.test, &outcome.settings, device, config.masks)?;
    let not_evaluated = metrics
        .is_none()
        .then(|| "no held-out views (llffhold 0 or too few images)".to_string());

    // All or nothing: test views and spiral frames are rendered into a staging folder in the
    // run folder and moved in when every frame is written.
    let staging = tempfile::Builder::new()
        .prefix(&format!("{}frames-", base::temp_prefix()))
        .tempdir_in(dir)
        .map_err(|e| TrainError::io(dir, e))?;
    let test_dir = staging.path().join("test");
    std::fs::create_dir_all(&test_dir).map_err(|e| TrainError::io(&test_dir, e))?;
    let (w, h) = (data.width, data.height);
    let cameras: Vec<splat::Camera> = data.test.iter().map(|v| v.camera.clone()).collect();
    let renders = device.render_views(model, &cameras, &outcome.settings)?;
    data.test
        .par_iter()
        .zip(renders)
        .try_for_each(|(v, out)| -> Result<()> {
            let render = out.color;
            save_pixels(&test_dir.join(format!("{}.png", v.name)), &render, w, h)?;
            let mut row: Vec<&[Vec3]> = vec![&v.observed, &render];
            // Each panel's PSNR against the clean image, or the render's against the photo.
            let db = |a: &[Vec3], b: &[Vec3]| {
                base::metrics::psnr_rgb(a, b).map_or(String::new(), |p| format!(" {p:.2} dB"))
            };
            let labels = match &v.clean {
                Some(c) => {
                    row.push(c);
                    vec![
                        format!("photo{}", db(&v.observed, c)),
                        format!("render{}", db(&render, c)),
                        "clean".to_string(),
                    ]
                }
                None => vec![
                    "photo".to_string(),
                    format!("render{}", db(&render, &v.observed)),
                ],
            };
            save_rgb8_png(
                &crate::output::plot::label_panels(&side_by_side(&row, w, h), w, GAP, &labels),
                &test_dir.join(format!("{}_compare.png", v.name)),
            )?;
            Ok(())
        })?;

    if spiral_frames > 0 {
        let spiral_dir = staging.path().join("spiral");
        std::fs::create_dir_all(&spiral_dir).map_err(|e| TrainError::io(&spiral_dir, e))?;
        let path =
            scenes::spiral::spiral(&data.capture.cameras, &data.capture.bounds, spiral_frames);
        render_frames(model, &outcome.settings, &path, &spiral_dir, device)?;
    }
    for name in ["test", "spiral"] {
        let (from, to) = (staging.path().join(name), dir.join(name));
        if !from.exists() {
            continue;
        }
        if to.exists() {
            std::fs::remove_dir_all(&to).map_err(|e| TrainError::io(&to, e))?;
        }
        std::fs::rename(&from, &to).map_err(|e| TrainError::io(&to, e))?;
    }

    let observed_psnr = match &metrics {
        Some(m) if m.against == crate::train::eval::Against::Clean => {
            let (mut sum, mut in_mask) = (0.0, Vec::new());
            // On the object, the photo is scored as a render that learnt nothing outside it.
            let masks = config.masks.map(|_| crate::settings::MaskUse::Loss);
            for v in &data.test {
                // Against::Clean: every held-out view has its clean image.
                let clean = v.clean.as_deref().ok_or_else(|| {
                    TrainError::Invalid(format!("held-out view {} has no clean image", v.name))
                })?;
                let sc = eval::scored(
                    &v.observed,
                    clean,
                    v.mask.as_deref(),
                    masks,
                    outcome.settings.background,
                );
                sum += sc.compare(v.camera.width, v.camera.height)?.0;
                in_mask.extend(sc.psnr_in_mask());
            }
            Some((sum / data.test.len() as f64, eval::mean(&in_mask)))
        }
        _ => None,
    };
    let (observed_psnr, observed_psnr_in_mask) = match observed_psnr {
        Some((all, mask)) => (Some(all), mask),
        None => (None, None),
    };
    let psf_change = match &outcome.psf {
        Some((supplied, refined)) => {
            refined.save_npy(&dir.join(PSF_REFINED_FILE))?;
            save_rgb8_png(
                &aberration::picture::psf_grids_picture(&[supplied, refined]),
                &dir.join(PSF_REFINED_PICTURE),
            )?;
            let cells = aberration::refine::cell_errors(refined, supplied)?;
            Some(cells.iter().sum::<f64>() / cells.len() as f64)
        }
        None => None,
    };
    let summary = RunSummary {
        psf_change,
        psf_warp: outcome.psf_warp.clone(),
        mode: config.mode.to_string(),
        iters: outcome.steps,
        stopped: outcome.stopped.clone(),
        train_seconds: outcome.train_seconds,
        splats: model.len(),
        model_bytes: model.param_bytes(),
        sh_degree: model.sh_degree,
        restorer: data.restorer.as_ref().map(|r| r.describe()),
        lambda: (config.mode == crate::train::config::Mode::Aware).then_some(config.lambda),
        not_evaluated,
        metrics,
        observed_psnr,
        observed_psnr_in_mask,
    };
    write_json(&dir.join(METRICS_FILE), &summary)?;
    Ok(summary)
}

/// Renders a capture's `cameras` to `dir/<name>.png`.
pub fn render_frames(
    model: &splat::Gaussians,
    settings: &splat::RenderSettings,
    cameras: &[scenes::Camera],
    dir: &Path,
    device: &Device,
) -> Result<Vec<PathBuf>> {
    let named: Vec<(String, splat::Camera)> = cameras
        .iter()
        .map(|c| (c.name.clone(), splat_camera(c)))
        .collect();
    render_named(model, settings, &named, dir, device)
}

/// Renders each `(name, camera)` to `dir/<name>.png`.
pub fn render_named(
    model: &splat::Gaussians,
    settings: &splat::RenderSettings,
    cameras: &[(String, splat::Camera)],
    dir: &Path,
    device: &Device,
) -> Result<Vec<PathBuf>> {
    let mut written = Vec::with_capacity(cameras.len());
    // A few frames at a time: rendered together, then encoded in parallel.
    for chunk in cameras.chunks(8) {
        if base::interrupt::requested() {
            return Err(TrainError::Interrupted(format!(
                "rendering stopped after {} of {} frames; none was kept",
                written.len(),
                cameras.len()
            )));
        }
        let cams: Vec<splat::Camera> = chunk.iter().map(|(_, c)| c.clone()).collect();
        let frames = device.render_views(model, &cams, settings)?;
        let paths = chunk
            .par_iter()
            .zip(frames)
            .map(|((name, _), out)| {
                let path = dir.join(format!("{name}.png"));
                save_pixels(&path, &out.color, out.width, out.height)?;
                Ok(path)
            })
            .collect::<Result<Vec<_>>>()?;
        written.extend(paths);
    }
    Ok(written)
}

/// What the PSNR-vs-time picture draws: the held-out PSNR at each evaluation and, when the
/// capture has clean images, the aberrated input's PSNR as a flat line over the same time,
/// the level training must beat. Empty when nothing was evaluated.
pub fn log_series(log: &[LogRow], observed_psnr: Option<f64>) -> Vec<crate::output::plot::Series> {
    let points: Vec<(f64, f64)> = log
        .iter()
        .filter_map(|r| r.test_psnr.map(|p| (r.seconds, p)))
        .collect();
    let Some(&(last, _)) = points.last() else {
        return Vec::new();
    };
    let mut series = vec![crate::output::plot::Series {
        name: "held-out PSNR".into(),
        points,
    }];
    if let Some(p) = observed_psnr.filter(|p| p.is_finite()) {
        series.push(crate::output::plot::Series {
            name: "the aberrated input".into(),
            points: vec![(0.0, p), (last, p)],
        });
    }
    series
}

/// The PSNR-vs-time picture, when there are test PSNRs to plot.
pub fn plot_log(dir: &Path, log: &[LogRow], observed_psnr: Option<f64>) -> Result<()> {
    let series = log_series(log, observed_psnr);
    if series.is_empty() {
        return Ok(());
    }
    crate::output::plot::line_plot(
        &dir.join(PSNR_PLOT),
        "held-out PSNR vs training time",
        "training time (s)",
        "PSNR vs clean (dB)",
        &series,
    )?;
    Ok(())
}

/// Writes the picture of a PSF grid (its cells in log scale, channel by channel, with a
/// colour bar; the lens's wavelengths and field when known) to `path`.
pub fn write_psf_figure(
    path: &Path,
    grid: &aberration::PsfGrid,
    wavelengths_nm: Option<[f64; 3]>,
    max_field_deg: Option<f64>,
) -> Result<()> {
    let figure = plot::psf_figure(grid, wavelengths_nm, max_field_deg);
    aberration::image::save_rgb8_png(&figure, path)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(step: u64, seconds: f64, test: Option<f64>) -> LogRow {
        LogRow {
            step,
            seconds,
            loss: 0.1,
            train_psnr: 20.0,
            test_psnr: test,
            test_ssim: test.map(|_| 0.5),
            splats: 10,
            sh_degree: 0,
        }
    }

    #[test]
    fn the_plot_shows_the_inputs_psnr_as_a_line_over_the_run() {
        let log = [
            row(10, 1.5, Some(18.0)),
            row(15, 2.0, None),
            row(20, 3.0, Some(21.0)),
        ];
        let s = log_series(&log, Some(19.5));
        assert_eq!(s.len(), 2);
        assert_eq!(s[0].points, [(1.5, 18.0), (3.0, 21.0)]);
        assert_eq!(s[1].points, [(0.0, 19.5), (3.0, 19.5)]);
        // Without clean images (no input PSNR) or without evaluations: what there is.
        assert_eq!(log_series(&log, None).len(), 1);
        assert_eq!(log_series(&log, Some(f64::NAN)).len(), 1);
        assert!(log_series(&[row(5, 1.0, None)], Some(19.5)).is_empty());
    }
}
