//! The camera type every reader produces and the renderer consumes.
//!
//! # Convention
//!
//! Cameras follow OpenCV: in camera coordinates x points right, y points down and z points
//! forward (the camera looks along +z). [`Camera::world_to_camera`] maps a world point `p` to
//! `p_cam = R p + t`, and a point in front of the camera projects to pixel
//! `u = fx * x/z + cx`, `v = fy * y/z + cy`. Pixel `(i, j)` covers `[i, i+1) x [j, j+1)`, so its
//! centre sits at `(i + 0.5, j + 0.5)` and a principal point at the image centre is
//! `cx = width / 2`, `cy = height / 2`. COLMAP uses the same convention, so its poses and
//! intrinsics are taken over unchanged; LLFF's differ and are converted in [`crate::llff`].
//!
//! # Distortion
//!
//! Readers keep distortion coefficients found in a COLMAP model or a `transforms.json` in
//! [`Camera::distortion`], reported by the scene summary; [`Camera::project`] is a pure
//! pinhole projection and ignores them, and a capture's photos are undistorted onto that
//! pinhole camera at load ([`crate::undistort`]) unless asked not to be.

use std::fmt;

use glam::{DMat3, DMat4, DVec3};

/// A rigid transform `x -> rotation * x + translation`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Rigid {
    pub rotation: DMat3,
    pub translation: DVec3,
}

impl Rigid {
    pub const IDENTITY: Rigid = Rigid {
        rotation: DMat3::IDENTITY,
        translation: DVec3::ZERO,
    };

    pub fn apply(&self, p: DVec3) -> DVec3 {
        self.rotation * p + self.translation
    }

    /// Exact for rotations: the inverse rotation is the transpose.
    pub fn inverse(&self) -> Rigid {
        let rt = self.rotation.transpose();
        Rigid {
            rotation: rt,
            translation: -(rt * self.translation),
        }
    }

    pub fn to_mat4(&self) -> DMat4 {
        DMat4::from_cols(
            self.rotation.x_axis.extend(0.0),
            self.rotation.y_axis.extend(0.0),
            self.rotation.z_axis.extend(0.0),
            self.translation.extend(1.0),
        )
    }
}

/// The COLMAP camera models this crate reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CameraModel {
    SimplePinhole,
    Pinhole,
    SimpleRadial,
    Radial,
    OpenCv,
    FullOpenCv,
}

impl CameraModel {
    /// COLMAP's numeric model id as stored in `cameras.bin`.
    pub fn from_id(id: i32) -> Option<Self> {
        Some(match id {
            0 => Self::SimplePinhole,
            1 => Self::Pinhole,
            2 => Self::SimpleRadial,
            3 => Self::Radial,
            4 => Self::OpenCv,
            6 => Self::FullOpenCv,
            _ => return None,
        })
    }

    pub fn id(self) -> i32 {
        match self {
            Self::SimplePinhole => 0,
            Self::Pinhole => 1,
            Self::SimpleRadial => 2,
            Self::Radial => 3,
            Self::OpenCv => 4,
            Self::FullOpenCv => 6,
        }
    }

    pub fn from_name(name: &str) -> Option<Self> {
        Some(match name {
            "SIMPLE_PINHOLE" => Self::SimplePinhole,
            "PINHOLE" => Self::Pinhole,
            "SIMPLE_RADIAL" => Self::SimpleRadial,
            "RADIAL" => Self::Radial,
            "OPENCV" => Self::OpenCv,
            "FULL_OPENCV" => Self::FullOpenCv,
            _ => return None,
        })
    }

    pub fn name(self) -> &'static str {
        match self {
            Self::SimplePinhole => "SIMPLE_PINHOLE",
            Self::Pinhole => "PINHOLE",
            Self::SimpleRadial => "SIMPLE_RADIAL",
            Self::Radial => "RADIAL",
            Self::OpenCv => "OPENCV",
            Self::FullOpenCv => "FULL_OPENCV",
        }
    }

    /// How many parameters COLMAP stores for this model.
    pub fn param_count(self) -> usize {
        match self {
            Self::SimplePinhole => 3,
            Self::Pinhole => 4,
            Self::SimpleRadial => 4,
            Self::Radial => 5,
            Self::OpenCv => 8,
            Self::FullOpenCv => 12,
        }
    }
}

