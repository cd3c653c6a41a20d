//! nerfstudio's `transforms.json` (what `ns-process-data`, Polycam, Record3D and many capture
//! apps write): shared or per-frame pinhole intrinsics (`fl_x`, `fl_y`, `cx`, `cy`, `w`, `h`,
//! OpenCV's `k1 k2 p1 p2` kept for reporting as COLMAP's are), and per frame a `file_path`
//! relative to the file and a camera-to-world `transform_matrix` in nerfstudio's (OpenGL)
//! convention: x right, y up, the camera looking down its −z. Ours is OpenCV's (y down,
//! looking down +z), so the camera's y and z axes flip.
//!
//! Resolution: a frame's `images/NAME` is read from `images_N/NAME` at downsample N, and the
//! intrinsics are scaled to the size the photo has. `file_path`s that leave the capture's
//! folder (`..`, absolute paths) are refused, as COLMAP image names are.
//!
//! Points: `ply_file_path` (relative to the file, inside the capture) names the initial
//! points, in the frames' world ([`crate::point_ply`]); without it they are random in the
//! frusta. Bounds: the format has no near/far, so each camera's bounds come from the rig:
//! with `r` the largest distance of a camera from the cameras' centroid, near is `r / 100`
//! and far `4 r` (`r` 1 for a single camera), wide enough for a ring around an object or a
//! forward-facing sweep.

use std::path::{Component, Path, PathBuf};

use glam::{DMat3, DVec3};
use serde_json::Value;

use crate::camera::{Bounds, Camera, CameraModel, Distortion, Rigid};
use crate::error::{Result, SceneError};
use crate::images;
use crate::limits;

/// The file's name in a capture folder.
pub const TRANSFORMS: &str = "transforms.json";

/// What a `transforms.json` holds: its frames, in the order of the file, and the point
/// cloud it names.
pub struct Transforms {
    pub frames: Vec<Frame>,
    pub ply_file: Option<PathBuf>,
}

/// One frame: its photo and its camera at the photo's size.
pub struct Frame {
    pub path: PathBuf,
    pub camera: Camera,
    /// The frame's `mask_path` (white = keep), inside the capture: `masks_N/` at
    /// `downsample` N when that copy exists, else the file as named (shrunk at load).
    pub mask: Option<PathBuf>,
}

/// A number of the frame, else of the file (nerfstudio allows both), else `default`.
/// The frame's value of `key`, else the file's; a value that is there but not a number is
/// an error, not an absent key.
fn number(frame: &Value, doc: &Value, key: &str) -> std::result::Result<Option<f64>, String> {
    let v = match &frame[key] {
        Value::Null => &doc[key],
        v => v,
    };
    match v {
        Value::Null => Ok(None),
        v => v
            .as_f64()
            .map(Some)
            .ok_or_else(|| format!("{key} is {v}, not a number")),
    }
}

/// The photo file a frame names at `downsample` (1: as written).
fn frame_path(root: &Path, file: &str, downsample: u32) -> std::result::Result<PathBuf, String> {
    let rel = Path::new(file);
    if rel
        .components()
        .any(|c| !matches!(c, Component::Normal(_) | Component::CurDir))
    {
        return Err(format!(
            "{file:?} leaves the capture's folder (absolute or with ..); only files inside it are read"
        ));
    }
    let mut parts = rel
        .components()
        .filter(|c| matches!(c, Component::Normal(_)));
    let first = parts
        .next()
        .map(|c| c.as_os_str().to_string_lossy().into_owned());
    Ok(match (downsample, first.as_deref()) {
        (1, _) | (_, None) => root.join(rel),
        (n, Some("images")) => {
            let mut p = root.join(format!("images_{n}"));
            p.extend(parts);
            p
        }
        (n, Some(_)) => {
            return Err(format!(
                "{file:?} is not under images/, so there is no images_{n}/ copy of it"
            ));
        }
    })
}

/// A frame's `mask_path` at `downsample`: inside the capture, under `masks_N/` when the
/// path starts with `masks/` and that copy exists (as `ns-process-data` writes them), else as
/// named (a full-size mask, shrunk with the photo at load).
fn mask_path(root: &Path, file: &str, downsample: u32) -> std::result::Result<PathBuf, String> {
    let full = frame_path(root, file, 1)?;
    if downsample > 1 {
        let rel = Path::new(file);
        let mut parts = rel
            .components()
            .filter(|c| matches!(c, Component::Normal(_)));
        if parts.next().is_some_and(|c| c.as_os_str() == "masks") {
            let mut p = root.join(format!("masks_{downsample}"));
            p.extend(parts);
            if p.is_file() {
                return Ok(p);
            }
        }
    }
    Ok(full)
}

