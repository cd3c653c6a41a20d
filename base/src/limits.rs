//! The size limits every file reader checks before it reserves memory, in one place. A size
//! read from a header (a shape, a count) is multiplied with overflow checks and compared with
//! both the bytes the file actually holds and these limits; a refusal names the file and the
//! limit. The limits are far above any real input (the paper's PSF grid is 17.7 MB, fern's
//! COLMAP model a few MB) and far below what would exhaust a workstation.

/// Most bytes of array data a `.npy` file may hold (PSF grids, `poses_bounds.npy`): 1 GiB.
pub const MAX_NPY_BYTES: u64 = 1 << 30;

/// Most bytes of a COLMAP model file (`cameras`, `images`, `points3D`, `.bin` or `.txt`),
/// which is read whole: 2 GiB.
pub const MAX_MODEL_FILE_BYTES: u64 = 2 << 30;

/// Most bytes of a small text or JSON side file (`aberration.json`, `config.json`, a weights
/// file's header): 16 MiB.
pub const MAX_TEXT_FILE_BYTES: u64 = 16 << 20;

/// Most pixels of a photo or image decoded (from its header, before decoding): 64 Mi pixels,
/// 768 MiB as the float RGB every stage works in. A full-resolution LLFF photo has 12 M.
pub const MAX_IMAGE_PIXELS: u64 = 1 << 26;

/// Refuses an image whose header claims more than [`MAX_IMAGE_PIXELS`], before a byte of it
/// is decoded (a few hundred compressed bytes can claim gigabytes).
pub fn check_image_pixels(width: u32, height: u32) -> Result<(), String> {
    let pixels = width as u64 * height as u64;
    if pixels > MAX_IMAGE_PIXELS {
        return Err(format!(
            "the image header claims {width}x{height} pixels, more than the {} Mi pixels an image may have",
            MAX_IMAGE_PIXELS >> 20
        ));
    }
    Ok(())
}

/// The product of `dims` and then `item_bytes`, `None` on overflow.
pub fn checked_bytes(dims: &[u64], item_bytes: u64) -> Option<u64> {
    dims.iter()
        .try_fold(1u64, |acc, &d| acc.checked_mul(d))?
        .checked_mul(item_bytes)
}

/// `bytes` as a human-readable size (`1 GiB`, `17.7 MB`), for refusals.
pub fn describe_bytes(bytes: u64) -> String {
    const GIB: u64 = 1 << 30;
    const MIB: u64 = 1 << 20;
    if bytes >= GIB && bytes.is_multiple_of(GIB) {
        format!("{} GiB", bytes / GIB)
    } else if bytes >= MIB && bytes.is_multiple_of(MIB) {
        format!("{} MiB", bytes / MIB)
    } else {
        format!("{bytes} bytes")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn products_overflow_to_none() {
        assert_eq!(checked_bytes(&[81, 135, 135, 3], 4), Some(17_714_700));
        assert_eq!(checked_bytes(&[], 8), Some(8));
        assert_eq!(checked_bytes(&[1 << 32, 1 << 32], 1), None);
        assert_eq!(checked_bytes(&[1 << 31, 1 << 31], 4), None);
        assert_eq!(describe_bytes(MAX_NPY_BYTES), "1 GiB");
        assert_eq!(describe_bytes(MAX_TEXT_FILE_BYTES), "16 MiB");
    }
}
