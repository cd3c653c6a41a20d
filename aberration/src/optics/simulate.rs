//! The G×G PSF grid of the paper, simulated from the lens.
//!
//! Grid point (row i, column j) sits at normalised image position
//! `u = (2j − G + 1)/(G − 1)`, `v = (2i − G + 1)/(G − 1)` (x right, y down), and sees the
//! field angle `θ` with `tan θ = tan θ_max · √(u² + v²)/√2`: image height is proportional to
//! `tan θ` and the corners are at `θ_max`. The lens is rotationally symmetric, so each
//! distinct radius is propagated once per wavelength (tilt along +x) and every grid point
//! samples that intensity rotated to its azimuth.

use super::phase::Lens;
use super::propagate::{FocalWindow, Propagator};
use super::sensor::sample_psf;
use crate::error::{AberrationError, Result};
use crate::psf_grid::PsfGrid;
use rayon::prelude::*;
use std::collections::BTreeMap;

/// `x` for a message: plainly when of ordinary size, else in scientific notation.
fn num(x: f64) -> String {
    if x == 0.0 || (1e-3..1e7).contains(&x.abs()) {
        format!("{}", (x * 1e4).round() / 1e4)
    } else {
        format!("{x:.3e}")
    }
}

/// Most memory a simulation may hold at once, far above what the paper's grid needs.
pub const MAX_WORKING_BYTES: u64 = 4 << 30;

#[derive(Clone, Debug, PartialEq)]
pub struct SimConfig {
    pub lens: Lens,
    /// R, G, B wavelengths (nm).
    pub wavelengths_nm: [f64; 3],
    /// Side of the propagation grid (samples of the meta-atom pitch); zero padding beyond
    /// the aperture.
    pub fft_size: usize,
    /// Sensor pixel pitch referred to the focal plane (µm).
    pub sensor_pitch_um: f64,
    /// PSF side K (px).
    pub psf_size: usize,
    /// Grid side G.
    pub grid: usize,
    /// Field angle at the grid corners (degrees).
    pub max_field_deg: f64,
    /// Sub-samples per pixel side when integrating the focal-plane intensity.
    pub supersample: usize,
    /// How far behind the focal plane the sensor sits (µm; negative: in front): the defocus
    /// of a sensor set a little off.
    pub sensor_offset_um: f64,
    /// Every PSF turned by this angle about its centre (degrees, clockwise on the image): a
    /// calibration rig rotated against the sensor.
    pub rotation_deg: f64,
}

impl Default for SimConfig {
    /// The paper's setting: 606/511/462 nm, 5.86 µm pixels behind a ×8.1 relay (0.7235 µm
    /// at the focal plane), 135-px PSFs on a 9×9 grid for a 1215-px sensor, corners at 20°.
    fn default() -> Self {
        Self {
            lens: Lens::default(),
            wavelengths_nm: [606.0, 511.0, 462.0],
            fft_size: 3000,
            sensor_pitch_um: 5.86 / 8.1,
            psf_size: 135,
            grid: 9,
            max_field_deg: 20.0,
            supersample: 4,
            sensor_offset_um: 0.0,
            rotation_deg: 0.0,
        }
    }
}

/// A grid point's place in the field.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FieldPoint {
    /// Integer radial key `(2j−G+1)² + (2i−G+1)²`, equal for points of equal radius.
    pub key: usize,
    pub theta: f64,
    pub azimuth: f64,
}

impl SimConfig {
    /// The paper's lens scaled down five times at the same f-number (100 µm aperture,
    /// f = 200 µm, 700² propagation grid) on a 3×3 grid of `psf_size` px reaching 10°: a
    /// whole grid in well under a second, for tests and the quick demo.
    pub fn small(psf_size: usize) -> Self {
        let mut cfg = Self::default();
        cfg.lens.aperture_um = 100.0;
        cfg.lens.focal_um = 200.0;
        cfg.fft_size = 700;
        cfg.grid = 3;
        cfg.psf_size = psf_size;
        cfg.max_field_deg = 10.0;
        cfg
    }