impl fmt::Display for CameraModel {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// Lens distortion in normalised image coordinates (OpenCV's rational radial-tangential
/// model, of which COLMAP's SIMPLE_RADIAL, RADIAL and OPENCV are special cases). Being
/// dimensionless, the coefficients do not change when images are downsampled.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Distortion {
    /// The model the coefficients came from, kept for reporting.
    pub model: CameraModel,
    pub k1: f64,
    pub k2: f64,
    pub p1: f64,
    pub p2: f64,
    /// FULL_OPENCV's `k3, k4, k5, k6`: the radial factor is
    /// `(1 + k1 r² + k2 r⁴ + k3 r⁶) / (1 + k4 r² + k5 r⁴ + k6 r⁶)`; zero for the other models.
    pub rational: [f64; 4],
}

impl Distortion {
    /// Maps an undistorted normalised point `(x/z, y/z)` to where the lens images it.
    pub fn distort(&self, x: f64, y: f64) -> (f64, f64) {
        let r2 = x * x + y * y;
        let [k3, k4, k5, k6] = self.rational;
        let radial = (1.0 + self.k1 * r2 + self.k2 * r2 * r2 + k3 * r2 * r2 * r2)
            / (1.0 + k4 * r2 + k5 * r2 * r2 + k6 * r2 * r2 * r2);
        (
            x * radial + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x),
            y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y,
        )
    }

    pub fn is_zero(&self) -> bool {
        self.k1 == 0.0
            && self.k2 == 0.0
            && self.p1 == 0.0
            && self.p2 == 0.0
            && self.rational == [0.0; 4]
    }
}

impl fmt::Display for Distortion {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.model {
            CameraModel::SimplePinhole | CameraModel::Pinhole => write!(f, "{} (none)", self.model),
            CameraModel::SimpleRadial => write!(f, "{} k1={:.6}", self.model, self.k1),
            CameraModel::Radial => {
                write!(f, "{} k1={:.6} k2={:.6}", self.model, self.k1, self.k2)
            }
            CameraModel::FullOpenCv => {
                let [k3, k4, k5, k6] = self.rational;
                write!(
                    f,
                    "{} k1={:.6} k2={:.6} p1={:.6} p2={:.6} k3={k3:.6} k4={k4:.6} k5={k5:.6} k6={k6:.6}",
                    self.model, self.k1, self.k2, self.p1, self.p2
                )
            }
            CameraModel::OpenCv => write!(
                f,
                "{} k1={:.6} k2={:.6} p1={:.6} p2={:.6}",
                self.model, self.k1, self.k2, self.p1, self.p2
            ),
        }
    }
}

/// A pinhole camera in the OpenCV convention described in the module docs.
#[derive(Clone, Debug, PartialEq)]
pub struct Camera {
    /// The image file stem, e.g. `image007`.
    pub name: String,
    pub width: u32,
    pub height: u32,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub world_to_camera: Rigid,
    /// The lens's distortion; the photos are undistorted at load (see the module docs).
    pub distortion: Option<Distortion>,
}

/// Where a world point lands in an image.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Projection {
    pub u: f64,
    pub v: f64,
    /// Distance along the optical axis (camera z).
    pub depth: f64,
}

impl Camera {
    pub fn camera_to_world(&self) -> Rigid {
        self.world_to_camera.inverse()
    }

    /// The optical centre in world coordinates.
    pub fn center(&self) -> DVec3 {
        self.camera_to_world().translation
    }

    /// Pinhole projection; `None` for points at or behind the camera plane.
    pub fn project(&self, world: DVec3) -> Option<Projection> {
        let p = self.world_to_camera.apply(world);
        if p.z <= 0.0 {
            return None;
        }
        Some(Projection {
            u: self.fx * p.x / p.z + self.cx,
            v: self.fy * p.y / p.z + self.cy,
            depth: p.z,
        })
    }

    pub fn contains(&self, projection: &Projection) -> bool {
        (0.0..self.width as f64).contains(&projection.u)
            && (0.0..self.height as f64).contains(&projection.v)
    }

    /// The world point seen at pixel coordinates `(u, v)` at camera depth `depth`.
    pub fn unproject(&self, u: f64, v: f64, depth: f64) -> DVec3 {
        let p = DVec3::new(
            (u - self.cx) / self.fx * depth,
            (v - self.cy) / self.fy * depth,
            depth,
        );
        self.camera_to_world().apply(p)
    }

    /// The same camera for an image resized to `width x height`. Pixel edges sit at integer
    /// coordinates, so intrinsics scale by the size ratio with no half-pixel shift.
    pub fn resized(&self, width: u32, height: u32) -> Camera {
        let sx = width as f64 / self.width as f64;
        let sy = height as f64 / self.height as f64;
        Camera {
            width,
            height,
            fx: self.fx * sx,
            fy: self.fy * sy,
            cx: self.cx * sx,
            cy: self.cy * sy,
            ..self.clone()
        }
    }
}

/// Per-image depth range of the scene content, as LLFF stores it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bounds {
    pub near: f64,
    pub far: f64,
}
