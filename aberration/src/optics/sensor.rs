//! Sampling the focal-plane intensity onto sensor pixels.

use super::propagate::FocalWindow;

/// A `k×k` sensor PSF around the spot at `(spot_x_um, 0)`, rotated by `azimuth` (the
/// direction of the field point in image coordinates, x right, y down), in pixels of
/// `pitch_um`. Each pixel integrates the bilinear power density over `ss×ss` sub-samples,
/// so it holds the energy falling on it. The centre pixel is `(k/2, k/2)`.
pub fn sample_psf(
    window: &FocalWindow,
    spot_x_um: f64,
    k: usize,
    pitch_um: f64,
    azimuth: f64,
    ss: usize,
) -> Vec<f64> {
    let c = (k / 2) as f64;
    let (sin, cos) = azimuth.sin_cos();
    let ss = ss.max(1);
    let sub: Vec<f64> = (0..ss)
        .map(|s| (s as f64 + 0.5) / ss as f64 - 0.5)
        .collect();
    let area = pitch_um * pitch_um / (ss * ss) as f64;
    let mut out = vec![0.0; k * k];
    for p in 0..k {
        for q in 0..k {
            let mut acc = 0.0;
            for sy in &sub {
                let dy = (p as f64 - c + sy) * pitch_um;
                for sx in &sub {
                    let dx = (q as f64 - c + sx) * pitch_um;
                    // Rotate the sensor offset into the frame where the field tilt is +x.
                    let a = dx * cos + dy * sin;
                    let b = -dx * sin + dy * cos;
                    acc += window.density(spot_x_um + a, b);
                }
            }
            out[p * k + q] = acc * area;
        }
    }
    out
}
