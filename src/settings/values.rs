//! Value parsers for numeric command-line flags: a value that makes no sense is refused by
//! clap with the flag's name, before any work (zero, negative, NaN and infinite where they do
//! not apply, and sizes beyond the limits written here).

/// Largest image side a flag may ask for (procedural scenes, sensors).
pub const MAX_SIDE: u32 = 16_384;

fn float(s: &str) -> Result<f64, String> {
    let v: f64 = s
        .trim()
        .parse()
        .map_err(|_| format!("'{s}' is not a number"))?;
    if !v.is_finite() {
        return Err(format!("{v} is not finite"));
    }
    Ok(v)
}

/// A finite number > 0.
pub fn positive(s: &str) -> Result<f64, String> {
    let v = float(s)?;
    if v > 0.0 {
        Ok(v)
    } else {
        Err(format!("{} must be positive", s.trim()))
    }
}

/// A finite number ≥ 0 (a time budget: 0 stops after the first step).
pub fn non_negative(s: &str) -> Result<f64, String> {
    let v = float(s)?;
    if v >= 0.0 {
        Ok(v)
    } else {
        Err(format!("{} must not be negative", s.trim()))
    }
}

/// A finite number > 0, as f32.
pub fn positive_f32(s: &str) -> Result<f32, String> {
    let v = positive(s)? as f32;
    if v > 0.0 && v.is_finite() {
        Ok(v)
    } else {
        Err(format!("{s} is out of range"))
    }
}

/// A finite number ≥ 0, as f32 (a loss weight).
pub fn weight(s: &str) -> Result<f32, String> {
    let v = float(s)?;
    if (0.0..=1e6).contains(&v) {
        Ok(v as f32)
    } else {
        Err(format!("{} must be in [0, 1e6]", s.trim()))
    }
}

/// A field angle in degrees: in (0, 89].
pub fn field_angle(s: &str) -> Result<f64, String> {
    let v = float(s)?;
    if v > 0.0 && v <= 89.0 {
        Ok(v)
    } else {
        Err(format!("{} must be in (0, 89]", s.trim()))
    }
}

/// A whole number of pixels, before each flag's own range.
fn pixel_count(s: &str) -> Result<usize, String> {
    s.trim()
        .parse()
        .map_err(|_| format!("'{s}' is not a pixel count"))
}

/// A sensor size in pixels: 8..=65536 (smaller would map PSFs far beyond the image).
pub fn sensor_px(s: &str) -> Result<usize, String> {
    let v = pixel_count(s)?;
    if (8..=65_536).contains(&v) {
        Ok(v)
    } else {
        Err(format!("{v} px is outside 8..=65536"))
    }
}

/// A learning rate: in (0, 1], so that it stays finite and meaningful in f32 (1e308 is finite
/// in f64 and infinite in f32).
pub fn learning_rate(s: &str) -> Result<f64, String> {
    let v = float(s)?;
    if v > 0.0 && v <= 1.0 {
        Ok(v)
    } else {
        Err(format!("{} must be in (0, 1]", s.trim()))
    }
}

/// A Wiener constant (noise-to-signal power ratio): in (0, 1000]; beyond, the filter returns
/// nothing but the image's mean.
pub fn wiener_k(s: &str) -> Result<f32, String> {
    let v = float(s)?;
    if v > 0.0 && v <= 1000.0 && (v as f32) > 0.0 {
        Ok(v as f32)
    } else {
        Err(format!("{} must be in (0, 1000]", s.trim()))
    }
}

/// A validation crop side: 0 (whole images) or at least [`MIN_CROP`] pixels.
pub fn val_crop(s: &str) -> Result<usize, String> {
    let v = pixel_count(s)?;
    if v == 0 || (MIN_CROP..=MAX_SIDE as usize).contains(&v) {
        Ok(v)
    } else {
        Err(format!(
            "{v} px: use 0 (whole images) or {MIN_CROP} to {MAX_SIDE} px"
        ))
    }
}

/// `restorer train --crop`: a training crop side from [`MIN_CROP`] to 1024 px (whether the
/// config's levels divide it is checked with the config).
pub fn train_crop(s: &str) -> Result<usize, String> {
    let v = pixel_count(s)?;
    if (MIN_CROP..=MAX_TRAIN_CROP).contains(&v) {
        Ok(v)
    } else {
        Err(format!("{v} px: use {MIN_CROP} to {MAX_TRAIN_CROP} px"))
    }
}

/// The largest training crop: a training photo must hold it, and a step's memory grows with
/// its square.
pub const MAX_TRAIN_CROP: usize = 1024;

/// The smallest validation crop: a few of the network's attention windows.
pub const MIN_CROP: usize = 16;

