//! LLFF's `poses_bounds.npy`: reading, writing, and conversion to [`Camera`].
//!
//! # The file
//!
//! An `N x 17` float array (f64 or f32), one row per image in sorted-file-name order. The first
//! 15 values are a row-major `3 x 5` matrix: columns 0..3 are the camera's *down*, *right* and
//! *back* axes in world coordinates, column 3 is the camera centre, column 4 is
//! `[height, width, focal]` of the full-resolution images. Values 15 and 16 are near and far.
//!
//! # Conversion to the OpenCV convention
//!
//! OpenCV's camera axes are right (x), down (y), forward (z), so the camera-to-world rotation is
//! `[right | down | -back] = [col1 | col0 | -col2]` and the centre is column 3. The
//! world-to-camera transform is its inverse, `R = C^T`, `t = -C^T c`. LLFF built its columns
//! from COLMAP's camera-to-world `[x | y | z]` as `[y | x | -z]`, so this recovers COLMAP's pose
//! exactly and LLFF poses share the world frame of `sparse/0/points3D.bin`. The principal point
//! is the image centre; focal lengths scale with the image size relative to `[height, width]`.

use std::path::{Path, PathBuf};

use glam::{DMat3, DVec3};
use npyz::WriterBuilder;

use crate::atomic;
use crate::camera::{Bounds, Camera, Rigid};
use crate::error::{Result, SceneError};
use crate::images::{self, BitDepth, Photo};

pub const POSES_BOUNDS: &str = "poses_bounds.npy";

/// One row of `poses_bounds.npy`, in LLFF's own terms.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LlffPose {
    /// Columns: down, right, back axes of the camera in world coordinates.
    pub axes: DMat3,
    pub center: DVec3,
    /// Full-resolution image height and width in pixels.
    pub height: f64,
    pub width: f64,
    /// Full-resolution focal length in pixels.
    pub focal: f64,
    pub bounds: Bounds,
}

impl LlffPose {
    /// Camera-to-world in the OpenCV convention (see the module docs).
    pub fn camera_to_world(&self) -> Rigid {
        Rigid {
            rotation: DMat3::from_cols(self.axes.y_axis, self.axes.x_axis, -self.axes.z_axis),
            translation: self.center,
        }
    }

    /// The camera for an image of `width x height` pixels of this pose.
    pub fn to_camera(&self, name: &str, width: u32, height: u32) -> Camera {
        let sx = width as f64 / self.width;
        let sy = height as f64 / self.height;
        Camera {
            name: name.to_string(),
            width,
            height,
            fx: self.focal * sx,
            fy: self.focal * sy,
            cx: width as f64 / 2.0,
            cy: height as f64 / 2.0,
            world_to_camera: self.camera_to_world().inverse(),
            distortion: None,
        }
    }

    /// The LLFF row of a camera whose images are `downsample` times smaller than the
    /// full-resolution size the row records. LLFF can only express one focal length and a
    /// centred principal point; anything else is refused with the reason.
    pub fn from_camera(
        camera: &Camera,
        bounds: Bounds,
        downsample: f64,
    ) -> std::result::Result<LlffPose, String> {
        let tol = 1e-9 * camera.fx.abs().max(1.0);
        if (camera.fx - camera.fy).abs() > tol {
            return Err(format!(
                "camera {} has fx {} != fy {}; LLFF stores one focal length",
                camera.name, camera.fx, camera.fy
            ));
        }
        let (w, h) = (camera.width as f64, camera.height as f64);
        if (camera.cx - w / 2.0).abs() > 1e-9 * w || (camera.cy - h / 2.0).abs() > 1e-9 * h {
            return Err(format!(
                "camera {} has principal point ({}, {}), LLFF requires the centre ({}, {})",
                camera.name,
                camera.cx,
                camera.cy,
                w / 2.0,
                h / 2.0
            ));
        }
        let c2w = camera.camera_to_world();
        let r = c2w.rotation;
        Ok(LlffPose {
            axes: DMat3::from_cols(r.y_axis, r.x_axis, -r.z_axis),
            center: c2w.translation,
            height: h * downsample,
            width: w * downsample,
            focal: camera.fx * downsample,
            bounds,
        })
    }

    fn to_row(self) -> [f64; 17] {
        let mut row = [0.0; 17];
        let cols = [
            self.axes.x_axis,
            self.axes.y_axis,
            self.axes.z_axis,
            self.center,
            DVec3::new(self.height, self.width, self.focal),
        ];
        for (c, col) in cols.iter().enumerate() {
            for r in 0..3 {
                row[r * 5 + c] = col[r];
            }
        }
        row[15] = self.bounds.near;
        row[16] = self.bounds.far;
        row
    }

