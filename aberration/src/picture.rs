//! Pictures people look at: the PSF grid on a log scale.

use crate::psf_grid::PsfGrid;
use image::{Rgb, RgbImage};

/// Decades shown below each channel's peak.
pub const DECADES: f32 = 4.0;

/// The gutter between the three channel mosaics of [`psf_grid_picture`], in pixels.
pub const CHANNEL_GAP: usize = 8;

/// Viridis, sampled at five points and interpolated linearly (`t` in [0, 1]: a colour bar).
pub fn viridis(t: f32) -> [u8; 3] {
    const C: [[f32; 3]; 5] = [
        [68.0, 1.0, 84.0],
        [59.0, 82.0, 139.0],
        [33.0, 145.0, 140.0],
        [94.0, 201.0, 98.0],
        [253.0, 231.0, 37.0],
    ];
    let t = if t.is_nan() { 0.0 } else { t.clamp(0.0, 1.0) } * 4.0;
    let i = (t.floor() as usize).min(3);
    let f = t - i as f32;
    std::array::from_fn(|c| (C[i][c] * (1.0 - f) + C[i + 1][c] * f).round() as u8)
}

/// Three mosaics side by side (R, G, B channel), each the G×G grid of PSFs with a 2-px
/// border, coloured by `log10(psf / channel peak)` over four decades.
pub fn psf_grid_picture(psf: &PsfGrid) -> RgbImage {
    let (g, k) = (psf.grid(), psf.size());
    let gap = 2;
    let panel = g * (k + gap) + gap;
    let mut img = RgbImage::from_pixel(
        (3 * panel + 2 * CHANNEL_GAP) as u32,
        panel as u32,
        Rgb([255, 255, 255]),
    );
    for c in 0..3 {
        let peak = (0..g * g)
            .flat_map(|gi| psf.kernel(gi, c).iter())
            .cloned()
            .fold(f32::MIN_POSITIVE, f32::max);
        let x0 = c * (panel + CHANNEL_GAP);
        for gi in 0..g * g {
            let (i, j) = (gi / g, gi % g);
            let kernel = psf.kernel(gi, c);
            for y in 0..k {
                for x in 0..k {
                    let v = kernel[y * k + x].max(0.0) / peak;
                    let t = 1.0 + v.max(1e-30).log10() / DECADES;
                    let px = x0 + gap + j * (k + gap) + x;
                    let py = gap + i * (k + gap) + y;
                    img.put_pixel(px as u32, py as u32, Rgb(viridis(t)));
                }
            }
        }
    }
    img
}

/// Grids of one shape as [`psf_grid_picture`]s stacked top to bottom (e.g. supplied, refined,
/// true), 8 px apart, for the eye to compare.
pub fn psf_grids_picture(grids: &[&PsfGrid]) -> RgbImage {
    let pictures: Vec<RgbImage> = grids.iter().map(|g| psf_grid_picture(g)).collect();
    let width = pictures.iter().map(|p| p.width()).max().unwrap_or(1);
    let height = pictures.iter().map(|p| p.height() + 8).sum::<u32>().max(9) - 8;
    let mut out = RgbImage::from_pixel(width, height, Rgb([255, 255, 255]));
    let mut y = 0;
    for p in &pictures {
        image::imageops::replace(&mut out, p, 0, y as i64);
        y += p.height() + 8;
    }
    out
}