/// Reads `root/transforms.json`: each frame's photo path (at `downsample`) and camera, in the
/// order of the file, and the point cloud it names. Errors name the file, the frame and the
/// problem.
pub fn read_transforms(root: &Path, downsample: u32) -> Result<Transforms> {
    let path = root.join(TRANSFORMS);
    SceneError::check_file_size(&path, base::limits::MAX_TEXT_FILE_BYTES)?;
    let text = base::input::read_to_string(&path).map_err(|e| SceneError::io(&path, e))?;
    let doc: Value = serde_json::from_str(&text)
        .map_err(|e| SceneError::invalid(&path, format!("not JSON: {e}")))?;
    let Some(frames) = doc["frames"].as_array().filter(|f| !f.is_empty()) else {
        return Err(SceneError::invalid(&path, "no frames"));
    };
    match &doc["camera_model"] {
        Value::Null => {}
        Value::String(m) if m == "OPENCV" || m == "PINHOLE" => {}
        Value::String(m) => {
            return Err(SceneError::UnknownCameraModel {
                path: path.clone(),
                model: format!("{m} (camera_model; OPENCV and PINHOLE are read)"),
            });
        }
        v => {
            return Err(SceneError::invalid(
                &path,
                format!("camera_model is {v}, not a model's name (OPENCV or PINHOLE)"),
            ));
        }
    }
    let ply_file = match &doc["ply_file_path"] {
        Value::Null => None,
        Value::String(file) => {
            let ply = frame_path(root, file, 1)
                .map_err(|p| SceneError::invalid(&path, format!("ply_file_path {p}")))?;
            if !ply.is_file() {
                return Err(SceneError::NotFound {
                    path: ply,
                    what: format!("point cloud named by ply_file_path in {}", path.display()),
                });
            }
            Some(ply)
        }
        v => {
            return Err(SceneError::invalid(
                &path,
                format!("ply_file_path is {v}, not a file name"),
            ));
        }
    };
    let mut out = Vec::with_capacity(frames.len());
    let mut seen = std::collections::HashMap::new();
    for (i, frame) in frames.iter().enumerate() {
        let bad = |problem: String| SceneError::invalid(&path, format!("frame {i}: {problem}"));
        let file = frame["file_path"]
            .as_str()
            .ok_or_else(|| bad("no file_path".into()))?;
        let photo =
            frame_path(root, file, downsample).map_err(|p| bad(format!("file_path {p}")))?;
        if !photo.is_file() {
            return Err(SceneError::NotFound {
                path: photo,
                what: format!("photo of frame {i} in {}", path.display()),
            });
        }
        if let Some(first) = seen.insert(photo.clone(), i) {
            return Err(bad(format!(
                "names the photo of frame {first} ({}) again",
                photo.display()
            )));
        }
        let need = |key: &str| {
            number(frame, &doc, key)
                .map_err(&bad)?
                .ok_or_else(|| bad(format!("no {key}")))
        };
        let (w, h) = (need("w")?, need("h")?);
        let (fx, fy, cx, cy) = (need("fl_x")?, need("fl_y")?, need("cx")?, need("cy")?);
        limits::check_size(w, h).map_err(bad)?;
        limits::check_intrinsics(w, h, fx, fy, cx, cy).map_err(bad)?;
        let k =
            |key: &str| Ok::<_, SceneError>(number(frame, &doc, key).map_err(&bad)?.unwrap_or(0.0));
        // nerfstudio's radial factor is 1 + k1 r² + k2 r⁴ + k3 r⁶ + k4 r⁸: k3 is the r⁶ term
        // FULL_OPENCV's numerator holds; an r⁸ term has no place in the model.
        let k4 = k("k4")?;
        if k4 != 0.0 {
            return Err(bad(format!(
                "k4 is {k4}: the r⁸ radial term is not modelled (k1, k2, k3, p1 and p2 are); undistort the photos first"
            )));
        }
        let distortion = Distortion {
            model: CameraModel::OpenCv,
            k1: k("k1")?,
            k2: k("k2")?,
            p1: k("p1")?,
            p2: k("p2")?,
            rational: [k("k3")?, 0.0, 0.0, 0.0],
        };
        limits::check_distortion(&distortion).map_err(bad)?;
        limits::check_distortion_folds(&distortion, w, h, fx, fy, cx, cy).map_err(bad)?;
        let m = frame["transform_matrix"]
            .as_array()
            .filter(|rows| rows.len() >= 3)
            .ok_or_else(|| bad("no 4x4 transform_matrix".into()))?;
        let mut c2w = [[0.0f64; 4]; 3];
        for (r, row) in m.iter().take(3).enumerate() {
            let row = row
                .as_array()
                .filter(|v| v.len() == 4)
                .ok_or_else(|| bad(format!("transform_matrix row {r} is not 4 numbers")))?;
            for (c, v) in row.iter().enumerate() {
                c2w[r][c] = v.as_f64().filter(|v| v.is_finite()).ok_or_else(|| {
                    bad(format!("transform_matrix[{r}][{c}] is not a finite number"))
                })?;
            }
        }
        let (rotation, centre) =
            opengl_to_ours(&c2w).map_err(|e| bad(format!("transform_matrix: {e}")))?;
        let (pw, ph) = images::image_size(&photo)?;
        let (sx, sy) = (pw as f64 / w, ph as f64 / h);
        limits::check_downsample((w, h), (pw, ph)).map_err(bad)?;
        // Another aspect would stretch the focal unevenly.
        if !limits::same_aspect((w, h), (pw, ph)) {
            return Err(bad(format!(
                "the photo {} is {pw}x{ph} but w and h say {w}x{h} (aspect differs)",
                photo.display()
            )));
        }
        let mask = match &frame["mask_path"] {
            Value::Null => None,
            Value::String(m) => {
                Some(mask_path(root, m, downsample).map_err(|p| bad(format!("mask_path {p}")))?)
            }
            v => return Err(bad(format!("mask_path is {v}, not a file name"))),
        };
        if let Some(m) = mask.as_ref().filter(|m| !m.is_file()) {
            return Err(SceneError::NotFound {
                path: m.clone(),
                what: format!("mask of frame {i} in {}", path.display()),
            });
        }
        let name = photo
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        out.push(Frame {
            mask,
            path: photo,
            camera: Camera {
                name,
                width: pw,
                height: ph,
                fx: fx * sx,
                fy: fy * sy,
                cx: cx * sx,
                cy: cy * sy,
                world_to_camera: Rigid {
                    rotation,
                    translation: centre,
                }
                .inverse(),
                distortion: (distortion.k1, distortion.k2, distortion.p1, distortion.p2)
                    .ne(&(0.0, 0.0, 0.0, 0.0))
                    .then_some(distortion),
            },
        });
    }
    Ok(Transforms {
        frames: out,
        ply_file,
    })
}

