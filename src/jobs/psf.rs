//! `psf simulate` and `psf show` as jobs: the metalens's PSF grid simulated from its phase
//! profile (every flag and both names checked before the propagation starts), and a grid file
//! drawn as a picture.

use aberration::PsfGrid;
use aberration::optics::{Dispersion, PhaseProfile, SimConfig, SimReport, simulate_grid};
use clap::{Args, ValueEnum};
use std::path::PathBuf;

use crate::error::{Result, TrainError};
use crate::output::guard;

#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum Profile {
    /// The optimised lens of Tseng et al. 2021 (the paper's).
    Neural,
    /// An ideal hyperbolic lens at --design-nm.
    Hyperbolic,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum DispersionArg {
    /// Tseng's meta-atom proxy.
    MetaAtom,
    /// Wrapped phase scaled by design/lambda.
    Scaled,
    /// No dispersion: the designed phase at every wavelength.
    None,
}

#[derive(Args, Clone, Debug)]
pub struct LensArgs {
    /// Grid side G.
    #[arg(long, default_value_t = 9, value_parser = clap::value_parser!(u64).range(1..=33))]
    pub grid: u64,
    /// PSF side K in pixels.
    #[arg(long, default_value_t = 135, value_parser = clap::value_parser!(u64).range(3..=1023))]
    pub size: u64,
    /// The lens's phase profile.
    #[arg(long, value_enum, default_value_t = Profile::Neural)]
    pub profile: Profile,
    /// How the phase changes with wavelength.
    #[arg(long, value_enum, default_value_t = DispersionArg::MetaAtom)]
    pub dispersion: DispersionArg,
    /// Design wavelength (nm) of the hyperbolic profile and of --dispersion scaled.
    #[arg(long, default_value_t = 452.0, value_parser = crate::settings::values::positive, allow_negative_numbers = true)]
    pub design_nm: f64,
    /// Lens aperture diameter (µm).
    #[arg(long, default_value_t = 500.0, value_parser = crate::settings::values::positive, allow_negative_numbers = true)]
    pub aperture_um: f64,
    /// Focal length (µm).
    #[arg(long, default_value_t = 1000.0, value_parser = crate::settings::values::positive, allow_negative_numbers = true)]
    pub focal_um: f64,
    /// Meta-atom pitch (µm), also the propagation sampling.
    #[arg(long, default_value_t = 0.35, value_parser = crate::settings::values::positive, allow_negative_numbers = true)]
    pub pitch_um: f64,
    /// Side of the angular-spectrum grid in samples.
    #[arg(long, default_value_t = 3000, value_parser = clap::value_parser!(u64).range(16..=8192))]
    pub fft_size: u64,
    /// Sensor pixel at the focal plane (µm): 5.86 µm behind a ×8.1 relay.
    #[arg(long, default_value_t = 5.86 / 8.1, value_parser = crate::settings::values::positive, allow_negative_numbers = true)]
    pub sensor_pitch_um: f64,
    /// Field angle at the grid corners (degrees).
    #[arg(long, default_value_t = 20.0, value_parser = crate::settings::values::field_angle, allow_negative_numbers = true)]
    pub max_field_deg: f64,
    /// Sub-samples per pixel side when integrating the focal plane.
    #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u64).range(1..=16))]
    pub supersample: u64,
    /// The lens design scaled to this many times its focal length at the same aperture (its
    /// phase scaled inversely, the sensor at the new focal plane): a lens that came out a
    /// little off.
    #[arg(long, default_value_t = 1.0, value_parser = crate::settings::values::positive, allow_negative_numbers = true)]
    pub focal_scale: f64,
    /// The sensor this far behind the focal plane (µm; negative: in front): defocus.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    pub sensor_offset_um: f64,
    /// Every PSF turned by this angle about its centre (degrees): a calibration rotated
    /// against the sensor.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    pub rotation_deg: f64,
}