    pub fn validate(&self) -> Result<()> {
        let bad = |m: String| Err(AberrationError::BadParameter(m));
        let l = &self.lens;
        if !(l.aperture_um > 0.0 && l.focal_um > 0.0 && l.pitch_um > 0.0) {
            return bad("aperture, focal length and pitch must be positive".into());
        }
        if self.fft_size < 16 || (self.fft_size as f64) * l.pitch_um < l.aperture_um {
            return bad(format!(
                "propagation grid of {} samples x {} um does not hold the {} um aperture",
                self.fft_size, l.pitch_um, l.aperture_um
            ));
        }
        if self.psf_size == 0 || self.grid == 0 || self.sensor_pitch_um <= 0.0 {
            return bad("PSF size, grid and sensor pitch must be positive".into());
        }
        if !(0.0..90.0).contains(&self.max_field_deg) {
            return bad(format!(
                "max field angle {} must be in [0, 90)",
                self.max_field_deg
            ));
        }
        if !self.rotation_deg.is_finite()
            || !self.sensor_offset_um.is_finite()
            || self.sensor_um() <= 0.0
        {
            return bad(format!(
                "a sensor {} um off a {} um focal length, turned {} degrees, is not a sensor position",
                num(self.sensor_offset_um),
                num(l.focal_um),
                num(self.rotation_deg)
            ));
        }
        if self
            .wavelengths_nm
            .iter()
            .any(|w| !w.is_finite() || *w <= 0.0)
        {
            return bad("wavelengths must be positive".into());
        }
        if l.aperture_um < 2.0 * l.pitch_um || !l.focal_um.is_finite() {
            return bad(format!(
                "an aperture of {} um spans fewer than two {} um meta-atoms: no lens to simulate",
                num(l.aperture_um),
                num(l.pitch_um)
            ));
        }
        // Optics each in range can still describe no imaging system: a focal length shorter
        // than the light's wavelength, a diffraction-limited spot wider than the PSF crop (the
        // crop would hold almost none of the light), or sensor pixels so fine that the whole
        // crop falls between two samples of the focal plane (a flat PSF).
        let longest_um = self.wavelengths_nm.iter().cloned().fold(0.0, f64::max) / 1000.0;
        if l.focal_um < longest_um {
            return bad(format!(
                "a focal length of {} um is shorter than the {} um wavelength: no lens focuses there",
                num(l.focal_um),
                num(longest_um)
            ));
        }
        let airy_px = 2.44 * longest_um * l.focal_um / l.aperture_um / self.sensor_pitch_um;
        if airy_px.is_nan() || airy_px > self.psf_size as f64 {
            return bad(format!(
                "a {} um focal length behind a {} um aperture focuses {} um light to a {} px spot at best (the diffraction limit), wider than the {} px PSF: lower the focal length or the sensor pitch, or raise the aperture or the PSF size",
                num(l.focal_um),
                num(l.aperture_um),
                num(longest_um),
                num(airy_px),
                self.psf_size
            ));
        }
        if self.psf_size as f64 * self.sensor_pitch_um < 2.0 * l.pitch_um {
            return bad(format!(
                "a {} px PSF at {} um sensor pixels spans {} um, less than two {} um samples of the focal plane: the PSF would be flat; raise the sensor pitch or the PSF size",
                self.psf_size,
                num(self.sensor_pitch_um),
                num(self.psf_size as f64 * self.sensor_pitch_um),
                num(l.pitch_um)
            ));
        }
        // The flags are checked together, not one by one: each may be in range while their
        // product is not (a huge sensor pitch or PSF needs a focal window wider than the
        // propagation grid; a fine grid of big PSFs makes a file no reader accepts).
        let reach = self.window_reach();
        if !(reach.is_finite() && 2.0 * reach + 5.0 <= self.fft_size as f64) {
            return bad(format!(
                "a {} px PSF at {} um sensor pixels spans {} samples of the focal plane, more than the {}-sample propagation grid: lower the PSF size or the sensor pitch, or raise the FFT size",
                self.psf_size,
                num(self.sensor_pitch_um),
                num(2.0 * reach),
                self.fft_size
            ));
        }
        let file = base::limits::checked_bytes(
            &[
                self.grid as u64,
                self.grid as u64,
                self.psf_size as u64,
                self.psf_size as u64,
                3,
            ],
            4,
        );
        if file.is_none_or(|b| b > base::limits::MAX_NPY_BYTES) {
            return bad(format!(
                "a {g}x{g} grid of {k} px PSFs is {} MiB, more than the {} a PSF file may hold",
                file.map_or(u64::MAX, |b| b >> 20),
                base::limits::describe_bytes(base::limits::MAX_NPY_BYTES),
                g = self.grid,
                k = self.psf_size
            ));
        }
        let work = self.working_bytes();
        if work > MAX_WORKING_BYTES {
            return bad(format!(
                "the simulation would hold {} MiB of focal-plane fields, more than {}: lower the grid, the PSF size or the FFT size",
                work >> 20,
                base::limits::describe_bytes(MAX_WORKING_BYTES)
            ));
        }
        Ok(())
    }

    /// Distance from the lens to the sensor (µm).
    pub fn sensor_um(&self) -> f64 {
        self.lens.focal_um + self.sensor_offset_um
    }

    /// Half-width, in propagation samples, of the focal window a rotated PSF needs (with a
    /// bilinear margin); f64 so that absurd flags give infinity instead of a wrapped index.
    fn window_reach(&self) -> f64 {
        (self.psf_size as f64 / 2.0 + 1.0) * self.sensor_pitch_um * 2f64.sqrt() / self.lens.pitch_um
            + 2.0
    }

    /// Peak memory of [`simulate_grid`]: a propagation grid (spectrum and transfer function),
    /// its window rows, and a focal window per distinct field radius and channel.
    fn working_bytes(&self) -> u64 {
        let n = self.fft_size as u64;
        let side = 2 * self.window_half() as u64 + 1;
        let g = self.grid;
        let radii = (0..g * g)
            .map(|gi| self.field_point(gi / g, gi % g).key)
            .collect::<std::collections::BTreeSet<_>>()
            .len() as u64;
        2 * n * n * 16 + side * n * 16 + radii * 3 * side * side * 8
    }

