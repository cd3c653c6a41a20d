//! Training pairs over a family of metalenses: each pair through a lens drawn about the
//! paper's, at a PSF scale drawn over the range the network should serve, with its own noise
//! level and an augmented photo, so that one network serves every capture of the family.
//!
//! Simulating a lens is the expensive part (a whole grid of propagations), so a run simulates
//! a bank of lenses once ([`LensFamily::lens`], cached by the caller) and every pair draws one
//! of them; the scale, noise and augmentation are drawn per pair.

use crate::coverage::{Envelope, Family};
use crate::error::Result;
use aberration::optics::{SimConfig, simulate_grid};
use aberration::{Image, NoiseModel, PsfGrid};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// How lenses, blur scales and sensor noise are drawn about the paper's setting.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LensFamily {
    /// Focal length within ± this many per cent of the paper's.
    pub focal_percent: f64,
    /// Sensor within ± this many µm of the focal plane (defocus).
    pub sensor_offset_um: f64,
    /// Each colour's wavelength within ± this many nm of the paper's 606/511/462 nm.
    pub wavelength_nm: f64,
    /// The calibration rig turned within ± this many degrees.
    pub rotation_deg: f64,
    /// A measured grid's defects ([`aberration::refine::measured`]): noise up to this share
    /// of each kernel's peak, and a uniform pedestal up to this share of its energy.
    pub psf_noise: f32,
    pub pedestal: f32,
    /// PSF side at the photo's size (px), drawn as `psf_px_draw` says.
    pub psf_px: [usize; 2],
    /// How the PSF side is drawn over `psf_px`. Read as log-uniform from headers written
    /// before the field.
    #[serde(default)]
    pub psf_px_draw: ScaleDraw,
    /// Sensor noise as a multiple of the paper's, drawn log-uniform.
    pub noise_scale: [f32; 2],
}

impl Default for LensFamily {
    /// The family of issue 51: focal ±5 %, sensor ±5 µm, wavelengths ±15 nm, rotation ±3°,
    /// PSF noise up to 1 % of the peak and a pedestal up to 1 % of the energy, 15–140 px PSFs,
    /// noise ×0.5–2.
    fn default() -> Self {
        Self {
            focal_percent: 5.0,
            sensor_offset_um: 5.0,
            wavelength_nm: 15.0,
            rotation_deg: 3.0,
            psf_noise: 0.01,
            pedestal: 0.01,
            psf_px: [15, 140],
            psf_px_draw: ScaleDraw::LogUniform,
            noise_scale: [0.5, 2.0],
        }
    }
}

/// How a pair's PSF side is drawn over the family's range.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum ScaleDraw {
    /// Each doubling of the side equally often: over 15–140 px, half the pairs below 46 px.
    #[default]
    #[value(name = "log")]
    // Recorded as the flag names it; the first headers with the field wrote `log-uniform`.
    #[serde(rename = "log", alias = "log-uniform")]
    LogUniform,
    /// Each pixel of side equally often: over 15–140 px, 44 % of the pairs above 85 px
    /// (22 % log-uniform), for weights that must gain where the blur is widest.
    #[value(name = "linear")]
    Linear,
}

/// One lens of a family: the simulator's settings and the measurement defects.
#[derive(Clone, Debug, PartialEq)]
pub struct DrawnLens {
    pub sim: SimConfig,
    pub psf_noise: f32,
    pub pedestal: f32,
    pub seed: u64,
}

/// Uniform in `[-1, 1]`.
fn sym(rng: &mut ChaCha8Rng) -> f64 {
    rng.random::<f64>() * 2.0 - 1.0
}

/// Log-uniform in `[lo, hi]`.
fn log_uniform(rng: &mut ChaCha8Rng, lo: f64, hi: f64) -> f64 {
    (lo.ln() + rng.random::<f64>() * (hi.ln() - lo.ln())).exp()
}