impl LensArgs {
    pub fn config(&self) -> SimConfig {
        let mut cfg = SimConfig {
            grid: self.grid as usize,
            psf_size: self.size as usize,
            fft_size: self.fft_size as usize,
            sensor_pitch_um: self.sensor_pitch_um,
            max_field_deg: self.max_field_deg,
            supersample: self.supersample as usize,
            sensor_offset_um: self.sensor_offset_um,
            rotation_deg: self.rotation_deg,
            ..SimConfig::default()
        };
        cfg.lens.aperture_um = self.aperture_um;
        cfg.lens.focal_um = self.focal_um;
        cfg.lens.pitch_um = self.pitch_um;
        cfg.lens.profile = match self.profile {
            Profile::Neural => PhaseProfile::neural(),
            Profile::Hyperbolic => PhaseProfile::Hyperbolic {
                design_nm: self.design_nm,
            },
        };
        cfg.lens.dispersion = match self.dispersion {
            DispersionArg::MetaAtom => Dispersion::MetaAtom,
            DispersionArg::Scaled => Dispersion::ScaledWrapped {
                design_nm: self.design_nm,
            },
            DispersionArg::None => Dispersion::None,
        };
        cfg.lens = cfg.lens.with_focal_scale(self.focal_scale);
        cfg
    }
}

#[derive(Args, Clone, Debug)]
pub struct SimulateRequest {
    /// Output .npy (shape (G·G, K, K, 3), float32).
    #[arg(long)]
    pub out: PathBuf,
    /// Also draw the grid to this PNG.
    #[arg(long)]
    pub picture: Option<PathBuf>,
    #[command(flatten)]
    pub lens: LensArgs,
}

#[derive(Args, Clone, Debug)]
pub struct ShowRequest {
    /// PSF grid .npy.
    pub psf: PathBuf,
    /// Where the picture goes (PNG).
    #[arg(long)]
    pub out: PathBuf,
}

/// What `psf simulate` wrote.
#[derive(Clone, Debug)]
pub struct SimulateReport {
    pub out: PathBuf,
    pub picture: Option<PathBuf>,
    /// The propagation's figures: angles, power in the crop, peaks, seconds.
    pub sim: SimReport,
}

/// The lens flags checked: the simulation's own refusals name them.
fn check_lens(cfg: &SimConfig) -> Result<()> {
    cfg.validate().map_err(|e| {
        TrainError::from(e).context(
            "the lens flags (--grid, --size, --fft-size, --pitch-um, --sensor-pitch-um, --aperture-um, --focal-um, --focal-scale, --sensor-offset-um, --rotation-deg) do not make a simulation",
        )
    })
}

/// Simulates the grid `a` describes into `--out` (and its picture); `on_progress(done,
/// total)` follows the propagations. Every check comes before the propagation.
pub fn simulate(
    a: &SimulateRequest,
    on_progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<SimulateReport> {
    let cfg = a.lens.config();
    check_lens(&cfg)?;
    guard::refuse_unwritable_file("--out", &a.out)?;
    guard::refuse_other_extension(
        "--out",
        &a.out,
        "npy",
        "the grid is written as a NumPy array",
    )?;
    if let Some(p) = &a.picture {
        guard::refuse_unwritable_image("--picture", p)?;
        guard::refuse_overwrite("--picture", p, &[("--out", &a.out)])?;
    }
    let (grid, sim) = simulate_grid(&cfg, on_progress)
        .map_err(|e| TrainError::from(e).context("PSF simulation failed"))?;
    grid.save_npy(&a.out)?;
    if let Some(p) = &a.picture {
        crate::output::write_psf_figure(
            p,
            &grid,
            Some(cfg.wavelengths_nm),
            Some(cfg.max_field_deg),
        )?;
    }
    Ok(SimulateReport {
        out: a.out.clone(),
        picture: a.picture.clone(),
        sim,
    })
}

/// Draws the grid file `a.psf` into `a.out`; returns the grid's side and its PSFs' size.
pub fn show(a: &ShowRequest) -> Result<(usize, usize)> {
    guard::refuse_overwrite("--out", &a.out, &[("the PSF file", &a.psf)])?;
    guard::refuse_unwritable_image("--out", &a.out)?;
    let grid = PsfGrid::load_npy(&a.psf)?;
    crate::output::write_psf_figure(&a.out, &grid, None, None)?;
    Ok((grid.grid(), grid.size()))
}
