//! Seeded synthetic scenes for benchmarks and smoke tests.

use glam::Vec3;

use crate::camera::Camera;
use crate::model::{Gaussians, sh_rest_count};
use base::SplitMix64;

/// How [`random_gaussians`] draws each parameter, every one uniformly in its range.
#[derive(Clone, Copy, Debug)]
pub struct Draws {
    /// The box the means fill, per axis.
    pub mean: [(f64, f64); 3],
    pub scale: ScaleDraw,
    pub logit: (f64, f64),
    /// The DC coefficients, and the higher SH bands' coefficients.
    pub dc: (f64, f64),
    pub rest: (f64, f64),
}

/// How the three log-scales of a Gaussian are drawn.
#[derive(Clone, Copy, Debug)]
pub enum ScaleDraw {
    /// Log-uniform between two scales (natural units).
    LogUniform(f64, f64),
    /// `base` times a uniform factor in the range.
    Around { base: f64, factor: (f64, f64) },
}

/// `n` random Gaussians of SH degree `sh_degree`, drawn as `draws` says from the seeded
/// stream (the same seed and draws give the same scene everywhere); quaternions are
/// normally distributed, so rotations are uniform.
pub fn random_gaussians(seed: u64, n: usize, sh_degree: u32, draws: &Draws) -> Gaussians {
    let mut rng = SplitMix64::new(seed);
    let mut g = Gaussians::new(sh_degree);
    let rc = sh_rest_count(sh_degree);
    let uniform3 = |rng: &mut SplitMix64, [x, y, z]: [(f64, f64); 3]| {
        Vec3::new(
            rng.uniform(x.0, x.1) as f32,
            rng.uniform(y.0, y.1) as f32,
            rng.uniform(z.0, z.1) as f32,
        )
    };
    for _ in 0..n {
        let mean = uniform3(&mut rng, draws.mean);
        let mut ls = || match draws.scale {
            ScaleDraw::LogUniform(lo, hi) => rng.uniform(lo.ln(), hi.ln()) as f32,
            ScaleDraw::Around { base, factor } => {
                (base * rng.uniform(factor.0, factor.1)).ln() as f32
            }
        };
        let log_scale = Vec3::new(ls(), ls(), ls());
        let q = [
            rng.normal() as f32,
            rng.normal() as f32,
            rng.normal() as f32,
            rng.normal() as f32,
        ];
        let logit = rng.uniform(draws.logit.0, draws.logit.1) as f32;
        let dc = uniform3(&mut rng, [draws.dc; 3]);
        let rest: Vec<Vec3> = (0..rc)
            .map(|_| uniform3(&mut rng, [draws.rest; 3]))
            .collect();
        g.push(mean, log_scale, q, logit, dc, &rest);
    }
    g
}

/// `n` Gaussians filling a 4×3×3 box 4..7 units in front of the camera returned by
/// [`benchmark_camera`]. Scales shrink as `n^(-1/3)` so the covered fraction of the view stays
/// roughly constant with `n` (like a fixed scene reconstructed at a finer level of detail);
/// at 100k the typical scale is 0.01 (≈ 1–2 px on screen at 504×378).
pub fn random_box_scene(seed: u64, n: usize, sh_degree: u32) -> Gaussians {
    let draws = Draws {
        mean: [(-2.0, 2.0), (-1.5, 1.5), (4.0, 7.0)],
        scale: ScaleDraw::Around {
            base: 0.01 * (100_000.0 / n.max(1) as f64).cbrt(),
            factor: (0.5, 2.0),
        },
        logit: (-2.0, 3.0),
        dc: (-1.5, 1.5),
        rest: (-0.2, 0.2),
    };
    random_gaussians(seed, n, sh_degree, &draws)
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
