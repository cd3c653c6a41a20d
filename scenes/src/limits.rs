//! What a capture may hold: the limits every reader checks at load time, so every command
//! (`scene info`, `scene aberrate`, `train`, `render`, `experiment`) refuses the same bad
//! capture with the same message, naming the file the bad value came from. Nothing here is
//! coerced: a value outside these limits is an error.
//!
//! | what | accepted |
//! |---|---|
//! | image size (camera model, poses, decoded images) | 1 to [`MAX_IMAGE_SIDE`] px a side |
//! | focal length | finite, between [`MIN_FOCAL_PER_WIDTH`] and [`MAX_FOCAL_PER_WIDTH`] image widths (a horizontal field of view between about 0.6° and 170°) |
//! | principal point | finite, within one image size of the image |
//! | distortion | finite, `|k1|, |k2|` ≤ [`MAX_RADIAL_DISTORTION`], `|p1|, |p2|` ≤ [`MAX_TANGENTIAL_DISTORTION`] |
//! | pose | finite; a COLMAP quaternion of norm at least [`MIN_QUATERNION_NORM`] |
//! | points (`points3D`) and camera positions | finite, every coordinate within [`MAX_COORDINATE`] |
//! | near/far bounds | `MIN_DEPTH ≤ near < far ≤ MAX_COORDINATE` |
//! | images against the model | at most [`MAX_DOWNSAMPLE`] times smaller than the poses or cameras say, same aspect within a pixel |

use crate::camera::Distortion;

/// Largest image side, in pixels, a camera or image may have.
pub const MAX_IMAGE_SIDE: u64 = 65_536;
/// Smallest focal length as a multiple of the image width (about a 170° field of view).
pub const MIN_FOCAL_PER_WIDTH: f64 = 0.05;
/// Largest focal length as a multiple of the image width (about a 0.6° field of view).
pub const MAX_FOCAL_PER_WIDTH: f64 = 100.0;
/// Largest radial distortion coefficient magnitude (normalised coordinates).
pub const MAX_RADIAL_DISTORTION: f64 = 10.0;
/// Largest tangential distortion coefficient magnitude.
pub const MAX_TANGENTIAL_DISTORTION: f64 = 1.0;
/// Smallest norm of a COLMAP rotation quaternion before normalisation.
pub const MIN_QUATERNION_NORM: f64 = 1e-6;
/// Largest magnitude of a point coordinate (squared, it must stay far from overflow).
pub const MAX_COORDINATE: f64 = 1e8;
/// Smallest near bound: depths below it make the splat thresholds and the projection
/// meaningless (and their reciprocals overflow on the way).
pub const MIN_DEPTH: f64 = 1e-8;
/// Most times smaller the loaded images may be than the size the poses or cameras record
/// (LLFF's `images_8` is 8).
pub const MAX_DOWNSAMPLE: f64 = 64.0;

/// `v` for a message: plain for ordinary magnitudes, scientific for the absurd ones a
/// refusal is usually about (`1e-20`, not twenty zeros).
pub fn show(v: f64) -> String {
    if v == 0.0 || !v.is_finite() || (1e-4..1e9).contains(&v.abs()) {
        format!("{v}")
    } else {
        format!("{v:e}")
    }
}

/// Checks an image size against [`MAX_IMAGE_SIDE`].
pub fn check_size(width: f64, height: f64) -> Result<(), String> {
    let ok = |v: f64| v.is_finite() && v >= 1.0 && v <= MAX_IMAGE_SIDE as f64;
    if ok(width) && ok(height) {
        Ok(())
    } else {
        Err(format!(
            "image size {}x{}; each side must be 1 to {MAX_IMAGE_SIDE} px",
            show(width),
            show(height)
        ))
    }
}

