//! Test support: an independent brute-force float64 renderer and seeded scene generators.
#![allow(dead_code)]

#[allow(unused_imports)]
pub use splat::reference::{self, flatten, params_per_gaussian};

use base::SplitMix64;
use glam::Vec3;
use splat::{Camera, Gaussians, sh_rest_count};

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
    let mut rng = SplitMix64::new(seed);
    let mut g = Gaussians::new(sh_degree);
    let rc = sh_rest_count(sh_degree);
    for _ in 0..n {
        let mean = Vec3::new(
            rng.uniform(-extent, extent) as f32,
            rng.uniform(-extent, extent) as f32,
            rng.uniform(-extent, extent) as f32,
        );
        let ls = |r: &mut SplitMix64| r.uniform(scale_range.0.ln(), scale_range.1.ln()) as f32;
        let log_scale = Vec3::new(ls(&mut rng), ls(&mut rng), ls(&mut rng));
        let q = [
            rng.normal() as f32,
            rng.normal() as f32,
            rng.normal() as f32,
            rng.normal() as f32,
        ];
        let logit = rng.uniform(-1.5, 1.5) as f32;
        let dc = Vec3::new(
            rng.uniform(-1.0, 1.0) as f32,
            rng.uniform(-1.0, 1.0) as f32,
            rng.uniform(-1.0, 1.0) as f32,
        );
        let rest: Vec<Vec3> = (0..rc)
            .map(|_| {
                Vec3::new(
                    rng.uniform(-0.1, 0.1) as f32,
                    rng.uniform(-0.1, 0.1) as f32,
                    rng.uniform(-0.1, 0.1) as f32,
                )
            })
            .collect();
        g.push(mean, log_scale, q, logit, dc, &rest);
    }
    g
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