    fn from_row(row: &[f64]) -> LlffPose {
        let col = |c: usize| DVec3::new(row[c], row[5 + c], row[10 + c]);
        let hwf = col(4);
        LlffPose {
            axes: DMat3::from_cols(col(0), col(1), col(2)),
            center: col(3),
            height: hwf.x,
            width: hwf.y,
            focal: hwf.z,
            bounds: Bounds {
                near: row[15],
                far: row[16],
            },
        }
    }
}

/// Reads and validates `poses_bounds.npy`: shape `N x 17` (its size checked against the file
/// before allocation), f64 or f32, C or Fortran order, finite values, orthonormal axes, sizes
/// and focal within [`crate::limits`], `0 < near < far`.
pub fn read_poses_bounds(path: &Path) -> Result<Vec<LlffPose>> {
    if !path.exists() {
        return Err(SceneError::NotFound {
            path: path.to_path_buf(),
            what: "LLFF poses file".into(),
        });
    }
    // Sizes are checked against the file and base::limits::MAX_NPY_BYTES before allocation.
    let npy = base::npy::read_f64(path).map_err(|e| match e {
        base::npy::NpyError::Io { path, source } => SceneError::io(path, source),
        other => SceneError::Npy(other),
    })?;
    let shape = npy.shape;
    if shape.len() != 2 || shape[1] != 17 {
        return Err(SceneError::invalid(
            path,
            format!("array shape is {shape:?}, expected [N, 17]"),
        ));
    }
    let rows = shape[0] as usize;
    let fortran = npy.fortran;
    let values = npy.values;
    let mut poses = Vec::with_capacity(rows);
    for r in 0..rows {
        let row: Vec<f64> = (0..17)
            .map(|c| {
                if fortran {
                    values[c * rows + r]
                } else {
                    values[r * 17 + c]
                }
            })
            .collect();
        if let Some(column) = row.iter().position(|v| !v.is_finite()) {
            return Err(SceneError::NonFinite {
                path: path.to_path_buf(),
                row: r,
                column,
            });
        }
        let pose = LlffPose::from_row(&row);
        validate(&pose).map_err(|p| SceneError::invalid(path, format!("row {r}: {p}")))?;
        poses.push(pose);
    }
    Ok(poses)
}

fn validate(pose: &LlffPose) -> std::result::Result<(), String> {
    let gram = pose.axes.transpose() * pose.axes;
    let off = (gram - DMat3::IDENTITY).to_cols_array();
    if off.iter().any(|v| v.abs() > 1e-3) {
        return Err("down/right/back axes are not orthonormal".into());
    }
    // A reflection here would mirror every image.
    if pose.camera_to_world().rotation.determinant() < 0.0 {
        return Err("down/right/back axes form a left-handed frame".into());
    }
    if pose.height <= 0.0 || pose.width <= 0.0 || pose.focal <= 0.0 {
        return Err(format!(
            "height {}, width {}, focal {} must be positive",
            pose.height, pose.width, pose.focal
        ));
    }
    crate::limits::check_size(pose.width, pose.height)?;
    let (w, h) = (pose.width, pose.height);
    crate::limits::check_intrinsics(w, h, pose.focal, pose.focal, w / 2.0, h / 2.0)?;
    crate::limits::check_bounds(pose.bounds.near, pose.bounds.far)?;
    crate::limits::check_point(pose.center.to_array()).map_err(|p| format!("camera {p}"))?;
    Ok(())
}

/// Writes `poses_bounds.npy` as little-endian f64, C order, under a temporary name first.
pub fn write_poses_bounds(path: &Path, poses: &[LlffPose]) -> Result<()> {
    atomic::write_file(path, |w| {
        let io = |e| SceneError::io(path, e);
        let mut npy = npyz::WriteOptions::<f64>::new()
            .default_dtype()
            .shape(&[poses.len() as u64, 17])
            .writer(w)
            .begin_nd()
            .map_err(io)?;
        for pose in poses {
            npy.extend(pose.to_row()).map_err(io)?;
        }
        npy.finish().map_err(io)
    })
}

/// The image folder LLFF uses for a downsampling factor: `images` or `images_N`.
pub fn image_folder_name(downsample: u32) -> String {
    if downsample <= 1 {
        "images".to_string()
    } else {
        format!("images_{downsample}")
    }
}