/// Checks intrinsics for an image of `width`x`height` (sizes already checked).
pub fn check_intrinsics(
    width: f64,
    height: f64,
    fx: f64,
    fy: f64,
    cx: f64,
    cy: f64,
) -> Result<(), String> {
    for (name, f) in [("fx", fx), ("fy", fy)] {
        let ratio = f / width;
        if !(f.is_finite() && (MIN_FOCAL_PER_WIDTH..=MAX_FOCAL_PER_WIDTH).contains(&ratio)) {
            return Err(format!(
                "focal length {name} = {} px for a {width} px wide image; it must be finite and \
                 {MIN_FOCAL_PER_WIDTH} to {MAX_FOCAL_PER_WIDTH} image widths",
                show(f)
            ));
        }
    }
    let within = |c: f64, side: f64| c.is_finite() && c >= -side && c <= 2.0 * side;
    if !(within(cx, width) && within(cy, height)) {
        return Err(format!(
            "principal point ({}, {}) lies more than an image size outside the {width}x{height} image",
            show(cx),
            show(cy)
        ));
    }
    Ok(())
}

/// Checks distortion coefficients against [`MAX_RADIAL_DISTORTION`] and
/// [`MAX_TANGENTIAL_DISTORTION`].
pub fn check_distortion(d: &Distortion) -> Result<(), String> {
    let radial = [d.k1, d.k2]
        .iter()
        .chain(&d.rational)
        .all(|k| k.is_finite() && k.abs() <= MAX_RADIAL_DISTORTION);
    let tangential = [d.p1, d.p2]
        .iter()
        .all(|p| p.is_finite() && p.abs() <= MAX_TANGENTIAL_DISTORTION);
    if radial && tangential {
        Ok(())
    } else {
        Err(format!(
            "distortion k1 {}, k2 {}, p1 {}, p2 {}, k3..k6 {}; |k| must be at most \
             {MAX_RADIAL_DISTORTION} and |p| at most {MAX_TANGENTIAL_DISTORTION}",
            show(d.k1),
            show(d.k2),
            show(d.p1),
            show(d.p2),
            d.rational.map(show).join(" ")
        ))
    }
}

/// Checks that the lens map does not fold the image back on itself: the distorted radius
/// `r·radial(r)` must grow with `r` out to the farthest corner of a `w × h` image with these
/// intrinsics (in normalised coordinates). Coefficients inside [`check_distortion`]'s bounds can
/// still turn the radius back before the corner, and undistorting then trains on mirrored
/// content.
pub fn check_distortion_folds(
    d: &Distortion,
    w: f64,
    h: f64,
    fx: f64,
    fy: f64,
    cx: f64,
    cy: f64,
) -> Result<(), String> {
    let corner = [(0.0, 0.0), (w, 0.0), (0.0, h), (w, h)]
        .iter()
        .map(|(u, v)| (((u - cx) / fx).powi(2) + ((v - cy) / fy).powi(2)).sqrt())
        .fold(0.0, f64::max);
    const SAMPLES: usize = 1024;
    let mut last = 0.0;
    for i in 1..=SAMPLES {
        let r = corner * i as f64 / SAMPLES as f64;
        // Along a ray the tangential terms are second order; the radial map decides.
        let (x, _) = d.distort(r, 0.0);
        let radial = x - d.p2 * 3.0 * r * r;
        if radial.is_nan() || radial <= last {
            return Err(format!(
                "distortion {d} folds the image: the distorted radius stops growing at {:.3} of the way to the farthest corner (normalised radius {r:.4} of {corner:.4}), so undistorting would repeat mirrored content",
                i as f64 / SAMPLES as f64
            ));
        }
        last = radial;
    }
    Ok(())
}

/// Checks a point position against [`MAX_COORDINATE`].
pub fn check_point(xyz: [f64; 3]) -> Result<(), String> {
    if xyz
        .iter()
        .all(|v| v.is_finite() && v.abs() <= MAX_COORDINATE)
    {
        Ok(())
    } else {
        Err(format!(
            "position [{}, {}, {}]; coordinates must be finite and within ±{MAX_COORDINATE:e}",
            show(xyz[0]),
            show(xyz[1]),
            show(xyz[2])
        ))
    }
}

