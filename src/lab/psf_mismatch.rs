//! `metasplat experiment psf-mismatch`: what a mis-calibrated PSF grid costs aware training,
//! and how much `--refine-psf` wins back.
//!
//! The capture is aberrated through the simulated lens; every run then trains believing
//! another grid, simulated with one error at a time (focal length, the calibration lasers'
//! wavelengths, sensor defocus, a rotated rig, measurement noise, a background pedestal).
//! Variants split where the loss comes from: `wrong` (the wrong grid for the blur of `L_abr`
//! and for `I_ac`), `blur-only` (wrong blur, true `I_ac`), `iac-only` (true blur, wrong
//! `I_ac`), `refined` (wrong for both, with `--refine-psf`).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use aberration::PsfGrid;
use aberration::optics::SimConfig;
use clap::Args;

use super::runs::{ExperimentPlace, ExperimentRuns};
use crate::error::{Result, TrainError};
use crate::output::RunSummary;
use crate::output::plot::{Series, line_plot};
use crate::train::config::Mode;

/// One calibration error.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum PsfError {
    /// The lens's focal length off by this many percent.
    Focal(f64),
    /// Calibrated at the laser lines 635/532/450 nm instead of the design's 606/511/462.
    Lasers,
    /// The sensor this many µm off the focal plane.
    Defocus(f64),
    /// The calibration rig turned by this many degrees.
    Rotate(f64),
    /// Measurement noise of this fraction of each PSF's peak.
    Noise(f32),
    /// A uniform background holding this fraction of each PSF's energy.
    Pedestal(f32),
}

/// The wavelengths (R, G, B, nm) of the paper's calibration lasers.
pub const LASER_NM: [f64; 3] = [635.0, 532.0, 450.0];

impl std::str::FromStr for PsfError {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        if s == "lasers" {
            return Ok(Self::Lasers);
        }
        let (kind, value) = s.split_once(':').ok_or_else(|| {
            format!("'{s}' is not a PSF error: focal:PERCENT, lasers, defocus:UM, rotate:DEG, noise:FRACTION or pedestal:FRACTION")
        })?;
        let v: f64 = value
            .parse()
            .ok()
            .filter(|v: &f64| v.is_finite())
            .ok_or_else(|| format!("'{value}' in '{s}' is not a number"))?;
        let e = match kind {
            "focal" if v.abs() < 50.0 && v != 0.0 => Self::Focal(v),
            "defocus" if v.abs() <= 100.0 && v != 0.0 => Self::Defocus(v),
            "rotate" if v.abs() <= 45.0 && v != 0.0 => Self::Rotate(v),
            "noise" if v > 0.0 && v <= 1.0 => Self::Noise(v as f32),
            "pedestal" if v > 0.0 && v < 1.0 => Self::Pedestal(v as f32),
            "focal" | "defocus" | "rotate" | "noise" | "pedestal" => {
                return Err(format!(
                    "'{s}': out of range (focal: a non-zero percent under 50; defocus: non-zero, at most 100 um; rotate: non-zero, at most 45 degrees; noise: in (0, 1]; pedestal: in (0, 1))"
                ));
            }
            other => {
                return Err(format!(
                    "'{other}' is not a kind of PSF error (focal, lasers, defocus, rotate, noise, pedestal)"
                ));
            }
        };
        Ok(e)
    }
}

/// As written on the command line (`focal:+3`), so that it parses back.
impl std::fmt::Display for PsfError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Focal(v) => write!(f, "focal:{v:+}"),
            Self::Lasers => write!(f, "lasers"),
            Self::Defocus(v) => write!(f, "defocus:{v:+}"),
            Self::Rotate(v) => write!(f, "rotate:{v}"),
            Self::Noise(v) => write!(f, "noise:{v}"),
            Self::Pedestal(v) => write!(f, "pedestal:{v}"),
        }
    }
}

impl PsfError {
    /// The error in file and folder names (`focal+3`).
    pub fn slug(&self) -> String {
        self.to_string().replace(':', "")
    }

    pub fn describe(&self) -> String {
        match self {
            Self::Focal(v) => format!("focal length {v:+} %"),
            Self::Lasers => "laser lines 635/532/450 nm".into(),
            Self::Defocus(v) => format!("sensor {v:+} um"),
            Self::Rotate(v) => format!("rotated {v} deg"),
            Self::Noise(v) => format!("noise {v} of peak"),
            Self::Pedestal(v) => format!("pedestal {v} of energy"),
        }
    }

