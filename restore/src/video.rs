//! Scores of a restored clip against its clean one: per frame PSNR and SSIM, and how much the
//! restoration flickers. Frame-by-frame restoration can change from one frame to the next where
//! the scene does not; the clean clip's own motion is the reference for how much consecutive
//! frames should differ.

use aberration::Image;

use crate::error::{RestoreError, Result};

/// Mean absolute difference of two images of one size, over every value.
fn mean_abs_diff(a: &Image, b: &Image) -> f64 {
    a.data
        .iter()
        .zip(&b.data)
        .map(|(x, y)| (*x as f64 - *y as f64).abs())
        .sum::<f64>()
        / a.data.len().max(1) as f64
}

/// Mean over consecutive frames of their mean absolute difference (0 for fewer than two).
pub fn frame_to_frame(frames: &[Image]) -> f64 {
    if frames.len() < 2 {
        return 0.0;
    }
    frames
        .windows(2)
        .map(|w| mean_abs_diff(&w[0], &w[1]))
        .sum::<f64>()
        / (frames.len() - 1) as f64
}

/// Flicker of a restored clip: how much more its consecutive frames differ than the clean
/// clip's do ([`frame_to_frame`] of `restored` minus that of `clean`, in [0, 1] units). Zero
/// for a clip equal to its clean one; grows with frame-to-frame changes the scene does not
/// have. Clips of different lengths or frame sizes are refused.
pub fn flicker(restored: &[Image], clean: &[Image]) -> Result<f64> {
    check_clips(restored, clean)?;
    Ok(frame_to_frame(restored) - frame_to_frame(clean))
}

/// Temporal error of a restored clip: the mean absolute difference between its
/// frame-to-frame changes and the clean clip's, `|(r_t − r_{t−1}) − (c_t − c_{t−1})|` over
/// every value and consecutive pair, in [0, 1] units. An error that stays put from frame to
/// frame (a constant offset, a fixed blur of a still scene) does not count; flicker does, and
/// so does motion smoothed away, which [`flicker`] sees as negative (a blurred clip changes
/// less than the clean one). Zero for fewer than two frames; clips that differ in length or
/// size are refused.
pub fn temporal_error(restored: &[Image], clean: &[Image]) -> Result<f64> {
    check_clips(restored, clean)?;
    if clean.len() < 2 {
        return Ok(0.0);
    }
    let pairs = (1..clean.len()).map(|t| {
        let (r0, r1, c0, c1) = (&restored[t - 1], &restored[t], &clean[t - 1], &clean[t]);
        (0..c1.data.len())
            .map(|k| {
                let dr = r1.data[k] as f64 - r0.data[k] as f64;
                let dc = c1.data[k] as f64 - c0.data[k] as f64;
                (dr - dc).abs()
            })
            .sum::<f64>()
            / c1.data.len().max(1) as f64
    });
    Ok(pairs.sum::<f64>() / (clean.len() - 1) as f64)
}