/// Checks near/far bounds against [`MIN_DEPTH`] and [`MAX_COORDINATE`].
pub fn check_bounds(near: f64, far: f64) -> Result<(), String> {
    if near >= MIN_DEPTH && far > near && far <= MAX_COORDINATE {
        Ok(())
    } else {
        Err(format!(
            "bounds near {} far {}; they must satisfy {MIN_DEPTH:e} <= near < far <= {MAX_COORDINATE:e}",
            show(near),
            show(far)
        ))
    }
}

/// Whether an image of `image` pixels has the aspect of the `recorded` size, within the pixel
/// of drift that rounding a downsampled size gives (every capture reader's rule).
pub fn same_aspect(recorded: (f64, f64), image: (u32, u32)) -> bool {
    let drift = (image.0 as f64 * recorded.1) / (image.1 as f64 * recorded.0) - 1.0;
    drift.abs() <= 1.0 / image.0.min(image.1) as f64 + 1e-9
}

/// Checks that images of `image` px are not more than [`MAX_DOWNSAMPLE`] times smaller than
/// the `recorded` size.
pub fn check_downsample(recorded: (f64, f64), image: (u32, u32)) -> Result<(), String> {
    let factor = (recorded.0 / image.0 as f64).max(recorded.1 / image.1 as f64);
    if factor <= MAX_DOWNSAMPLE {
        Ok(())
    } else {
        Err(format!(
            "the images are {}x{} but the model records {}x{}, {factor:.0} times larger; at most \
             {MAX_DOWNSAMPLE} is accepted",
            image.0, image.1, recorded.0, recorded.1
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::CameraModel;

    #[test]
    fn limits_accept_ordinary_cameras_and_refuse_absurd_ones() {
        assert!(check_size(4032.0, 3024.0).is_ok());
        assert!(check_size(0.0, 10.0).is_err());
        assert!(check_size(f64::NAN, 10.0).is_err());
        assert!(check_size(1e6, 10.0).is_err());
        assert!(check_intrinsics(504.0, 378.0, 407.6, 407.6, 252.0, 189.0).is_ok());
        for f in [f64::NAN, 0.0, -5.0, 1e-20, 1e30, f64::INFINITY] {
            assert!(
                check_intrinsics(504.0, 378.0, f, 407.6, 252.0, 189.0).is_err(),
                "{f}"
            );
        }
        assert!(check_intrinsics(504.0, 378.0, 407.6, 407.6, f64::NAN, 189.0).is_err());
        let d = |k1| Distortion {
            model: CameraModel::OpenCv,
            k1,
            k2: 0.0,
            p1: 0.0,
            p2: 0.0,
            rational: [0.0; 4],
        };
        assert!(check_distortion(&d(-0.3)).is_ok());
        // k1 = -0.3 folds past r = 1/sqrt(0.9) ≈ 1.054: inside a wide image, not a narrow one.
        assert!(check_distortion_folds(&d(-0.3), 640.0, 480.0, 500.0, 500.0, 320.0, 240.0).is_ok());
        let wide = check_distortion_folds(&d(-0.3), 640.0, 480.0, 250.0, 250.0, 320.0, 240.0);
        assert!(
            wide.as_ref().is_err_and(|e| e.contains("folds")),
            "{wide:?}"
        );
        assert!(check_distortion(&d(1e6)).is_err());
        assert!(check_distortion(&d(f64::NAN)).is_err());
        assert!(check_point([1.0, -2.0, 3.0]).is_ok());
        assert!(check_point([f64::NAN, 0.0, 0.0]).is_err());
        assert!(check_point([1e300, 0.0, 0.0]).is_err());
        assert!(check_downsample((4032.0, 3024.0), (504, 378)).is_ok());
        assert!(check_downsample((64000.0, 48000.0), (32, 24)).is_err());
        assert!(same_aspect((4032.0, 3024.0), (504, 378)));
        // Rounding a downsampled side is a pixel of drift; a quarter wider is another aspect.
        assert!(same_aspect((4032.0, 3024.0), (505, 378)));
        assert!(!same_aspect((40.0, 24.0), (32, 24)));
    }
}