/// The rotation (camera to world, our axes) and centre of a camera-to-world matrix in
/// nerfstudio's OpenGL axes (its first three rows), checked to be a rotation and a position.
fn opengl_to_ours(c2w: &[[f64; 4]; 3]) -> std::result::Result<(DMat3, DVec3), String> {
    // Columns: the camera's x, y, z axes in the world, then its centre.
    let axis = |c: usize| DVec3::new(c2w[0][c], c2w[1][c], c2w[2][c]);
    let rotation = DMat3::from_cols(axis(0), -axis(1), -axis(2));
    let gram = rotation.transpose() * rotation - DMat3::IDENTITY;
    if gram.to_cols_array().iter().any(|v| v.abs() > 1e-3) || rotation.determinant() < 0.0 {
        return Err("the rotation is not a rotation (not orthonormal or mirrored)".into());
    }
    let centre = axis(3);
    limits::check_point(centre.to_array()).map_err(|p| format!("camera {p}"))?;
    Ok((rotation, centre))
}

/// A camera path as nerfstudio's viewer exports it (`camera_path.json`, what `ns-render
/// camera-path` reads): `render_width`, `render_height`, optional `fps`, and per keyframe of
/// `camera_path` a camera-to-world `camera_to_world` (16 numbers, row-major, OpenGL axes as
/// in `transforms.json`) and a vertical `fov` in degrees; every frame is one camera.
pub struct CameraPath {
    pub cameras: Vec<Camera>,
    pub fps: f64,
}