impl LensFamily {
    /// Refuses ranges that describe no lens (negative spreads, an empty or zero scale range).
    pub fn validate(&self) -> std::result::Result<(), String> {
        let spreads = [
            self.focal_percent,
            self.sensor_offset_um,
            self.wavelength_nm,
            self.rotation_deg,
            self.psf_noise as f64,
            self.pedestal as f64,
        ];
        if spreads.iter().any(|v| !v.is_finite() || *v < 0.0) || self.focal_percent >= 50.0 {
            return Err(format!(
                "family spreads must be finite and non-negative: {self:?}"
            ));
        }
        if self.pedestal >= 1.0 {
            return Err(format!("a pedestal of {} leaves no PSF", self.pedestal));
        }
        let [lo, hi] = self.psf_px;
        if lo == 0 || lo > hi || hi > aberration::resample::MAX_MAPPED_PSF_PX {
            return Err(format!("PSF scales {lo}-{hi} px"));
        }
        let [a, b] = self.noise_scale;
        if !(a.is_finite() && b.is_finite() && a >= 0.0 && a <= b) {
            return Err(format!("noise scales {a}-{b}"));
        }
        Ok(())
    }

    /// Lens `index` of the family drawn about `base` (lens 0 is `base` itself, without
    /// defects: the family's centre is always in it). The same index always draws the same
    /// lens.
    pub fn lens(&self, base: &SimConfig, index: usize, seed: u64) -> DrawnLens {
        let seed = seed ^ base::mix64(index as u64 ^ 0x4C45_4E53);
        if index == 0 {
            return DrawnLens {
                sim: base.clone(),
                psf_noise: 0.0,
                pedestal: 0.0,
                seed,
            };
        }
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut sim = base.clone();
        sim.lens = sim
            .lens
            .with_focal_scale(1.0 + self.focal_percent / 100.0 * sym(&mut rng));
        sim.sensor_offset_um = base.sensor_offset_um + self.sensor_offset_um * sym(&mut rng);
        for w in &mut sim.wavelengths_nm {
            *w += self.wavelength_nm * sym(&mut rng);
        }
        sim.rotation_deg = base.rotation_deg + self.rotation_deg * sym(&mut rng);
        DrawnLens {
            sim,
            psf_noise: self.psf_noise * rng.random::<f32>(),
            pedestal: self.pedestal * rng.random::<f32>(),
            seed,
        }
    }

    /// The record a weights header keeps of the family and the lenses' envelope.
    pub fn record(&self, lenses: &[PsfGrid]) -> Option<Family> {
        Some(Family {
            drawn: serde_json::to_value(self).ok()?,
            envelope: Envelope::of(lenses)?,
        })
    }

    /// What one pair draws: its lens (an index into the bank), PSF side, noise and
    /// augmentation.
    pub fn pair(&self, lenses: usize, seed: u64) -> PairDraw {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let [lo, hi] = self.psf_px;
        let psf_px = match self.psf_px_draw {
            ScaleDraw::LogUniform => log_uniform(&mut rng, lo as f64, hi as f64),
            ScaleDraw::Linear => lo as f64 + rng.random::<f64>() * (hi - lo) as f64,
        }
        .round() as usize;
        let [a, b] = self.noise_scale;
        let noise = if a > 0.0 {
            log_uniform(&mut rng, a as f64, b as f64) as f32
        } else {
            a + (b - a) * rng.random::<f32>()
        };
        PairDraw {
            lens: rng.random_range(0..lenses.max(1)),
            psf_px: psf_px.clamp(lo, hi),
            noise_scale: noise,
            flip: rng.random(),
            quarter_turns: rng.random_range(0..4),
            gains: std::array::from_fn(|_| 0.9 + 0.2 * rng.random::<f32>()),
            seed: rng.random(),
        }
    }
}

impl DrawnLens {
    /// The lens's grid, as a measurement of it would give it.
    pub fn simulate(&self) -> Result<PsfGrid> {
        let (grid, _) = simulate_grid(&self.sim, &|_, _| {})?;
        if self.psf_noise == 0.0 && self.pedestal == 0.0 {
            return Ok(grid);
        }
        Ok(aberration::refine::measured(
            &grid,
            self.psf_noise,
            self.pedestal,
            self.seed,
        )?)
    }
}

