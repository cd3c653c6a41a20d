//! `metasplat psf simulate|show`.

use super::progress;
use aberration::PsfGrid;
use aberration::optics::{Dispersion, PhaseProfile, SimConfig, SimReport, simulate_grid};
use anyhow::{Context, Result};
use clap::{Args, Subcommand, ValueEnum};
use std::path::PathBuf;

#[derive(Subcommand)]
pub enum PsfCommand {
    /// Simulate the G×G PSF grid from the metalens phase profile and write it as .npy.
    Simulate(SimulateArgs),
    /// Draw a PSF grid file as a picture (log scale, one panel per channel).
    Show(ShowArgs),
}

#[derive(Clone, Copy, ValueEnum)]
pub enum Profile {
    /// The optimised lens of Tseng et al. 2021 (the paper's).
    Neural,
    /// An ideal hyperbolic lens at --design-nm.
    Hyperbolic,
}

#[derive(Clone, Copy, ValueEnum)]
pub enum DispersionArg {
    /// Tseng's meta-atom proxy.
    MetaAtom,
    /// Wrapped phase scaled by design/lambda.
    Scaled,
    /// No dispersion: the designed phase at every wavelength.
    None,
}

#[derive(Args, Clone)]
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
    #[arg(long, default_value_t = 452.0, value_parser = metasplat::settings::values::positive, allow_negative_numbers = true)]
    pub design_nm: f64,
    /// Lens aperture diameter (µm).
    #[arg(long, default_value_t = 500.0, value_parser = metasplat::settings::values::positive, allow_negative_numbers = true)]
    pub aperture_um: f64,
    /// Focal length (µm).
    #[arg(long, default_value_t = 1000.0, value_parser = metasplat::settings::values::positive, allow_negative_numbers = true)]
    pub focal_um: f64,
    /// Meta-atom pitch (µm), also the propagation sampling.
    #[arg(long, default_value_t = 0.35, value_parser = metasplat::settings::values::positive, allow_negative_numbers = true)]
    pub pitch_um: f64,
    /// Side of the angular-spectrum grid in samples.
    #[arg(long, default_value_t = 3000, value_parser = clap::value_parser!(u64).range(16..=8192))]
    pub fft_size: u64,
    /// Sensor pixel at the focal plane (µm): 5.86 µm behind a ×8.1 relay.
    #[arg(long, default_value_t = 5.86 / 8.1, value_parser = metasplat::settings::values::positive, allow_negative_numbers = true)]
    pub sensor_pitch_um: f64,
    /// Field angle at the grid corners (degrees).
    #[arg(long, default_value_t = 20.0, value_parser = metasplat::settings::values::field_angle, allow_negative_numbers = true)]
    pub max_field_deg: f64,
    /// Sub-samples per pixel side when integrating the focal plane.
    #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u64).range(1..=16))]
    pub supersample: u64,
    /// The lens design scaled to this many times its focal length at the same aperture (its
    /// phase scaled inversely, the sensor at the new focal plane): a lens that came out a
    /// little off.
    #[arg(long, default_value_t = 1.0, value_parser = metasplat::settings::values::positive, allow_negative_numbers = true)]
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

#[derive(Args)]
pub struct SimulateArgs {
    /// Output .npy (shape (G·G, K, K, 3), float32).
    #[arg(long)]
    pub out: PathBuf,
    /// Also draw the grid to this PNG.
    #[arg(long)]
    pub picture: Option<PathBuf>,
    #[command(flatten)]
    pub lens: LensArgs,
}

#[derive(Args)]
pub struct ShowArgs {
    /// PSF grid .npy.
    pub psf: PathBuf,
    /// Where the picture goes (PNG).
    #[arg(long)]
    pub out: PathBuf,
}

pub fn run(cmd: PsfCommand) -> Result<()> {
    match cmd {
        PsfCommand::Simulate(a) => {
            // The lens flags first: the simulation's own refusals name them.
            check_lens(&a.lens.config())?;
            metasplat::output::guard::refuse_unwritable_file("--out", &a.out)?;
            metasplat::output::guard::refuse_other_extension(
                "--out",
                &a.out,
                "npy",
                "the grid is written as a NumPy array",
            )?;
            if let Some(p) = &a.picture {
                metasplat::output::guard::refuse_unwritable_image("--picture", p)?;
                metasplat::output::guard::refuse_overwrite("--picture", p, &[("--out", &a.out)])?;
            }
            let cfg = a.lens.config();
            let (grid, report) = simulate(&cfg)?;
            grid.save_npy(&a.out)?;
            println!("wrote {}", a.out.display());
            if let Some(p) = a.picture {
                metasplat::output::write_psf_figure(
                    &p,
                    &grid,
                    Some(cfg.wavelengths_nm),
                    Some(cfg.max_field_deg),
                )?;
                println!("wrote {}", p.display());
            }
            print_report(&report);
            Ok(())
        }
        PsfCommand::Show(a) => {
            metasplat::output::guard::refuse_overwrite(
                "--out",
                &a.out,
                &[("the PSF file", &a.psf)],
            )?;
            metasplat::output::guard::refuse_unwritable_image("--out", &a.out)?;
            let grid = PsfGrid::load_npy(&a.psf)?;
            metasplat::output::write_psf_figure(&a.out, &grid, None, None)?;
            println!(
                "{}: {}x{} grid of {} px RGB PSFs; wrote {}",
                a.psf.display(),
                grid.grid(),
                grid.grid(),
                grid.size(),
                a.out.display()
            );
            Ok(())
        }
    }
}

fn check_lens(cfg: &SimConfig) -> Result<()> {
    cfg.validate().context(
        "the lens flags (--grid, --size, --fft-size, --pitch-um, --sensor-pitch-um, --aperture-um, --focal-um, --focal-scale, --sensor-offset-um, --rotation-deg) do not make a simulation",
    )
}

/// Simulates with a progress bar over the propagations.
pub fn simulate(cfg: &SimConfig) -> Result<(PsfGrid, SimReport)> {
    check_lens(cfg)?;
    let pb = progress::bar(0, "propagating");
    let out = simulate_grid(cfg, &|done, total| {
        pb.set_length(total as u64);
        pb.set_position(done as u64);
    })
    .context("PSF simulation failed")?;
    pb.finish_and_clear();
    Ok(out)
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
