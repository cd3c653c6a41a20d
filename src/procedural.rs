//! A procedural forward-facing scene with known ground truth, for the built-in demo and the
//! end-to-end tests: a textured back wall, a checkered panel and coloured balls, all made of
//! Gaussians, seen by an LLFF-like grid of cameras. Rendering it gives the clean capture.

use std::path::{Path, PathBuf};

use base::SplitMix64;
use glam::{DMat3, DVec3, Vec3};
use rayon::prelude::*;
use scenes::colmap::{ColmapPoint, text::write_points3d};
use scenes::{BitDepth, Bounds, Camera, LlffWriter, Rigid};
use splat::model::logit;
use splat::{Gaussians, RenderSettings};

use crate::convert::{pixels_to_rgb, splat_camera};
use crate::error::{Result, TrainError};

#[derive(Clone, Debug)]
pub struct ProceduralOptions {
    pub width: u32,
    pub height: u32,
    pub views: usize,
    pub seed: u64,
}

impl Default for ProceduralOptions {
    fn default() -> Self {
        Self {
            width: 160,
            height: 120,
            views: 12,
            seed: 0,
        }
    }
}

fn push_flat(g: &mut Gaussians, at: Vec3, half: f32, color: Vec3) {
    g.push(
        at,
        Vec3::new(half, half, half * 0.05).ln(),
        [1.0, 0.0, 0.0, 0.0],
        logit(0.95),
        splat::sh::rgb_to_sh_dc(color),
        &[],
    );
}

/// The ground-truth splats (SH degree 0).
pub fn ground_truth(seed: u64) -> Gaussians {
    let mut g = Gaussians::new(0);
    let mut rng = SplitMix64::new(seed);
    // Back wall at z = 10: stripes and a colour gradient, fine enough that the blur matters.
    let step = 0.12;
    for iy in 0..100 {
        for ix in 0..130 {
            let (x, y) = (-7.8 + ix as f32 * step, -6.0 + iy as f32 * step);
            let stripe = ((x * 2.2 + y * 0.7).sin() > 0.0) as u8 as f32;
            let color = Vec3::new(
                0.15 + 0.7 * stripe,
                0.2 + 0.5 * ((y + 6.0) / 12.0),
                0.25 + 0.6 * ((x + 7.8) / 15.6) * (1.0 - 0.5 * stripe),
            );
            push_flat(&mut g, Vec3::new(x, y, 10.0), step * 0.6, color);
        }
    }
    // A checkered panel at z = 6.
    let step = 0.08;
    for iy in 0..30 {
        for ix in 0..30 {
            let (x, y) = (-2.6 + ix as f32 * step, -0.4 + iy as f32 * step);
            let check = ((ix / 5 + iy / 5) % 2) as f32;
            push_flat(
                &mut g,
                Vec3::new(x, y, 6.0),
                step * 0.6,
                Vec3::splat(0.1 + 0.8 * check),
            );
        }
    }
    // Balls at mid depth.
    let balls = [
        (Vec3::new(1.4, -0.8, 5.0), 0.7, Vec3::new(0.9, 0.3, 0.2)),
        (Vec3::new(0.2, 1.2, 7.0), 0.9, Vec3::new(0.2, 0.7, 0.3)),
        (Vec3::new(-1.9, -1.5, 7.5), 0.6, Vec3::new(0.3, 0.4, 0.95)),
    ];
    for (center, radius, color) in balls {
        for _ in 0..1500 {
            let d = Vec3::new(
                rng.normal() as f32,
                rng.normal() as f32,
                rng.normal() as f32,
            )
            .normalize_or(Vec3::Z);
            let shade = 0.6 + 0.4 * (-d.y).max(0.0);
            g.push(
                center + d * radius,
                Vec3::splat(radius * 0.08).ln(),
                [1.0, 0.0, 0.0, 0.0],
                logit(0.9),
                splat::sh::rgb_to_sh_dc(color * shade),
                &[],
            );
        }
    }
    g
}