    /// The grid a user with this error believes in, made from the true lens `cfg`.
    pub fn grid(&self, cfg: &SimConfig, truth: &PsfGrid, seed: u64) -> Result<PsfGrid> {
        let mut c = cfg.clone();
        match *self {
            Self::Focal(v) => c.lens = c.lens.with_focal_scale(1.0 + v / 100.0),
            Self::Lasers => c.wavelengths_nm = LASER_NM,
            Self::Defocus(v) => c.sensor_offset_um = v,
            Self::Rotate(v) => c.rotation_deg = v,
            Self::Noise(v) => return Ok(aberration::refine::measured(truth, v, 0.0, seed)?),
            Self::Pedestal(v) => return Ok(aberration::refine::measured(truth, 0.0, v, seed)?),
        }
        c.validate()
            .map_err(|e| TrainError::Invalid(format!("{self}: {e}")))?;
        Ok(aberration::optics::simulate_grid(&c, &|_, _| {})?.0)
    }

    /// The family it is plotted in, and its place on that plot's axis.
    fn family(&self) -> Option<(&'static str, &'static str, f64)> {
        match *self {
            Self::Focal(v) => Some(("focal", "focal-length error (%)", v)),
            Self::Defocus(v) => Some(("defocus", "sensor offset (um)", v)),
            Self::Rotate(v) => Some(("rotate", "rig rotation (degrees)", v)),
            _ => None,
        }
    }
}

/// How a run trains against the wrong grid.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Variant {
    /// The wrong grid for the blur of L_abr and for I_ac.
    Wrong,
    /// The wrong grid for the blur, the true one for I_ac.
    BlurOnly,
    /// The true grid for the blur, the wrong one for I_ac.
    IacOnly,
    /// The wrong grid for both, refined during training (--refine-psf).
    Refined,
}

impl std::fmt::Display for Variant {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Wrong => "wrong",
            Self::BlurOnly => "blur-only",
            Self::IacOnly => "iac-only",
            Self::Refined => "refined",
        })
    }
}

#[derive(Args)]
pub struct PsfMismatchArgs {
    #[command(flatten)]
    pub place: ExperimentPlace,
    /// Training steps of every run.
    #[arg(long, default_value_t = 1500, value_parser = clap::value_parser!(u64).range(1..=100_000_000))]
    pub iters: u64,
    /// Weight of L(render, I_ac) (default: as `train`).
    #[arg(long, value_parser = crate::settings::values::weight, allow_negative_numbers = true)]
    pub lambda: Option<f32>,
    /// The errors, one at a time: focal:PERCENT, lasers, defocus:UM, rotate:DEG,
    /// noise:FRACTION (of each PSF's peak), pedestal:FRACTION (of its energy).
    #[arg(long, value_delimiter = ',', allow_negative_numbers = true, default_values_t = [
        PsfError::Focal(-5.0), PsfError::Focal(-2.0), PsfError::Focal(-1.0),
        PsfError::Focal(1.0), PsfError::Focal(2.0), PsfError::Focal(3.0), PsfError::Focal(5.0),
        PsfError::Lasers,
        PsfError::Defocus(-5.0), PsfError::Defocus(-2.0), PsfError::Defocus(2.0), PsfError::Defocus(5.0),
        PsfError::Rotate(1.0), PsfError::Rotate(2.0),
        PsfError::Noise(0.02), PsfError::Pedestal(0.05),
    ])]
    pub errors: Vec<PsfError>,
    /// What each error trains.
    #[arg(long, value_enum, value_delimiter = ',', default_values_t = [Variant::Wrong, Variant::BlurOnly, Variant::IacOnly, Variant::Refined])]
    pub variants: Vec<Variant>,
    /// What the refined runs learn (as `train --refine-psf`).
    #[arg(long, value_enum, default_value_t = crate::train::psf_refine::PsfModel::Warp)]
    pub refine_model: crate::train::psf_refine::PsfModel,
}

/// What [`run`] wrote: the table (also in `psf_mismatch.md`) and each row's figures.
#[derive(Clone, Debug)]
pub struct PsfMismatchReport {
    /// The markdown table, as written to [`Self::table_path`].
    pub table: String,
    pub table_path: PathBuf,
    /// Aware and restored with the true grid.
    pub matched: Figures,
    pub restored: Figures,
    /// Per error (in the order asked), per variant (in the order asked).
    pub rows: Vec<Vec<Figures>>,
    /// Per error, the wrong grid's mean cell error to the truth at the images' scale.
    pub grid_errors: Vec<f64>,
}

