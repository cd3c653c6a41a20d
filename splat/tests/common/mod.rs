//! Test support: an independent brute-force float64 renderer and seeded scene generators.
#![allow(dead_code)]

#[allow(unused_imports)]
pub use splat::reference::{self, flatten, params_per_gaussian};

use glam::Vec3;
use splat::synthetic::{Draws, ScaleDraw, random_gaussians};
use splat::{Camera, Gaussians};

/// A small camera with an off-centre principal point and a non-trivial pose.
pub fn test_camera(width: u32, height: u32, f: f32) -> Camera {
    let mut cam = Camera::look_at(
        Vec3::new(0.4, -0.3, -4.0),
        Vec3::new(0.0, 0.1, 0.0),
        Vec3::new(0.1, -1.0, 0.05),
        f,
        f * 1.1,
        width,
        height,
    );
    cam.cx += 0.37;
    cam.cy -= 0.21;
    cam
}

/// Random Gaussians around the origin with log-scales in `scale_range` (natural units).
pub fn random_scene(
    seed: u64,
    n: usize,
    sh_degree: u32,
    scale_range: (f64, f64),
    extent: f64,
) -> Gaussians {
    let draws = Draws {
        mean: [(-extent, extent); 3],
        scale: ScaleDraw::LogUniform(scale_range.0, scale_range.1),
        logit: (-1.5, 1.5),
        dc: (-1.0, 1.0),
        rest: (-0.1, 0.1),
    };
    random_gaussians(seed, n, sh_degree, &draws)
}

/// All parameters of Gaussian-major layout: mean 3, log-scale 3, quaternion 4, logit 1,
/// DC 3, rest 3·rc.
pub const GROUP_NAMES: [&str; 6] = [
    "mean",
    "log_scale",
    "rotation",
    "opacity",
    "sh_dc",
    "sh_rest",
];

/// Group index of parameter `k` within a Gaussian's block.
pub fn group_of(k: usize) -> usize {
    match k {
        0..3 => 0,
        3..6 => 1,
        6..10 => 2,
        10 => 3,
        11..14 => 4,
        _ => 5,
    }
}