/// `restorer train --psf-px-range`: the PSF sides a family run draws from, `LO-HI` pixels,
/// 1 ≤ LO ≤ HI ≤ the largest mapped PSF; both ends included.
pub fn psf_px_range(s: &str) -> Result<[usize; 2], String> {
    let (lo, hi) = s
        .split_once('-')
        .ok_or_else(|| format!("'{s}' is not LO-HI (e.g. 85-140)"))?;
    let (lo, hi) = (pixel_count(lo)?, pixel_count(hi)?);
    let max = aberration::resample::MAX_MAPPED_PSF_PX;
    if lo == 0 || lo > hi || hi > max {
        return Err(format!("{lo}-{hi} px: use 1 ≤ LO ≤ HI ≤ {max}"));
    }
    Ok([lo, hi])
}

/// Held-out view spacing: 0 (none held out) or at least 2 (1 would hold out every view).
pub fn llffhold(s: &str) -> Result<usize, String> {
    let v: usize = s
        .trim()
        .parse()
        .map_err(|_| format!("'{s}' is not a count"))?;
    if v == 1 {
        Err("1 would hold out every view: use 0 (none) or at least 2".into())
    } else {
        Ok(v)
    }
}

/// A camera pose "ex,ey,ez,tx,ty,tz": eye and target, finite and apart.
pub fn camera_pose(s: &str) -> Result<[f32; 6], String> {
    let v: Vec<f32> = s
        .split(',')
        .map(|x| x.trim().parse::<f32>())
        .collect::<Result<_, _>>()
        .map_err(|_| format!("'{s}' is not six numbers ex,ey,ez,tx,ty,tz"))?;
    let v: [f32; 6] = v
        .try_into()
        .map_err(|_| format!("'{s}' is not six numbers ex,ey,ez,tx,ty,tz"))?;
    if v.iter()
        .any(|x| !(x.is_finite() && x.abs() <= splat::formats::files::MAX_POSITION))
    {
        return Err(format!(
            "'{s}': every number must be within ±{:e}",
            splat::formats::files::MAX_POSITION
        ));
    }
    // The view direction and the near plane come from eye − target in f32: a separation
    // lost in the coordinates' rounding (or a denormal one) gives no direction at all.
    let d = (0..3)
        .map(|i| (v[i] as f64 - v[i + 3] as f64).powi(2))
        .sum::<f64>()
        .sqrt();
    let magnitude = v.iter().fold(1.0f64, |m, x| m.max(x.abs() as f64));
    let least = 1e-4 * magnitude;
    if d.is_nan() || d < least {
        return Err(format!(
            "'{s}': the eye and the target are {d:e} apart; put them at least {least:e} apart"
        ));
    }
    Ok(v)
}

/// A background colour: `black`, `white`, or `R,G,B` with each channel in [0, 1].
pub fn colour(s: &str) -> Result<[f32; 3], String> {
    match s.trim() {
        "black" => return Ok([0.0; 3]),
        "white" => return Ok([1.0; 3]),
        _ => {}
    }
    let parts: Vec<&str> = s.split(',').collect();
    if parts.len() != 3 {
        return Err(format!(
            "'{s}' is not a colour (black, white, or R,G,B with channels in [0, 1])"
        ));
    }
    let mut rgb = [0.0f32; 3];
    for ((c, p), name) in rgb.iter_mut().zip(parts).zip(["red", "green", "blue"]) {
        let v = float(p)?;
        if !(0.0..=1.0).contains(&v) {
            return Err(format!("'{s}': the {name} value {v} is outside [0, 1]"));
        }
        *c = v as f32;
    }
    Ok(rgb)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_camera_needs_an_eye_apart_from_its_target() {
        assert!(camera_pose("0,0,-1,0,0,1").is_ok());
        for bad in ["0,0,0,1e-30,0,0", "1,1,1,1,1,1", "1e7,0,0,1e7,0,1"] {
            let e = camera_pose(bad).unwrap_err();
            assert!(e.contains("apart"), "{bad}: {e}");
        }
        assert!(camera_pose("1e9,0,0,0,0,0").unwrap_err().contains("within"));
    }

    #[test]
    fn nonsense_is_refused() {
        for bad in ["nan", "inf", "-1", "0", "x", ""] {
            assert!(positive(bad).is_err(), "{bad}");
        }
        assert_eq!(positive("3e-4").unwrap(), 3e-4);
        assert!(positive_f32("1e300").is_err());
        assert!(weight("-1").is_err() && weight("NaN").is_err());
        assert_eq!(weight("0").unwrap(), 0.0);
        assert!(field_angle("90").is_err() && field_angle("0").is_err());
        assert!(llffhold("1").is_err());
        assert_eq!(psf_px_range(" 85-140").unwrap(), [85, 140]);
        for bad in ["85", "140-85", "0-10", "10-99999", "a-b", "-5-10"] {
            assert!(psf_px_range(bad).is_err(), "{bad}");
        }
        assert_eq!(llffhold("0").unwrap(), 0);
        assert_eq!(colour("white").unwrap(), [1.0; 3]);
        assert_eq!(colour("0.5, 0.25,1").unwrap(), [0.5, 0.25, 1.0]);
        for bad in ["1,2", "0.5,0.5,1.5", "grey", "0,0,nan", "0,0,0,0"] {
            assert!(colour(bad).is_err(), "{bad}");
        }
    }
}