/// An OpenCV camera at `eye` looking at `target`, image +y along world +y.
fn look_at(name: &str, eye: DVec3, target: DVec3, o: &ProceduralOptions) -> Camera {
    let forward = (target - eye).normalize();
    let right = DVec3::Y.cross(forward).normalize();
    let down = forward.cross(right);
    let rotation = DMat3::from_cols(right, down, forward).transpose();
    let f = 0.9 * o.width as f64;
    Camera {
        name: name.to_string(),
        width: o.width,
        height: o.height,
        fx: f,
        fy: f,
        cx: o.width as f64 / 2.0,
        cy: o.height as f64 / 2.0,
        world_to_camera: Rigid {
            rotation,
            translation: -(rotation * eye),
        },
        distortion: None,
    }
}

/// LLFF-like cameras: a jittered grid on the plane z = 0, all converging on a point 8 ahead.
pub fn cameras(o: &ProceduralOptions) -> Vec<Camera> {
    let cols = (o.views as f64).sqrt().ceil() as usize + 1;
    let rows = o.views.div_ceil(cols);
    let mut rng = SplitMix64::new(o.seed ^ 0xCA11);
    (0..o.views)
        .map(|i| {
            let (c, r) = ((i % cols) as f64, (i / cols) as f64);
            let eye = DVec3::new(
                (c / (cols - 1).max(1) as f64 - 0.5) * 1.2 + rng.uniform(-0.05, 0.05),
                (r / (rows - 1).max(1) as f64 - 0.5) * 0.8 + rng.uniform(-0.05, 0.05),
                rng.uniform(-0.1, 0.1),
            );
            look_at(&format!("view{i:03}"), eye, DVec3::new(0.0, 0.0, 8.0), o)
        })
        .collect()
}

/// Writes the clean capture (LLFF layout plus `sparse/0/points3D.txt`: a jittered subset of
/// the true centres, as SfM would give) and returns its path.
pub fn write_capture(dest: &Path, o: &ProceduralOptions) -> Result<PathBuf> {
    let truth = ground_truth(o.seed);
    let cams = cameras(o);
    let settings = RenderSettings::default();
    let images = cams
        .par_iter()
        .map(|c| {
            let out = splat::render(&truth, &splat_camera(c), &settings)?;
            Ok(pixels_to_rgb(
                &out.color
                    .iter()
                    .map(|p| p.clamp(Vec3::ZERO, Vec3::ONE))
                    .collect::<Vec<_>>(),
                c.width,
                c.height,
            ))
        })
        .collect::<Result<Vec<_>>>()?;
    let mut writer = LlffWriter::create(dest, 1, BitDepth::Eight)?;
    for (c, img) in cams.iter().zip(&images) {
        writer.add(
            c,
            Bounds {
                near: 4.0,
                far: 12.0,
            },
            img,
        )?;
    }
    let sparse = writer.staging_dir().join("sparse").join("0");
    std::fs::create_dir_all(&sparse).map_err(|e| TrainError::io(&sparse, e))?;
    let mut rng = SplitMix64::new(o.seed ^ 0x5F);
    let points: Vec<ColmapPoint> = (0..truth.len())
        .step_by(6)
        .enumerate()
        .map(|(k, i)| {
            let jitter = DVec3::new(rng.normal(), rng.normal(), rng.normal()) * 0.05;
            let c = splat::sh::sh_dc_to_rgb(truth.sh_dc[i]).clamp(Vec3::ZERO, Vec3::ONE);
            ColmapPoint {
                id: k as u64 + 1,
                xyz: truth.means[i].as_dvec3() + jitter,
                rgb: c.to_array().map(|v| (v * 255.0).round() as u8),
                error: 0.5,
                track: Vec::new(),
            }
        })
        .collect();
    write_points3d(&sparse.join("points3D.txt"), &points)?;
    Ok(writer.finish()?)
}
