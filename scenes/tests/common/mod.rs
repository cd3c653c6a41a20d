//! Helpers shared by the integration tests: hand-built cameras and fixture folders.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

use glam::{DMat3, DVec3};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use scenes::{Bounds, Camera, Photo, Rigid};

/// An OpenCV camera at `eye` looking at `target`, `up` pointing up in the image.
pub fn look_at(
    name: &str,
    eye: DVec3,
    target: DVec3,
    up: DVec3,
    width: u32,
    height: u32,
    f: f64,
) -> Camera {
    let forward = (target - eye).normalize();
    let right = forward.cross(up).normalize();
    let down = forward.cross(right);
    let c2w = DMat3::from_cols(right, down, forward);
    Camera {
        name: name.to_string(),
        width,
        height,
        fx: f,
        fy: f,
        cx: width as f64 / 2.0,
        cy: height as f64 / 2.0,
        world_to_camera: Rigid {
            rotation: c2w.transpose(),
            translation: -(c2w.transpose() * eye),
        },
        distortion: None,
    }
}

/// `n` cameras on a noisy arc facing the origin, LLFF-like.
pub fn arc_cameras(n: usize, width: u32, height: u32, seed: u64) -> (Vec<Camera>, Vec<Bounds>) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut cameras = Vec::new();
    let mut bounds = Vec::new();
    for i in 0..n {
        let a = i as f64 * 0.1 - 0.5;
        let eye = DVec3::new(4.0 * a.sin(), rng.random_range(-0.3..0.3), -4.0 * a.cos());
        let target = DVec3::new(
            rng.random_range(-0.2..0.2),
            rng.random_range(-0.2..0.2),
            0.0,
        );
        cameras.push(look_at(
            &format!("img{i:03}"),
            eye,
            target,
            DVec3::new(0.0, -1.0, 0.0),
            width,
            height,
            width as f64 * 0.9,
        ));
        bounds.push(Bounds {
            near: rng.random_range(1.0..2.0),
            far: rng.random_range(6.0..9.0),
        });
    }
    (cameras, bounds)
}

/// A smooth, camera-dependent test pattern.
pub fn pattern(width: u32, height: u32, k: usize) -> Photo {
    let mut data = Vec::with_capacity((width * height * 3) as usize);
    for y in 0..height {
        for x in 0..width {
            data.push(x as f32 / width as f32);
            data.push(y as f32 / height as f32);
            data.push(((x + y) as usize + k) as f32 % 7.0 / 7.0);
        }
    }
    Photo {
        width,
        height,
        data,
    }
}

pub fn fern_dir() -> Option<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/llff/fern");
    if dir.join("poses_bounds.npy").is_file() {
        Some(dir)
    } else {
        eprintln!("SKIP: {} not found", dir.display());
        None
    }
}
