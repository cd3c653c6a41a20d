//! Initial point clouds and the scene extent 3DGS derives from the cameras.

use glam::{DMat4, DVec3};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::camera::{Bounds, Camera};

/// Points with colours in `[0, 1]`, in world coordinates.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct PointCloud {
    pub positions: Vec<DVec3>,
    pub colors: Vec<[f32; 3]>,
}

impl PointCloud {
    pub fn len(&self) -> usize {
        self.positions.len()
    }

    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }
}

/// How many random points 3DGS seeds a scene without a sparse model with.
pub const DEFAULT_RANDOM_POINTS: usize = 100_000;

/// `count` points drawn uniformly over the cameras' frusta: a camera chosen uniformly, a pixel
/// position uniform over its image, and a depth uniform in that camera's `[near, far]`.
/// Colours are uniform in `[0, 1]`. The same seed gives the same cloud.
pub fn random_in_frusta(
    cameras: &[Camera],
    bounds: &[Bounds],
    count: usize,
    seed: u64,
) -> PointCloud {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut cloud = PointCloud {
        positions: Vec::with_capacity(count),
        colors: Vec::with_capacity(count),
    };
    let n = cameras.len().min(bounds.len());
    if n == 0 {
        return cloud;
    }
    for _ in 0..count {
        let i = rng.random_range(0..n);
        let (camera, b) = (&cameras[i], bounds[i]);
        let u = rng.random::<f64>() * camera.width as f64;
        let v = rng.random::<f64>() * camera.height as f64;
        let depth = b.near + rng.random::<f64>() * (b.far - b.near);
        cloud.positions.push(camera.unproject(u, v, depth));
        cloud
            .colors
            .push([rng.random(), rng.random(), rng.random()]);
    }
    cloud
}

/// Fraction of a random cloud placed on the background shell for a capture whose cameras
/// surround the scene.
pub const BACKGROUND_FRACTION: f64 = 0.25;

/// The background shell's radii, in units of [`Normalization::radius`] around the cameras'
/// mean centre: beyond every camera, so each looks at it from inside.
pub const SHELL_RADII: (f64, f64) = (2.0, 4.0);

/// `count` points on the far shell behind everything the cameras look at, where a capture
/// taken all around an object has its background (floor, walls, furniture): a camera chosen
/// uniformly, a pixel uniform over its image, and the point where that pixel's ray leaves a
/// sphere around the cameras' mean centre whose radius is uniform in [`SHELL_RADII`]. Without
/// them, random points lie only within the object's depth range, and the background seen
/// behind the object from one side is painted by splats in front of it from the other.
/// Colours are uniform in `[0, 1]`. The same seed gives the same cloud.
pub fn random_on_background_shell(cameras: &[Camera], count: usize, seed: u64) -> PointCloud {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut cloud = PointCloud {
        positions: Vec::with_capacity(count),
        colors: Vec::with_capacity(count),
    };
    let norm = Normalization::from_cameras(cameras);
    if cameras.is_empty() || norm.radius.is_nan() || norm.radius <= 0.0 {
        return cloud;
    }
    let centre = -norm.translate;
    for _ in 0..count {
        let camera = &cameras[rng.random_range(0..cameras.len())];
        let u = rng.random::<f64>() * camera.width as f64;
        let v = rng.random::<f64>() * camera.height as f64;
        let radius =
            norm.radius * (SHELL_RADII.0 + rng.random::<f64>() * (SHELL_RADII.1 - SHELL_RADII.0));
        let origin = camera.center();
        let dir = (camera.unproject(u, v, 1.0) - origin).normalize();
        // |o + t d − c|² = r² with the camera inside the sphere: the positive root.
        let oc = origin - centre;
        let b = oc.dot(dir);
        let t = -b
            + (b * b - oc.length_squared() + radius * radius)
                .max(0.0)
                .sqrt();
        cloud.positions.push(origin + t * dir);
        cloud
            .colors
            .push([rng.random(), rng.random(), rng.random()]);
    }
    cloud
}

/// 3DGS's `getNerfppNorm`: the camera centres' mean and the radius that encloses them, with a
/// 10% margin. 3DGS uses `radius` as the scene extent (densification and learning-rate scale)
/// and `translate` to recentre.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Normalization {
    /// Minus the mean camera centre.
    pub translate: DVec3,
    /// 1.1 times the largest distance of a camera centre from the mean.
    pub radius: f64,
}

impl Normalization {
    pub fn from_cameras(cameras: &[Camera]) -> Normalization {
        if cameras.is_empty() {
            return Normalization {
                translate: DVec3::ZERO,
                radius: 0.0,
            };
        }
        let centers: Vec<DVec3> = cameras.iter().map(Camera::center).collect();
        let mean = centers.iter().sum::<DVec3>() / centers.len() as f64;
        let diagonal = centers.iter().map(|c| c.distance(mean)).fold(0.0, f64::max);
        Normalization {
            translate: -mean,
            radius: diagonal * 1.1,
        }
    }

    /// World to normalised coordinates: recentre, then divide by `radius` so the cameras fit in
    /// the unit ball. (3DGS itself only recentres; the scale is offered for callers that want it.)
    pub fn transform(&self) -> DMat4 {
        let scale = if self.radius > 0.0 {
            1.0 / self.radius
        } else {
            1.0
        };
        DMat4::from_scale(DVec3::splat(scale)) * DMat4::from_translation(self.translate)
    }
}
