//! Splat files by their extension: `.ply` (INRIA layout), `.glb` and `.gltf`
//! (`KHR_gaussian_splatting`) and `.spz` (Niantic's compressed format).

use std::path::Path;

use crate::error::SplatError;
use crate::model::Gaussians;

/// The formats a scene can be read from and written to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    Ply,
    Glb,
    Gltf,
    Spz,
}

impl Format {
    /// The format of `path`, from its extension.
    pub fn of(path: &Path) -> Result<Format, SplatError> {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase);
        match ext.as_deref() {
            Some("ply") => Ok(Format::Ply),
            Some("glb") => Ok(Format::Glb),
            Some("gltf") => Ok(Format::Gltf),
            Some("spz") => Ok(Format::Spz),
            _ => Err(SplatError::Ply {
                path: path.to_path_buf(),
                problem: "unknown splat file type (use .ply, .glb, .gltf or .spz)".into(),
            }),
        }
    }
}

/// Reads a splat scene of any supported format.
pub fn read_splats(path: impl AsRef<Path>) -> Result<Gaussians, SplatError> {
    let path = path.as_ref();
    let g = match Format::of(path)? {
        Format::Ply => crate::formats::ply::read_ply(path),
        Format::Glb => crate::formats::glb::read_glb(path),
        Format::Gltf => crate::formats::glb::read_gltf(path),
        Format::Spz => crate::formats::spz::read_spz(path),
    }?;
    check_positions(path, &g)?;
    Ok(g)
}

/// Farthest a splat may lie from the origin on any axis: squared, a coordinate must stay far
/// from f32's overflow, or every projection of it is infinite.
pub const MAX_POSITION: f32 = 1e8;

/// Refuses a scene with a splat beyond [`MAX_POSITION`], naming the splat.
fn check_positions(path: &Path, g: &Gaussians) -> Result<(), SplatError> {
    if let Some(i) = g
        .means
        .iter()
        .position(|p| !(p.is_finite() && p.abs().max_element() <= MAX_POSITION))
    {
        return Err(SplatError::Ply {
            path: path.to_path_buf(),
            problem: format!(
                "splat {i} lies at {}; positions must be finite and within ±{MAX_POSITION:e}",
                g.means[i]
            ),
        });
    }
    Ok(())
}

/// [`read_splats`], reporting `(bytes_read, file_len)` while a PLY streams in; the other
/// formats are read whole and report once at the end.
pub fn read_splats_reporting(
    path: impl AsRef<Path>,
    progress: &dyn Fn(u64, u64),
) -> Result<Gaussians, SplatError> {
    let path = path.as_ref();
    if Format::of(path)? == Format::Ply {
        let g = crate::formats::ply::read_ply_reporting(path, progress)?;
        check_positions(path, &g)?;
        return Ok(g);
    }
    let g = read_splats(path)?;
    let len = std::fs::metadata(path).map_or(0, |m| m.len());
    progress(len, len);
    Ok(g)
}

/// Writes a splat scene in the format its extension names (atomically).
pub fn write_splats(path: impl AsRef<Path>, g: &Gaussians) -> Result<(), SplatError> {
    let path = path.as_ref();
    match Format::of(path)? {
        Format::Ply => crate::formats::ply::write_ply(path, g),
        Format::Glb => crate::formats::glb::write_glb(path, g),
        Format::Gltf => crate::formats::glb::write_gltf(path, g),
        Format::Spz => crate::formats::spz::write_spz(path, g),
    }
}
