//! Seeded synthetic scenes for benchmarks and smoke tests.

use glam::Vec3;

use crate::camera::Camera;
use crate::model::{Gaussians, sh_rest_count};
use base::SplitMix64;

/// `n` Gaussians filling a 4×3×3 box 4..7 units in front of the camera returned by
/// [`benchmark_camera`]. Scales shrink as `n^(-1/3)` so the covered fraction of the view stays
/// roughly constant with `n` (like a fixed scene reconstructed at a finer level of detail);
/// at 100k the typical scale is 0.01 (≈ 1–2 px on screen at 504×378).
pub fn random_box_scene(seed: u64, n: usize, sh_degree: u32) -> Gaussians {
    let mut rng = SplitMix64::new(seed);
    let mut g = Gaussians::new(sh_degree);
    let base = 0.01 * (100_000.0 / n.max(1) as f64).cbrt();
    let rc = sh_rest_count(sh_degree);
    for _ in 0..n {
        let mean = Vec3::new(
            rng.uniform(-2.0, 2.0) as f32,
            rng.uniform(-1.5, 1.5) as f32,
            rng.uniform(4.0, 7.0) as f32,
        );
        let mut ls = || (base * rng.uniform(0.5, 2.0)).ln() as f32;
        let log_scale = Vec3::new(ls(), ls(), ls());
        let q = [
            rng.normal() as f32,
            rng.normal() as f32,
            rng.normal() as f32,
            rng.normal() as f32,
        ];
        let logit = rng.uniform(-2.0, 3.0) as f32;
        let dc = Vec3::new(
            rng.uniform(-1.5, 1.5) as f32,
            rng.uniform(-1.5, 1.5) as f32,
            rng.uniform(-1.5, 1.5) as f32,
        );
        let rest: Vec<Vec3> = (0..rc)
            .map(|_| {
                Vec3::new(
                    rng.uniform(-0.2, 0.2) as f32,
                    rng.uniform(-0.2, 0.2) as f32,
                    rng.uniform(-0.2, 0.2) as f32,
                )
            })
            .collect();
        g.push(mean, log_scale, q, logit, dc, &rest);
    }
    g
}

/// 504×378 pinhole at the origin looking down +z (≈ 60° horizontal field of view).
pub fn benchmark_camera() -> Camera {
    Camera::look_at(
        Vec3::ZERO,
        Vec3::new(0.0, 0.0, 1.0),
        Vec3::new(0.0, -1.0, 0.0),
        436.0,
        436.0,
        504,
        378,
    )
}