/// Reads a `camera_path.json`; errors name the file, the keyframe and the problem.
pub fn read_camera_path(path: &Path) -> Result<CameraPath> {
    SceneError::check_file_size(path, base::limits::MAX_TEXT_FILE_BYTES)?;
    let text = base::input::read_to_string(path).map_err(|e| SceneError::io(path, e))?;
    let doc: Value = serde_json::from_str(&text)
        .map_err(|e| SceneError::invalid(path, format!("not JSON: {e}")))?;
    let bad = |problem: String| SceneError::invalid(path, problem);
    let size = |key: &str| {
        doc[key]
            .as_f64()
            .filter(|v| v.fract() == 0.0 && (8.0..=8192.0).contains(v))
            .map(|v| v as u32)
            .ok_or_else(|| bad(format!("{key} is {}, not a size from 8 to 8192", doc[key])))
    };
    let (w, h) = (size("render_width")?, size("render_height")?);
    let fps = match &doc["fps"] {
        Value::Null => 30.0,
        v => v
            .as_f64()
            .filter(|f| (0.1..=1000.0).contains(f))
            .ok_or_else(|| bad(format!("fps is {v}, not a rate from 0.1 to 1000")))?,
    };
    // The renderer draws pinhole frames: a path made for another camera would be drawn as
    // something it is not.
    match &doc["camera_type"] {
        Value::Null => {}
        Value::String(t) if t == "perspective" => {}
        v => {
            return Err(bad(format!(
                "camera_type is {v}: only \"perspective\" paths can be rendered (fisheye and equirectangular cameras are not drawn)"
            )));
        }
    }
    let Some(keys) = doc["camera_path"].as_array().filter(|k| !k.is_empty()) else {
        return Err(bad("no camera_path keyframes".into()));
    };
    let mut cameras = Vec::with_capacity(keys.len());
    for (i, key) in keys.iter().enumerate() {
        let at = |problem: String| bad(format!("camera_path[{i}]: {problem}"));
        let m = key["camera_to_world"]
            .as_array()
            .filter(|m| m.len() == 16)
            .ok_or_else(|| at("camera_to_world is not 16 numbers".into()))?;
        let mut rows = [[0.0f64; 4]; 4];
        for (k, v) in m.iter().enumerate() {
            rows[k / 4][k % 4] = v
                .as_f64()
                .filter(|v| v.is_finite())
                .ok_or_else(|| at(format!("camera_to_world[{k}] is not a finite number")))?;
        }
        // A rigid pose's last row is 0 0 0 1; another would be a projective map, not a camera.
        if rows[3] != [0.0, 0.0, 0.0, 1.0] {
            return Err(at(format!(
                "camera_to_world's last row is {:?}, not 0 0 0 1 (a rigid pose)",
                rows[3]
            )));
        }
        let rows = [rows[0], rows[1], rows[2]];
        let (rotation, centre) = opengl_to_ours(&rows).map_err(at)?;
        let fov = key["fov"]
            .as_f64()
            .filter(|f| *f > 0.0 && *f < 180.0)
            .ok_or_else(|| at(format!("fov is {}, not degrees in (0, 180)", key["fov"])))?;
        let f = h as f64 / 2.0 / (fov.to_radians() / 2.0).tan();
        cameras.push(Camera {
            name: format!("frame{i:05}"),
            width: w,
            height: h,
            fx: f,
            fy: f,
            cx: w as f64 / 2.0,
            cy: h as f64 / 2.0,
            world_to_camera: Rigid {
                rotation,
                translation: centre,
            }
            .inverse(),
            distortion: None,
        });
    }
    Ok(CameraPath { cameras, fps })
}

/// Near/far bounds for cameras without scene points (see the module docs).
pub fn rig_bounds(cameras: &[Camera]) -> Vec<Bounds> {
    let centres: Vec<DVec3> = cameras
        .iter()
        .map(|c| c.camera_to_world().translation)
        .collect();
    let centroid = centres.iter().copied().sum::<DVec3>() / centres.len().max(1) as f64;
    let r = centres
        .iter()
        .map(|c| c.distance(centroid))
        .fold(0.0, f64::max);
    let r = if r > 0.0 { r } else { 1.0 };
    vec![
        Bounds {
            near: r / 100.0,
            far: 4.0 * r,
        };
        cameras.len()
    ]
}
