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
        if path.is_dir() {
            return Err(SplatError::Ply {
                path: path.to_path_buf(),
                problem: "is a folder, not a splat file (.ply, .glb, .gltf or .spz)".into(),
            });
        }
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

/// Largest magnitude of any stored value of a splat (a coordinate, a colour coefficient, a
/// rotation component, an opacity logit): squared or summed over many splats, a value must
/// stay far from f32's overflow, or every render of it, and every loss against it, is
/// infinite.
pub const MAX_POSITION: f32 = 1e8;

/// Refuses a scene holding a value beyond [`MAX_POSITION`], naming the splat and what holds it.
fn check_positions(path: &Path, g: &Gaussians) -> Result<(), SplatError> {
    let ok = |v: f32| v.is_finite() && v.abs() <= MAX_POSITION;
    let bad = |i: usize, what: &str, value: String| SplatError::Ply {
        path: path.to_path_buf(),
        problem: format!(
            "splat {i} has {what} {value}; every value must be finite and within ±{MAX_POSITION:e}"
        ),
    };
    if let Some(i) = g
        .means
        .iter()
        .position(|p| !p.to_array().into_iter().all(ok))
    {
        return Err(SplatError::Ply {
            path: path.to_path_buf(),
            problem: format!(
                "splat {i} lies at {}; positions must be finite and within ±{MAX_POSITION:e}",
                g.means[i]
            ),
        });
    }
    if let Some(i) = g
        .sh_dc
        .iter()
        .position(|c| !c.to_array().into_iter().all(ok))
    {
        return Err(bad(
            i,
            "base colour (SH band 0)",
            format!("{:?}", g.sh_dc[i].to_array()),
        ));
    }
    let per = g.sh_rest.len().checked_div(g.len()).unwrap_or(0).max(1);
    if let Some(j) = g
        .sh_rest
        .iter()
        .position(|c| !c.to_array().into_iter().all(ok))
    {
        return Err(bad(
            j / per,
            "a higher SH coefficient",
            g.sh_rest[j].to_string(),
        ));
    }
    if let Some(i) = g.rotations.iter().position(|q| !q.iter().all(|&v| ok(v))) {
        return Err(bad(i, "rotation", format!("{:?}", g.rotations[i])));
    }
    // A zero quaternion is no rotation: renderers normalise it to NaN or to the identity,
    // each differently.
    if let Some(i) = g
        .rotations
        .iter()
        .position(|q| q.iter().map(|&v| v as f64 * v as f64).sum::<f64>() == 0.0)
    {
        return Err(SplatError::Ply {
            path: path.to_path_buf(),
            problem: format!(
                "splat {i} has the rotation quaternion {:?}, of length zero: no rotation",
                g.rotations[i]
            ),
        });
    }
    if let Some(i) = g.logit_opacities.iter().position(|&v| !ok(v)) {
        return Err(bad(
            i,
            "opacity logit",
            format!("{:?}", g.logit_opacities[i]),
        ));
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
