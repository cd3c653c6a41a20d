//! What a network was trained to restore, and whether a capture's PSF grid is inside it.
//!
//! A network trained on one grid serves that grid (its fingerprint in the weights header). A
//! network trained on a family of lenses serves any grid that looks like a member: grids are
//! compared by a scale-free [`shape`] (how wide each colour's PSF is at the centre, the edges
//! and the corners of the field, as the radius holding half its energy, relative to the
//! grid's mean width, and how much of its window the mean fills), and the header keeps the [`Envelope`] of the shapes of the lenses drawn in
//! training. The blur scale (PSF side at the photo's size) is checked apart, against the range
//! the header records.

use aberration::PsfGrid;
use serde::{Deserialize, Serialize};

/// Entries of [`shape`]: 3 colours × 3 zones of relative width, and the fill.
pub const SHAPE_LEN: usize = 10;
/// Names of the [`shape`] entries, for messages.
pub const SHAPE_NAMES: [&str; SHAPE_LEN] = [
    "red width at the centre",
    "red width at the edges",
    "red width at the corners",
    "green width at the centre",
    "green width at the edges",
    "green width at the corners",
    "blue width at the centre",
    "blue width at the edges",
    "blue width at the corners",
    "blur width against the PSF window",
];

/// Radius (px) of the disc about a kernel's centre that holds half its energy (EE50), with
/// the kernel's median taken off first: a measured grid's noise floor and pedestal, which
/// spread a little energy over the whole window, would otherwise outweigh the PSF itself in
/// any moment of it. The centre is the centroid of what is left.
fn ee50_radius(kernel: &[f32], k: usize) -> f64 {
    let mut sorted = kernel.to_vec();
    let mid = sorted.len() / 2;
    let (_, median, _) = sorted.select_nth_unstable_by(mid, f32::total_cmp);
    let floor = median.max(0.0) as f64;
    let w: Vec<f64> = kernel
        .iter()
        .map(|&v| (v as f64 - floor).max(0.0))
        .collect();
    let total: f64 = w.iter().sum();
    if total <= 0.0 {
        return 0.0;
    }
    let (mut cx, mut cy) = (0.0, 0.0);
    for (i, v) in w.iter().enumerate() {
        cx += v * (i % k) as f64;
        cy += v * (i / k) as f64;
    }
    let (cx, cy) = (cx / total, cy / total);
    let by_distance: Vec<(f64, f64)> = w
        .iter()
        .enumerate()
        .filter(|(_, v)| **v > 0.0)
        .map(|(i, v)| (((i % k) as f64 - cx).hypot((i / k) as f64 - cy), *v))
        .collect();
    // Each pixel's energy spread over one pixel of radius about its distance, so that the
    // energy held within r grows continuously and the radius moves smoothly with the PSF
    // (whole-pixel rings would make it jump between the few distances a grid has).
    let held = |r: f64| -> f64 {
        by_distance
            .iter()
            .map(|(d, v)| v * (r - d + 0.5).clamp(0.0, 1.0))
            .sum()
    };
    let (mut lo, mut hi) = (0.0, k as f64);
    for _ in 0..40 {
        let mid = 0.5 * (lo + hi);
        if held(mid) < 0.5 * total {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// Zone of grid cell `(row, col)` of a `g × g` grid: 0 the centre (the middle cell, or the
/// middle 2×2 of an even grid), 2 a corner, 1 any other cell on the rim; inner cells that are
/// not the centre count to no zone.
fn zone(row: usize, col: usize, g: usize) -> Option<usize> {
    let rim = |i: usize| i == 0 || i + 1 == g;
    let middle =
        |i: usize| 2 * i + 1 == g || (g.is_multiple_of(2) && (2 * i + 2 == g || 2 * i == g));
    match (rim(row), rim(col)) {
        (true, true) => Some(2),
        (true, false) | (false, true) => Some(1),
        _ if middle(row) && middle(col) => Some(0),
        _ => None,
    }
}

/// The scale-free shape of a grid: per colour (R, G, B), the mean half-energy radius of the
/// PSFs at the centre, on the rim and at the corners of the field, each divided by the mean
/// of the nine; then that mean divided by the PSF side. Resampling a grid to another size keeps it
/// (within the area resampling's added width), so one shape serves every photo size. A grid
/// of one cell has all three zones in that cell.
pub fn shape(psf: &PsfGrid) -> [f64; SHAPE_LEN] {
    let (g, k) = (psf.grid(), psf.size());
    let mut sum = [[0.0f64; 3]; 3];
    let mut count = [0usize; 3];
    for row in 0..g {
        for col in 0..g {
            let zones: Vec<usize> = if g == 1 {
                vec![0, 1, 2]
            } else {
                zone(row, col, g).into_iter().collect()
            };
            for z in zones {
                count[z] += 1;
                for (c, s) in sum.iter_mut().enumerate() {
                    s[z] += ee50_radius(psf.kernel(row * g + col, c), k);
                }
            }
        }
    }
    let mut widths = [0.0f64; 9];
    for c in 0..3 {
        for z in 0..3 {
            widths[c * 3 + z] = sum[c][z] / count[z].max(1) as f64;
        }
    }
    let mean = widths.iter().sum::<f64>() / 9.0;
    let mut out = [0.0; SHAPE_LEN];
    for (o, w) in out.iter_mut().zip(widths) {
        *o = if mean > 0.0 { w / mean } else { 1.0 };
    }
    out[9] = mean / k as f64;
    out
}

/// The range of every [`shape`] entry over the lenses a network was trained on, widened by a
/// margin: a grid whose shape lies inside is taken as one of the family.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Envelope {
    /// Grid side G of the family's grids.
    pub grid: usize,
    /// `[low, high]` per shape entry, margin included.
    pub ranges: Vec<[f64; 2]>,
}

/// Widening of an envelope on each side: this share of its range, and this share of the
/// value. A handful of lenses spans less than their family (of 32 lenses drawn past a bank of
/// 8, a sixth fell outside the bank's own ranges even widened by half of them); widened by the
/// whole range all 32 were inside, while other designs (an ideal lens at any of the three
/// wavelengths) stay far outside.
pub const MARGIN_OF_RANGE: f64 = 1.0;
pub const MARGIN_OF_VALUE: f64 = 0.02;

impl Envelope {
    /// The envelope of `grids` (at least one; all of one grid side).
    pub fn of(grids: &[PsfGrid]) -> Option<Self> {
        let first = grids.first()?;
        if grids.iter().any(|g| g.grid() != first.grid()) {
            return None;
        }
        let mut ranges = vec![[f64::INFINITY, f64::NEG_INFINITY]; SHAPE_LEN];
        for g in grids {
            for (r, v) in ranges.iter_mut().zip(shape(g)) {
                *r = [r[0].min(v), r[1].max(v)];
            }
        }
        for r in &mut ranges {
            let pad =
                MARGIN_OF_RANGE * (r[1] - r[0]) + MARGIN_OF_VALUE * r[0].abs().max(r[1].abs());
            // Outwards to six decimals: short numbers that read back from the header's JSON
            // as exactly these values.
            *r = [
                ((r[0] - pad) * 1e6).floor() / 1e6,
                ((r[1] + pad) * 1e6).ceil() / 1e6,
            ];
        }
        Some(Self {
            grid: first.grid(),
            ranges,
        })
    }

    /// Ok when `psf` is inside; otherwise the entries outside, as a sentence.
    pub fn holds(&self, psf: &PsfGrid) -> Result<(), String> {
        if psf.grid() != self.grid {
            return Err(format!(
                "the family's grids are {}x{}, this one is {}x{}",
                self.grid,
                self.grid,
                psf.grid(),
                psf.grid()
            ));
        }
        let s = shape(psf);
        let outside: Vec<String> = s
            .iter()
            .zip(&self.ranges)
            .zip(SHAPE_NAMES)
            .filter(|((v, r), _)| !(r[0]..=r[1]).contains(*v))
            .map(|((v, r), name)| format!("{name} {v:.3} (the family's {:.3}-{:.3})", r[0], r[1]))
            .collect();
        if outside.is_empty() {
            Ok(())
        } else {
            Err(outside.join(", "))
        }
    }
}

/// The lenses a family network was trained on: how each was drawn about the paper's lens, and
/// the [`Envelope`] of their grids' shapes, which is what loading checks.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Family {
    /// How the lenses were drawn, for people (focal length, sensor offset, wavelengths,
    /// rotation, PSF noise and pedestal ranges).
    pub drawn: serde_json::Value,
    pub envelope: Envelope,
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A grid of Gaussians whose width grows from the centre to the corners and with the
    /// colour, `widen` times the reference widths.
    fn gaussian_grid(g: usize, k: usize, widen: [f64; 3], field_growth: f64) -> PsfGrid {
        let c = (k / 2) as f64;
        let mut data = Vec::with_capacity(g * g * 3 * k * k);
        for row in 0..g {
            for col in 0..g {
                let r = ((row as f64 - (g - 1) as f64 / 2.0).powi(2)
                    + (col as f64 - (g - 1) as f64 / 2.0).powi(2))
                .sqrt();
                for (ch, w) in widen.iter().enumerate() {
                    let sigma = w * (1.5 + ch as f64 * 0.7) * (1.0 + field_growth * r);
                    let kernel: Vec<f32> = (0..k * k)
                        .map(|i| {
                            let (y, x) = ((i / k) as f64 - c, (i % k) as f64 - c);
                            (-(x * x + y * y) / (2.0 * sigma * sigma)).exp() as f32
                        })
                        .collect();
                    let s: f32 = kernel.iter().sum();
                    data.extend(kernel.iter().map(|v| v / s));
                }
            }
        }
        PsfGrid::from_planar(g, k, data).unwrap()
    }

    #[test]
    fn the_shape_is_the_widths_a_direct_sum_gives_and_survives_resampling() {
        let grid = gaussian_grid(5, 41, [1.0, 1.0, 1.0], 0.1);
        let s = shape(&grid);
        // The fill: a Gaussian holds half its energy within sigma·sqrt(2 ln 2); at the centre
        // the mean sigma is 2.2 px, and it grows outwards.
        let sigma_mean: f64 = (0..3).map(|c| 1.5 + c as f64 * 0.7).sum::<f64>() / 3.0;
        let ee50 = sigma_mean * (2.0 * 2f64.ln()).sqrt();
        assert!(s[9] > ee50 / 41.0 && s[9] < 2.0 * ee50 / 41.0, "{s:?}");
        // Against the direct definition for one kernel: the centre green PSF (sigma 2.2 px)
        // holds half its energy within 2.59 px, to the pixel grid's step.
        let r = ee50_radius(grid.kernel(12, 1), 41);
        assert!((r - 2.2 * (2.0 * 2f64.ln()).sqrt()).abs() < 0.5, "{r}");
        // Colours widen red < green < blue here, and every colour widens outwards.
        for z in 0..3 {
            assert!(s[z] < s[3 + z] && s[3 + z] < s[6 + z], "{s:?}");
        }
        for c in 0..3 {
            assert!(
                s[c * 3] < s[c * 3 + 1] && s[c * 3 + 1] < s[c * 3 + 2],
                "{s:?}"
            );
        }
        // The nine relative widths average to one.
        assert!((s[..9].iter().sum::<f64>() / 9.0 - 1.0).abs() < 1e-12);
        // The same grid at half the size keeps its shape to about a tenth (area resampling
        // widens the sharpest PSFs most: measured 10.4 % here), which is why grids are
        // compared at their native size.
        let half = grid.resampled(0.5);
        for (a, b) in s.iter().zip(shape(&half)) {
            assert!((a - b).abs() / a < 0.12, "{s:?} against {:?}", shape(&half));
        }
    }

    #[test]
    fn an_envelope_holds_its_members_and_their_neighbours_not_other_lenses() {
        let members: Vec<PsfGrid> = [0.9, 1.0, 1.1]
            .iter()
            .map(|&w| gaussian_grid(5, 41, [w, 1.0, 1.0 / w], 0.1))
            .collect();
        let env = Envelope::of(&members).unwrap();
        for m in &members {
            assert_eq!(env.holds(m), Ok(()));
        }
        // A lens between the members, and one of them resampled to a photo's size.
        assert_eq!(
            env.holds(&gaussian_grid(5, 41, [0.95, 1.0, 1.05], 0.1)),
            Ok(())
        );
        assert_eq!(env.holds(&members[1].resampled(0.7)), Ok(()));
        // Far more colour spread, a field that blurs three times as fast, another grid side.
        let e = env
            .holds(&gaussian_grid(5, 41, [0.5, 1.0, 2.0], 0.1))
            .unwrap_err();
        assert!(e.contains("red width") && e.contains("the family's"), "{e}");
        assert!(env.holds(&gaussian_grid(5, 41, [1.0; 3], 0.3)).is_err());
        let e = env.holds(&gaussian_grid(3, 41, [1.0; 3], 0.1)).unwrap_err();
        assert!(e.contains("5x5") && e.contains("3x3"), "{e}");
        // A delta grid (no blur) fills nothing of its window.
        let e = env.holds(&PsfGrid::delta(5, 41)).unwrap_err();
        assert!(e.contains("window"), "{e}");
        // Grids of different sides make no envelope.
        assert!(Envelope::of(&[members[0].clone(), gaussian_grid(3, 41, [1.0; 3], 0.1)]).is_none());
        assert!(Envelope::of(&[]).is_none());
        // It round-trips through the header's JSON.
        let json = serde_json::to_string(&env).unwrap();
        assert_eq!(serde_json::from_str::<Envelope>(&json).unwrap(), env);
    }
}