    pub fn field_point(&self, i: usize, j: usize) -> FieldPoint {
        let g = self.grid as isize;
        let (du, dv) = (2 * j as isize - g + 1, 2 * i as isize - g + 1);
        let key = (du * du + dv * dv) as usize;
        let r = if g > 1 {
            (key as f64).sqrt() / ((g - 1) as f64 * 2f64.sqrt())
        } else {
            0.0
        };
        let theta = (self.max_field_deg.to_radians().tan() * r).atan();
        FieldPoint {
            key,
            theta,
            azimuth: (dv as f64).atan2(du as f64),
        }
    }

    /// Half-size of the focal window that covers a rotated PSF with bilinear margin.
    fn window_half(&self) -> usize {
        // Bounded by the propagation grid once validated.
        self.window_reach().ceil() as usize
    }
}

/// What the simulation measured, per distinct field angle and channel.
#[derive(Clone, Debug)]
pub struct SimReport {
    pub angles_deg: Vec<f64>,
    /// Share of the incident power inside the PSF crop, `[angle][channel]`.
    pub crop_power: Vec<[f64; 3]>,
    /// Power reaching the focal plane (≈1 less the evanescent part).
    pub focal_power: Vec<[f64; 3]>,
    /// Peak of the unit-sum PSF on the +x axis at each angle.
    pub peak: Vec<[f64; 3]>,
    pub seconds: f64,
}

/// Simulates the PSF grid. `progress(done, total)` is called after each propagation.
pub fn simulate_grid(
    cfg: &SimConfig,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<(PsfGrid, SimReport)> {
    cfg.validate()?;
    let start = std::time::Instant::now();
    let g = cfg.grid;
    let points: Vec<FieldPoint> = (0..g * g)
        .map(|gi| cfg.field_point(gi / g, gi % g))
        .collect();
    let mut radial: BTreeMap<usize, f64> = BTreeMap::new();
    for p in &points {
        radial.insert(p.key, p.theta);
    }
    let radial: Vec<(usize, f64)> = radial.into_iter().collect();
    let prop = Propagator::new(cfg.fft_size, cfg.lens.pitch_um);
    let half = cfg.window_half();
    let total = radial.len() * 3;
    let mut windows: Vec<[Option<FocalWindow>; 3]> =
        radial.iter().map(|_| [None, None, None]).collect();
    let mut done = 0;
    for (ch, &lambda) in cfg.wavelengths_nm.iter().enumerate() {
        let transfer = prop.transfer(lambda, cfg.sensor_um());
        for (ri, &(_, theta)) in radial.iter().enumerate() {
            let spot = cfg.sensor_um() * theta.tan();
            windows[ri][ch] =
                Some(prop.focal_window(&cfg.lens, lambda, theta, &transfer, spot, half));
            done += 1;
            progress(done, total);
        }
    }
    let windows: Vec<[FocalWindow; 3]> = windows
        .into_iter()
        .map(|w| w.map(|o| o.expect("every window was simulated")))
        .collect();
    let index_of: BTreeMap<usize, usize> = radial
        .iter()
        .enumerate()
        .map(|(i, (k, _))| (*k, i))
        .collect();
    let k = cfg.psf_size;
    let kernels: Vec<Vec<f64>> = (0..g * g * 3)
        .into_par_iter()
        .map(|idx| {
            let (gi, ch) = (idx / 3, idx % 3);
            let p = points[gi];
            let w = &windows[index_of[&p.key]][ch];
            let spot = cfg.sensor_um() * p.theta.tan();
            let azimuth = p.azimuth + cfg.rotation_deg.to_radians();
            sample_psf(w, spot, k, cfg.sensor_pitch_um, azimuth, cfg.supersample)
        })
        .collect();
    let mut report = SimReport {
        angles_deg: radial.iter().map(|(_, t)| t.to_degrees()).collect(),
        crop_power: vec![[0.0; 3]; radial.len()],
        focal_power: vec![[0.0; 3]; radial.len()],
        peak: vec![[0.0; 3]; radial.len()],
        seconds: 0.0,
    };
    for (ri, ws) in windows.iter().enumerate() {
        let spot = cfg.sensor_um() * radial[ri].1.tan();
        for (ch, w) in ws.iter().enumerate() {
            let psf = sample_psf(w, spot, k, cfg.sensor_pitch_um, 0.0, cfg.supersample);
            let sum: f64 = psf.iter().sum();
            report.crop_power[ri][ch] = sum;
            report.focal_power[ri][ch] = w.total_power;
            report.peak[ri][ch] =
                psf.iter().cloned().fold(0.0, f64::max) / sum.max(f64::MIN_POSITIVE);
        }
    }
    let data: Vec<f32> = kernels.into_iter().flatten().map(|v| v as f32).collect();
    let grid = PsfGrid::from_planar(g, k, data).map_err(|e| {
        AberrationError::BadParameter(format!(
            "the simulated PSFs are unusable ({e}): is the crop too small?"
        ))
    })?;
    report.seconds = start.elapsed().as_secs_f64();
    Ok((grid, report))
}
