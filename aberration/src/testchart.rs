//! A built-in test chart, so the demo needs no data: a Siemens star for resolution,
//! colour patches for chromatic blur, bars, and a lattice of point sources that shows each
//! grid PSF directly.

use crate::image::Image;
use std::f32::consts::PI;

const PATCHES: [[f32; 3]; 12] = [
    [0.45, 0.32, 0.26],
    [0.76, 0.58, 0.50],
    [0.36, 0.48, 0.61],
    [0.35, 0.42, 0.26],
    [0.51, 0.50, 0.69],
    [0.39, 0.74, 0.67],
    [0.85, 0.47, 0.18],
    [0.28, 0.36, 0.65],
    [0.76, 0.33, 0.38],
    [0.36, 0.24, 0.42],
    [0.62, 0.74, 0.25],
    [0.89, 0.63, 0.16],
];

pub fn test_chart(width: usize, height: usize) -> Image {
    let (w, h) = (width as f32, height as f32);
    let s = w.min(h);
    Image::from_fn(width, height, |x, y| {
        let (fx, fy) = (x as f32 + 0.5, y as f32 + 0.5);
        let (u, v) = (fx / w, fy / h);
        // Dim background gradient.
        let mut rgb = [0.08 + 0.12 * u, 0.10 + 0.08 * v, 0.18 - 0.08 * u];
        // Siemens star in the centre.
        let (dx, dy) = (fx - 0.5 * w, fy - 0.5 * h);
        let r = (dx * dx + dy * dy).sqrt();
        if r < 0.22 * s {
            let spokes = 36.0;
            let on = ((dy.atan2(dx) * spokes / (2.0 * PI)).rem_euclid(1.0)) < 0.5;
            let val = if on { 0.95 } else { 0.05 };
            rgb = [val; 3];
        }
        // Colour patches along the bottom.
        if v > 0.78 && v < 0.94 && u > 0.06 && u < 0.94 {
            let i = (((u - 0.06) / 0.88) * 12.0).floor() as usize;
            let local = ((u - 0.06) / 0.88) * 12.0 - i as f32;
            if local > 0.08 && local < 0.92 {
                rgb = PATCHES[i.min(11)];
            }
        }
        // Bars of increasing frequency along the top.
        if v > 0.05 && v < 0.16 && u > 0.1 && u < 0.9 {
            let t = (u - 0.1) / 0.8;
            let period = 2.0 + 14.0 * (1.0 - t);
            let on = (fx / period).rem_euclid(1.0) < 0.5;
            rgb = if on { [0.9; 3] } else { [0.1; 3] };
        }
        // A 9x9 lattice of point sources, one per PSF tile centre.
        let (cx, cy) = ((u * 9.0).fract() - 0.5, (v * 9.0).fract() - 0.5);
        if (cx * w / 9.0).abs() < 1.0 && (cy * h / 9.0).abs() < 1.0 {
            rgb = [1.0; 3];
        }
        rgb
    })
}