/// Refuses clips of different lengths, a restored frame of another size than its clean one,
/// and a clip whose frames differ in size.
fn check_clips(restored: &[Image], clean: &[Image]) -> Result<()> {
    if restored.len() != clean.len() {
        return Err(RestoreError::BadInput(format!(
            "the restored clip has {} frames and the clean one {}",
            restored.len(),
            clean.len()
        )));
    }
    if let Some((i, _)) = restored
        .iter()
        .zip(clean)
        .enumerate()
        .find(|(_, (r, c))| (r.width, r.height) != (c.width, c.height))
    {
        return Err(RestoreError::BadInput(format!(
            "frame {i}: the restored frame is {}x{} and the clean one {}x{}",
            restored[i].width, restored[i].height, clean[i].width, clean[i].height
        )));
    }
    if let Some(i) = (1..clean.len())
        .find(|&i| (clean[i].width, clean[i].height) != (clean[0].width, clean[0].height))
    {
        return Err(RestoreError::BadInput(format!(
            "frame {i} is {}x{}, frame 0 {}x{}: a clip's frames are of one size",
            clean[i].width, clean[i].height, clean[0].width, clean[0].height
        )));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A clip of a bright square moving right one pixel a frame.
    fn clip(frames: usize) -> Vec<Image> {
        (0..frames)
            .map(|t| {
                let mut im = Image::new(16, 12);
                for c in 0..3 {
                    for y in 3..8 {
                        for x in (2 + t)..(7 + t) {
                            im.data[c * 16 * 12 + y * 16 + x] = 0.8;
                        }
                    }
                }
                im
            })
            .collect()
    }

    #[test]
    fn flicker_is_zero_for_the_clean_clip_and_grows_with_added_flicker() {
        let clean = clip(6);
        assert_eq!(flicker(&clean, &clean).unwrap(), 0.0);
        // The scene's own motion is not flicker: the clean clip moves, yet scores zero, and a
        // still clip scores below it.
        assert!(frame_to_frame(&clean) > 0.0);
        let mut last = 0.0;
        for amount in [0.01f32, 0.03, 0.1] {
            // Every other frame brighter by `amount`: a flicker the scene does not have.
            let flickering: Vec<Image> = clean
                .iter()
                .enumerate()
                .map(|(t, im)| Image {
                    data: im
                        .data
                        .iter()
                        .map(|v| v + if t % 2 == 0 { amount } else { 0.0 })
                        .collect(),
                    ..im.clone()
                })
                .collect();
            let f = flicker(&flickering, &clean).unwrap();
            assert!(f > last, "flicker {amount}: {f} after {last}");
            last = f;
        }
        assert!(flicker(&clean[..3], &clean).is_err());
    }

    /// Each frame of `clip` with `f(t, value)` applied to every value.
    fn map(clip: &[Image], f: impl Fn(usize, f32) -> f32) -> Vec<Image> {
        clip.iter()
            .enumerate()
            .map(|(t, im)| Image {
                data: im.data.iter().map(|&v| f(t, v)).collect(),
                ..im.clone()
            })
            .collect()
    }

    #[test]
    fn temporal_error_counts_flicker_and_smoothed_motion_not_a_steady_error() {
        let clean = clip(6);
        assert_eq!(temporal_error(&clean, &clean).unwrap(), 0.0);
        // An error that stays put: no temporal error, whatever its size.
        let offset = map(&clean, |_, v| v + 0.1);
        assert!(temporal_error(&offset, &clean).unwrap() < 1e-7);
        // Contrast lowered to 0.7: what is lost of the motion is the temporal error.
        let faded = map(&clean, |_, v| v * 0.7 + 0.1);
        let steady = temporal_error(&faded, &clean).unwrap();
        let lost = 0.3 * frame_to_frame(&clean);
        assert!((steady - lost).abs() < 1e-6, "{steady} against {lost}");
        let still = map(&clean, |_, v| v * 0.0 + clean[0].data[0]);
        assert!(temporal_error(&still, &clean).unwrap() > 0.0);
        // Frames averaged with their predecessor: smoother than the clean clip, which
        // flicker scores below zero and the temporal error above it.
        let smoothed: Vec<Image> = (0..clean.len())
            .map(|t| {
                let prev = &clean[t.saturating_sub(1)];
                Image {
                    data: clean[t]
                        .data
                        .iter()
                        .zip(&prev.data)
                        .map(|(a, b)| 0.5 * (a + b))
                        .collect(),
                    ..clean[t].clone()
                }
            })
            .collect();
        assert!(flicker(&smoothed, &clean).unwrap() < 0.0);
        assert!(temporal_error(&smoothed, &clean).unwrap() > 0.0);
        let mut last = 0.0;
        for amount in [0.01f32, 0.03, 0.1] {
            let flickering = map(&clean, |t, v| v + if t % 2 == 0 { amount } else { 0.0 });
            let e = temporal_error(&flickering, &clean).unwrap();
            assert!((e - amount as f64).abs() < 1e-6, "flicker {amount}: {e}");
            assert!(e > last);
            last = e;
        }
        assert!(temporal_error(&clean[..3], &clean).is_err());
        assert_eq!(temporal_error(&clean[..1], &clean[..1]).unwrap(), 0.0);
    }
}