/// One finished run's figures.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Figures {
    pub psnr: f64,
    pub ssim: f64,
    /// The refined grid's mean cell error to the truth (refined runs).
    pub refined_error: Option<f64>,
}

impl Figures {
    fn of(s: &RunSummary, refined_error: Option<f64>) -> Self {
        let (psnr, ssim) = s.psnr_ssim();
        Self {
            psnr,
            ssim,
            refined_error,
        }
    }
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

/// Runs the experiment `a` asks for: the aberrated copy and the grids (made once under
/// `--out`), every run, the table and the plots. `say` hears each stage as a sentence.
pub fn run(a: &PsfMismatchArgs, say: &mut dyn FnMut(String)) -> Result<PsfMismatchReport> {
    super::runs::refuse_repeats("--errors", &a.errors)?;
    super::runs::refuse_repeats("--variants", &a.variants)?;
    if a.place.psf.is_some()
        && let Some(e) = a
            .errors
            .iter()
            .find(|e| !matches!(e, PsfError::Noise(_) | PsfError::Pedestal(_)))
    {
        return Err(TrainError::Invalid(format!(
            "--errors {e}: with --psf given, only noise and pedestal errors can be made (the others simulate the paper's lens, not the grid given)"
        )));
    }
    let runs = ExperimentRuns {
        place: a.place.clone(),
        iters: a.iters,
        strategy: crate::settings::StrategyChoice::Auto,
        mask_mode: crate::settings::MaskChoice::Auto,
        coarse_to_fine: crate::settings::CoarseToFine::Auto,
        ceiling: false,
    };
    let (aberrated, _lock) = runs.aberrated(say)?;
    let true_path = a
        .place
        .psf
        .clone()
        .unwrap_or_else(|| a.place.out.join("psf.npy"));
    let truth = PsfGrid::load_npy(&true_path)?;
    let record = scenes::aberrated::AberrationRecord::read(&aberrated)?
        .ok_or_else(|| TrainError::file(&aberrated, "the aberrated copy has no aberration.json"))?;
    let (w, h) = (record.width as usize, record.height as usize);
    let truth_here = truth.for_image(w, h, record.sensor_px)?;
    let grids = a.place.out.join("psf");
    std::fs::create_dir_all(&grids).map_err(|e| TrainError::io(&grids, e))?;
    let cfg = SimConfig::default();
    let mut wrong_error = Vec::new();
    for e in &a.errors {
        let path = grids.join(format!("{}.npy", e.slug()));
        if !path.exists() {
            say(format!("simulating the grid with {}", e.describe()));
            e.grid(&cfg, &truth, a.place.seed)?.save_npy(&path)?;
        }
        let here = PsfGrid::load_npy(&path)?.for_image(w, h, record.sensor_px)?;
        wrong_error.push(mean(&aberration::refine::cell_errors(&here, &truth_here)?));
    }

    let eval_every = Some((a.iters / 10).max(1));
    let train = |dir: PathBuf,
                 mode: Mode,
                 assumed: Option<&Path>,
                 iac: Option<&Path>,
                 refine: bool|
     -> Result<RunSummary> {
        let mut args = runs.run(&aberrated, dir, mode);
        if mode == Mode::Aware {
            args.training.lambda = a.lambda;
        }
        args.training.eval_every = eval_every;
        args.training.refine_psf = refine.then_some(a.refine_model);
        args.data.assumed_psf = assumed.map(Path::to_path_buf);
        args.data.restorer_psf = iac.map(Path::to_path_buf);
        // The shipped network serves only the default grid: the runs that believe another
        // would get the Wiener stand-in and the matched one the network, and the table would
        // compare restorers, not grids.
        args.data.restorer = crate::settings::RestorerChoice::Wiener;
        args.spiral = 0;
        Ok(crate::run::train_quietly(&args)?.0)
    };
    let refined_error = |dir: &Path| -> Result<Option<f64>> {
        let path = dir.join(crate::output::PSF_REFINED_FILE);
        if !path.exists() {
            return Ok(None);
        }
        let refined = PsfGrid::load_npy(&path)?;
        Ok(Some(mean(&aberration::refine::cell_errors(
            &refined,
            &truth_here,
        )?)))
    };
    say("training aware with the true grid (matched)".into());
    let matched_dir = a.place.out.join("run_matched");
    let matched = Figures::of(
        &train(matched_dir.clone(), Mode::Aware, None, None, false)?,
        None,
    );
    say("training restored with the true grid".into());
    let restored = Figures::of(
        &train(
            a.place.out.join("run_restored"),
            Mode::Restored,
            None,
            None,
            false,
        )?,
        None,
    );
    let matched_refined = if a.variants.contains(&Variant::Refined) {
        say("training aware with the true grid, refined".into());
        let dir = a
            .place
            .out
            .join(format!("run_matched_refined-{}", a.refine_model));
        let s = train(dir.clone(), Mode::Aware, None, None, true)?;
        Some(Figures::of(&s, refined_error(&dir)?))
    } else {
        None
    };
    let mut results: Vec<Vec<Figures>> = Vec::new();
    for e in &a.errors {
        let wrong = grids.join(format!("{}.npy", e.slug()));
        let mut row = Vec::new();
        for v in &a.variants {
            say(format!("training {e} ({}), {v}", e.describe()));
            let dir = match v {
                Variant::Refined => {
                    a.place
                        .out
                        .join(format!("run_{}_refined-{}", e.slug(), a.refine_model))
                }
                _ => a.place.out.join(format!("run_{}_{v}", e.slug())),
            };
            let (assumed, iac) = match v {
                Variant::Wrong | Variant::Refined => (Some(wrong.as_path()), None),
                Variant::BlurOnly => (Some(wrong.as_path()), Some(true_path.as_path())),
                Variant::IacOnly => (None, Some(wrong.as_path())),
            };
            let s = train(
                dir.clone(),
                Mode::Aware,
                assumed,
                iac,
                *v == Variant::Refined,
            )?;
            let err = refined_error(&dir)?;
            if err.is_some() {
                let supplied = PsfGrid::load_npy(&wrong)?.for_image(w, h, record.sensor_px)?;
                let refined = PsfGrid::load_npy(&dir.join(crate::output::PSF_REFINED_FILE))?;
                aberration::image::save_rgb8_png(
                    &aberration::picture::psf_grids_picture(&[&supplied, &refined, &truth_here]),
                    &dir.join("psf_supplied_refined_true.png"),
                )?;
                let (before, after) = (
                    aberration::refine::cell_errors(&supplied, &truth_here)?,
                    aberration::refine::cell_errors(&refined, &truth_here)?,
                );
                let g = truth_here.grid();
                let mut csv = String::from("row,column,supplied_error,refined_error\n");
                for (i, (b, r)) in before.iter().zip(&after).enumerate() {
                    let _ = writeln!(csv, "{},{},{b:.6},{r:.6}", i / g, i % g);
                }
                let path = dir.join("psf_cell_errors.csv");
                base::write_bytes_atomically(&path, csv.as_bytes())
                    .map_err(|e| TrainError::io(&path, e))?;
            }
            row.push(Figures::of(&s, err));
        }
        results.push(row);
    }

    let mut table = String::new();
    let _ = writeln!(
        table,
        "Held-out PSNR (dB) / SSIM against the clean images, {} steps, {}x{} images ({} px PSFs), I_ac from the Wiener filter through the grid each run believes; refined runs learn the `{}` model. \"grid error\": mean over grid cells of the relative L2 distance to the true grid at the images' scale.\n",
        a.iters,
        w,
        h,
        truth_here.size(),
        a.refine_model
    );
    let _ = writeln!(
        table,
        "| | aware, true grid | restored, true grid |{}",
        matched_refined
            .as_ref()
            .map_or("", |_| " aware, true grid, refined |")
    );
    let _ = writeln!(
        table,
        "|---|---:|---:|{}",
        if matched_refined.is_some() {
            "---:|"
        } else {
            ""
        }
    );
    let _ = writeln!(
        table,
        "| PSNR / SSIM | {:.2} / {:.4} | {:.2} / {:.4} |{}",
        matched.psnr,
        matched.ssim,
        restored.psnr,
        restored.ssim,
        matched_refined.as_ref().map_or(String::new(), |m| format!(
            " {:.2} / {:.4} ({:+.2}; grid moved to {:.4} of the truth) |",
            m.psnr,
            m.ssim,
            m.psnr - matched.psnr,
            m.refined_error.unwrap_or(f64::NAN)
        ))
    );
    let _ = write!(table, "\n| error | grid error |");
    for v in &a.variants {
        let _ = write!(table, " {v} |");
    }
    if a.variants.contains(&Variant::Refined) {
        let _ = write!(table, " refined grid error | recovered |");
    }
    let _ = writeln!(table);
    let _ = writeln!(
        table,
        "|---|---:|{}",
        "---:|".repeat(
            a.variants.len()
                + if a.variants.contains(&Variant::Refined) {
                    2
                } else {
                    0
                }
        )
    );
    for ((e, row), grid_err) in a.errors.iter().zip(&results).zip(&wrong_error) {
        let _ = write!(table, "| {} | {grid_err:.4} |", e.describe());
        for f in row {
            let _ = write!(
                table,
                " {:.2} ({:+.2}) / {:.4} |",
                f.psnr,
                f.psnr - matched.psnr,
                f.ssim
            );
        }
        if let (Some(ri), Some(wi)) = (
            a.variants.iter().position(|v| *v == Variant::Refined),
            a.variants.iter().position(|v| *v == Variant::Wrong),
        ) {
            let lost = matched.psnr - row[wi].psnr;
            let won = row[ri].psnr - row[wi].psnr;
            let _ = write!(
                table,
                " {:.4} | {} |",
                row[ri].refined_error.unwrap_or(f64::NAN),
                if lost > 0.1 {
                    format!("{:.0} %", 100.0 * won / lost)
                } else {
                    "(no loss)".into()
                }
            );
        } else if let Some(ri) = a.variants.iter().position(|v| *v == Variant::Refined) {
            let _ = write!(
                table,
                " {:.4} | |",
                row[ri].refined_error.unwrap_or(f64::NAN)
            );
        }
        let _ = writeln!(table);
    }
    let table_path = a.place.out.join("psf_mismatch.md");
    base::write_bytes_atomically(&table_path, table.as_bytes())
        .map_err(|e| TrainError::io(&table_path, e))?;
    let mut families: Vec<(&str, &str)> = Vec::new();
    for e in &a.errors {
        if let Some((f, axis, _)) = e.family()
            && !families.iter().any(|(g, _)| *g == f)
        {
            families.push((f, axis));
        }
    }
    for (family, axis) in families {
        let points = |k: usize| -> Vec<(f64, f64)> {
            let mut p: Vec<(f64, f64)> = a
                .errors
                .iter()
                .zip(&results)
                .filter_map(|(e, row)| {
                    e.family()
                        .filter(|(f, _, _)| *f == family)
                        .map(|(_, _, x)| (x, row[k].psnr))
                })
                .chain(std::iter::once((0.0, matched.psnr)))
                .collect();
            p.sort_by(|a, b| a.0.total_cmp(&b.0));
            p
        };
        let series: Vec<Series> = a
            .variants
            .iter()
            .enumerate()
            .map(|(k, v)| Series {
                name: v.to_string(),
                points: points(k),
            })
            .chain(std::iter::once(Series {
                name: "restored, true grid".into(),
                points: {
                    let xs: Vec<f64> = points(0).iter().map(|p| p.0).collect();
                    vec![
                        (xs.first().copied().unwrap_or(0.0), restored.psnr),
                        (xs.last().copied().unwrap_or(0.0), restored.psnr),
                    ]
                },
            }))
            .collect();
        line_plot(
            &a.place.out.join(format!("psf_mismatch_{family}.png")),
            &format!("aware training with a wrong PSF grid: {family}"),
            axis,
            "held-out PSNR vs clean (dB)",
            &series,
        )?;
    }
    Ok(PsfMismatchReport {
        table,
        table_path,
        matched,
        restored,
        rows: results,
        grid_errors: wrong_error,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn errors_parse_back_from_what_they_print_and_bad_ones_say_why() {
        for e in [
            PsfError::Focal(-5.0),
            PsfError::Focal(2.5),
            PsfError::Lasers,
            PsfError::Defocus(-2.0),
            PsfError::Rotate(1.5),
            PsfError::Noise(0.02),
            PsfError::Pedestal(0.05),
        ] {
            assert_eq!(e.to_string().parse::<PsfError>(), Ok(e), "{e}");
            assert!(!e.slug().contains(':'));
        }
        for (bad, says) in [
            ("focal", "not a PSF error"),
            ("focal:0", "out of range"),
            ("focal:x", "not a number"),
            ("defocus:inf", "not a number"),
            ("noise:2", "out of range"),
            ("pedestal:1", "out of range"),
            ("tilt:1", "not a kind"),
        ] {
            let err = bad.parse::<PsfError>().unwrap_err();
            assert!(err.contains(says), "{bad}: {err}");
        }
    }
}