/// What one training pair draws.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PairDraw {
    pub lens: usize,
    pub psf_px: usize,
    pub noise_scale: f32,
    /// Mirror left-right, then turn by this many quarter turns.
    pub flip: bool,
    pub quarter_turns: u8,
    /// Per-colour gain (colour jitter), the result clamped to [0, 1].
    pub gains: [f32; 3],
    /// Seed of the pair's noise and PSF position.
    pub seed: u64,
}

impl PairDraw {
    /// The paper's noise scaled as drawn.
    pub fn noise(&self, paper: NoiseModel) -> NoiseModel {
        NoiseModel {
            gaussian_sigma: paper.gaussian_sigma * self.noise_scale,
            poisson_scale: paper.poisson_scale * self.noise_scale,
        }
    }

    /// `photo` mirrored, turned and colour-jittered as drawn.
    pub fn augment(&self, photo: &Image) -> Image {
        let (w, h) = (photo.width, photo.height);
        let turns = self.quarter_turns % 4;
        let (ow, oh) = if turns % 2 == 1 { (h, w) } else { (w, h) };
        Image::from_fn(ow, oh, |x, y| {
            // Where output (x, y) comes from: undo the turns (clockwise), then the mirror.
            let (mut sx, mut sy) = (x, y);
            let mut dims = (ow, oh);
            for _ in 0..turns {
                // One clockwise quarter turn takes (x, y) of a w×h image from (y, w-1-x) of
                // the h×w image before it.
                (sx, sy) = (sy, dims.0 - 1 - sx);
                dims = (dims.1, dims.0);
            }
            if self.flip {
                sx = w - 1 - sx;
            }
            std::array::from_fn(|c| (photo.get(sx, sy, c) * self.gains[c]).clamp(0.0, 1.0))
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn draws_stay_in_their_ranges_and_repeat_for_the_same_seed() {
        let f = LensFamily::default();
        f.validate().unwrap();
        let base = SimConfig::default();
        assert_eq!(f.lens(&base, 0, 9).sim, base);
        for i in 1..50 {
            let l = f.lens(&base, i, 9);
            assert_eq!(l, f.lens(&base, i, 9));
            let focal = l.sim.lens.focal_um / base.lens.focal_um;
            assert!((focal - 1.0).abs() <= 0.05 + 1e-12, "{focal}");
            assert!((l.sim.sensor_offset_um - base.sensor_offset_um).abs() <= 5.0);
            for (a, b) in l.sim.wavelengths_nm.iter().zip(base.wavelengths_nm) {
                assert!((a - b).abs() <= 15.0);
            }
            assert!(l.sim.rotation_deg.abs() <= 3.0);
            assert!((0.0..=0.01).contains(&l.psf_noise) && (0.0..=0.01).contains(&l.pedestal));
        }
        assert_ne!(f.lens(&base, 1, 9), f.lens(&base, 2, 9));
        let mut seen = [usize::MAX, 0];
        let mut below_57 = 0;
        for s in 0..2000 {
            let p = f.pair(8, s);
            assert_eq!(p, f.pair(8, s));
            assert!((15..=140).contains(&p.psf_px) && p.lens < 8);
            assert!((0.5..=2.0).contains(&p.noise_scale));
            assert!(p.gains.iter().all(|g| (0.9..=1.1).contains(g)));
            seen = [seen[0].min(p.psf_px), seen[1].max(p.psf_px)];
            below_57 += usize::from(p.psf_px < 46);
        }
        assert!(seen[0] <= 17 && seen[1] >= 135, "{seen:?}");
        // Log-uniform: the geometric middle of 15-140 px (45.8) splits the draws in half.
        assert!((850..1150).contains(&below_57), "{below_57}");
        // Linear: the arithmetic middle (77.5) does, and 44 % lie above 85 px (22 % above).
        let linear = LensFamily {
            psf_px_draw: ScaleDraw::Linear,
            ..f.clone()
        };
        let (mut below_mid, mut above_85, mut above_85_log) = (0, 0, 0);
        for s in 0..4000 {
            let p = linear.pair(8, s);
            assert!((15..=140).contains(&p.psf_px));
            below_mid += usize::from(p.psf_px < 78);
            above_85 += usize::from(p.psf_px > 85);
            above_85_log += usize::from(f.pair(8, s).psf_px > 85);
        }
        assert!((1800..2200).contains(&below_mid), "{below_mid}");
        assert!((1600..1900).contains(&above_85), "{above_85}");
        assert!((750..1000).contains(&above_85_log), "{above_85_log}");
        // Headers written before the field read as log-uniform.
        let mut old = serde_json::to_value(&f).unwrap();
        old.as_object_mut().unwrap().remove("psf_px_draw");
        let read: LensFamily = serde_json::from_value(old).unwrap();
        assert_eq!(read, f);
        // The log draw is recorded as its flag's value, and read under its earlier name too.
        let log = serde_json::to_value(&read).unwrap();
        assert_eq!(log["psf_px_draw"], "log");
        let mut earlier = log.clone();
        earlier["psf_px_draw"] = "log-uniform".into();
        assert_eq!(serde_json::from_value::<LensFamily>(earlier).unwrap(), read);
        // Ranges that describe no lens are refused.
        for bad in [
            LensFamily {
                psf_px: [0, 10],
                ..f.clone()
            },
            LensFamily {
                psf_px: [50, 40],
                ..f.clone()
            },
            LensFamily {
                focal_percent: -1.0,
                ..f.clone()
            },
            LensFamily {
                pedestal: 1.0,
                ..f.clone()
            },
            LensFamily {
                noise_scale: [2.0, 1.0],
                ..f.clone()
            },
        ] {
            assert!(bad.validate().is_err(), "{bad:?}");
        }
    }

    #[test]
    fn augmentation_mirrors_turns_and_tints_as_a_direct_index_map_says() {
        let photo = Image::from_fn(5, 3, |x, y| [x as f32 / 10.0, y as f32 / 10.0, 0.5]);
        let base = PairDraw {
            lens: 0,
            psf_px: 15,
            noise_scale: 1.0,
            flip: false,
            quarter_turns: 0,
            gains: [1.0; 3],
            seed: 0,
        };
        assert_eq!(base.augment(&photo), photo);
        // A mirror: x reads from w-1-x.
        let m = PairDraw { flip: true, ..base }.augment(&photo);
        assert_eq!(m.get(0, 1, 0), photo.get(4, 1, 0));
        // One clockwise quarter turn: a 3×5 image whose top row is the old left column,
        // bottom to top.
        let t = PairDraw {
            quarter_turns: 1,
            ..base
        }
        .augment(&photo);
        assert_eq!((t.width, t.height), (3, 5));
        for y in 0..5 {
            for x in 0..3 {
                for c in 0..3 {
                    assert_eq!(t.get(x, y, c), photo.get(y, 2 - x, c), "({x}, {y})");
                }
            }
        }
        // Four turns are none; two are a half turn.
        let four = PairDraw {
            quarter_turns: 4,
            ..base
        };
        assert_eq!(four.augment(&photo), photo);
        let half = PairDraw {
            quarter_turns: 2,
            ..base
        }
        .augment(&photo);
        assert_eq!(half.get(0, 0, 0), photo.get(4, 2, 0));
        // Gains scale each colour and clamp to 1.
        let g = PairDraw {
            gains: [2.0, 1.0, 1.1],
            ..base
        }
        .augment(&photo);
        assert_eq!(g.get(4, 0, 0), 0.8);
        assert_eq!(g.get(0, 0, 2), 0.55);
        let bright = Image::filled(2, 2, [0.95, 0.5, 0.5]);
        assert_eq!(
            PairDraw {
                gains: [1.1, 1.0, 1.0],
                ..base
            }
            .augment(&bright)
            .get(1, 1, 0),
            1.0
        );
    }
}
