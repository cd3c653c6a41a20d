//! COLMAP's sparse model as stored on disk, and its conversion to [`Camera`]s.

use glam::{DMat3, DQuat, DVec3};

use crate::camera::{Camera, CameraModel, Distortion, Rigid};

#[derive(Clone, Debug, PartialEq)]
pub struct ColmapCamera {
    pub id: u32,
    pub model: CameraModel,
    pub width: u64,
    pub height: u64,
    /// In COLMAP's order for `model`; the readers check the count.
    pub params: Vec<f64>,
}

/// Pinhole intrinsics plus whatever distortion the model carries.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Intrinsics {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    /// `None` for the pinhole models.
    pub distortion: Option<Distortion>,
}

impl ColmapCamera {
    pub fn intrinsics(&self) -> Intrinsics {
        let p = &self.params;
        let get = |i: usize| p.get(i).copied().unwrap_or(0.0);
        let distortion = |k1, k2, p1, p2| {
            Some(Distortion {
                model: self.model,
                k1,
                k2,
                p1,
                p2,
                rational: [0.0; 4],
            })
        };
        let (fx, fy, cx, cy, distortion) = match self.model {
            CameraModel::SimplePinhole => (get(0), get(0), get(1), get(2), None),
            CameraModel::Pinhole => (get(0), get(1), get(2), get(3), None),
            CameraModel::SimpleRadial => (
                get(0),
                get(0),
                get(1),
                get(2),
                distortion(get(3), 0.0, 0.0, 0.0),
            ),
            CameraModel::Radial => (
                get(0),
                get(0),
                get(1),
                get(2),
                distortion(get(3), get(4), 0.0, 0.0),
            ),
            CameraModel::OpenCv => (
                get(0),
                get(1),
                get(2),
                get(3),
                distortion(get(4), get(5), get(6), get(7)),
            ),
            CameraModel::FullOpenCv => (
                get(0),
                get(1),
                get(2),
                get(3),
                distortion(get(4), get(5), get(6), get(7)).map(|d| Distortion {
                    rational: [get(8), get(9), get(10), get(11)],
                    ..d
                }),
            ),
        };
        Intrinsics {
            fx,
            fy,
            cx,
            cy,
            distortion,
        }
    }
}

/// A 2D feature of an image; `point3d_id` is -1 when it triangulated nothing.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Point2D {
    pub xy: [f64; 2],
    pub point3d_id: i64,
}

#[derive(Clone, Debug, PartialEq)]
pub struct ColmapImage {
    pub id: u32,
    /// World-to-camera rotation as a quaternion `(w, x, y, z)`.
    pub qvec: [f64; 4],
    /// World-to-camera translation.
    pub tvec: DVec3,
    pub camera_id: u32,
    pub name: String,
    pub points2d: Vec<Point2D>,
}

impl ColmapImage {
    /// COLMAP's poses are already OpenCV world-to-camera; only the quaternion is normalised.
    pub fn world_to_camera(&self) -> Rigid {
        let [w, x, y, z] = self.qvec;
        let q = DQuat::from_xyzw(x, y, z, w).normalize();
        Rigid {
            rotation: DMat3::from_quat(q),
            translation: self.tvec,
        }
    }

    pub fn from_world_to_camera(
        id: u32,
        camera_id: u32,
        name: &str,
        world_to_camera: &Rigid,
    ) -> Self {
        let q = DQuat::from_mat3(&world_to_camera.rotation);
        ColmapImage {
            id,
            qvec: [q.w, q.x, q.y, q.z],
            tvec: world_to_camera.translation,
            camera_id,
            name: name.to_string(),
            points2d: Vec::new(),
        }
    }

    /// The camera at the model's resolution, named after the file stem.
    pub fn camera(&self, camera: &ColmapCamera) -> Camera {
        let k = camera.intrinsics();
        let stem = std::path::Path::new(&self.name)
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| self.name.clone());
        Camera {
            name: stem,
            width: camera.width as u32,
            height: camera.height as u32,
            fx: k.fx,
            fy: k.fy,
            cx: k.cx,
            cy: k.cy,
            world_to_camera: self.world_to_camera(),
            distortion: k.distortion,
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TrackElement {
    pub image_id: u32,
    pub point2d_idx: u32,
}

#[derive(Clone, Debug, PartialEq)]
pub struct ColmapPoint {
    pub id: u64,
    pub xyz: DVec3,
    pub rgb: [u8; 3],
    pub error: f64,
    pub track: Vec<TrackElement>,
}

/// The three files of a sparse reconstruction.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct ColmapModel {
    pub cameras: Vec<ColmapCamera>,
    pub images: Vec<ColmapImage>,
    pub points: Vec<ColmapPoint>,
}