/// Builds an LLFF directory in a hidden staging folder next to the destination and renames it
/// into place on [`LlffWriter::finish`]; dropping the writer earlier deletes the staging
/// folder, so an interrupted run leaves no half scene.
pub struct LlffWriter {
    staging: tempfile::TempDir,
    dest: PathBuf,
    downsample: u32,
    depth: BitDepth,
    entries: Vec<(String, LlffPose)>,
}

impl LlffWriter {
    /// Starts a capture whose images go to `images_{downsample}/` (or `images/` for 1) while
    /// `poses_bounds.npy` records the size `downsample` times larger, as LLFF does.
    pub fn create(dest: &Path, downsample: u32, depth: BitDepth) -> Result<LlffWriter> {
        if dest.exists() {
            return Err(SceneError::invalid(
                dest,
                "already exists; refusing to overwrite a scene",
            ));
        }
        let parent = match dest.parent() {
            Some(p) if !p.as_os_str().is_empty() => p,
            _ => Path::new("."),
        };
        std::fs::create_dir_all(parent).map_err(|e| SceneError::io(parent, e))?;
        // What a killed run left beside its scene goes before this one stages its own.
        base::remove_orphans(parent);
        let staging = tempfile::Builder::new()
            .prefix(&format!("{}scene-", base::temp_prefix()))
            .tempdir_in(parent)
            .map_err(|e| SceneError::io(parent, e))?;
        let images = staging.path().join(image_folder_name(downsample));
        std::fs::create_dir(&images).map_err(|e| SceneError::io(&images, e))?;
        Ok(LlffWriter {
            staging,
            dest: dest.to_path_buf(),
            downsample: downsample.max(1),
            depth,
            entries: Vec::new(),
        })
    }

    /// The staging folder, for extra files (clean images, PSFs) that must appear atomically
    /// with the scene.
    pub fn staging_dir(&self) -> &Path {
        self.staging.path()
    }

    /// Writes `image` as `<camera.name>.png` and records its pose.
    pub fn add(&mut self, camera: &Camera, bounds: Bounds, image: &Photo) -> Result<()> {
        let path = self
            .staging
            .path()
            .join(image_folder_name(self.downsample))
            .join(format!("{}.png", camera.name));
        if (image.width, image.height) != (camera.width, camera.height) {
            return Err(SceneError::invalid(
                &path,
                format!(
                    "image is {}x{} but camera {} is {}x{}",
                    image.width, image.height, camera.name, camera.width, camera.height
                ),
            ));
        }
        if self.entries.iter().any(|(n, _)| *n == camera.name) {
            return Err(SceneError::invalid(&path, "two cameras share this name"));
        }
        let pose = LlffPose::from_camera(camera, bounds, self.downsample as f64)
            .map_err(|p| SceneError::invalid(&path, p))?;
        images::write_png(&path, image, self.depth)?;
        self.entries.push((camera.name.clone(), pose));
        Ok(())
    }

    /// Writes `poses_bounds.npy` (rows in file-name order, the order readers match them in)
    /// and moves the finished scene to its destination.
    pub fn finish(mut self) -> Result<PathBuf> {
        self.entries.sort_by(|a, b| {
            format!("{}.png", a.0)
                .as_bytes()
                .cmp(format!("{}.png", b.0).as_bytes())
        });
        let poses: Vec<LlffPose> = self.entries.iter().map(|e| e.1).collect();
        write_poses_bounds(&self.staging.path().join(POSES_BOUNDS), &poses)?;
        let staging = self.staging.keep();
        std::fs::rename(&staging, &self.dest).map_err(|e| {
            let _ = std::fs::remove_dir_all(&staging);
            SceneError::io(&self.dest, e)
        })?;
        Ok(self.dest)
    }
}

/// Writes a whole LLFF capture in one call; see [`LlffWriter`].
pub fn write_llff(
    dest: &Path,
    cameras: &[Camera],
    bounds: &[Bounds],
    images: &[Photo],
    downsample: u32,
    depth: BitDepth,
) -> Result<PathBuf> {
    if cameras.len() != bounds.len() || cameras.len() != images.len() {
        return Err(SceneError::invalid(
            dest,
            format!(
                "{} cameras, {} bounds and {} images must match in number",
                cameras.len(),
                bounds.len(),
                images.len()
            ),
        ));
    }
    let mut writer = LlffWriter::create(dest, downsample, depth)?;
    for ((camera, &b), image) in cameras.iter().zip(bounds).zip(images) {
        writer.add(camera, b, image)?;
    }
    writer.finish()
}
