//! Procedural scenes with known ground truth, made of Gaussians; rendering them gives the
//! clean capture.
//!
//! - Forward-facing (the built-in demo and the end-to-end tests): a textured back wall, a
//!   checkered panel and coloured balls, seen by an LLFF-like grid of cameras, with SfM-like
//!   points.
//! - All around ([`write_capture_around`]): a textured object on a ground disc in the middle
//!   and cameras on a ring around it, without SfM points (training starts from random
//!   points): the wide-baseline, object-centred geometry of a turntable capture.

use std::path::{Path, PathBuf};

use base::SplitMix64;
use glam::{DMat3, DVec3, Vec3};
use rayon::prelude::*;
use scenes::colmap::{ColmapPoint, text::write_points3d};
use scenes::{BitDepth, Bounds, Camera, LlffWriter, Rigid};
use splat::model::logit;
use splat::{Gaussians, RenderSettings};

use crate::error::{Result, TrainError};
use crate::splats::convert::{pixels_to_rgb, splat_camera};

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
            let d = rng.normal_vec3().normalize_or(Vec3::Z);
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

/// The all-around scene's splats (SH degree 0): a striped ball, a checkered box beside it
/// and a ground disc, centred on the origin (world up is −y, as in captures).
pub fn ground_truth_around(seed: u64) -> Gaussians {
    let mut g = Gaussians::new(0);
    let mut rng = SplitMix64::new(seed ^ 0xA120);
    let dir = |rng: &mut SplitMix64| rng.normal_vec3().normalize_or(Vec3::Z);
    // A ball with bands around it: the texture changes with the view direction.
    let (center, radius) = (Vec3::new(-0.35, -0.2, 0.0), 0.6);
    for _ in 0..12_000 {
        let d = dir(&mut rng);
        let band = ((d.y * 9.0).sin() > 0.0) as u8 as f32;
        let side = 0.5 + 0.5 * d.x;
        let color = Vec3::new(0.85 * band + 0.1, 0.25 + 0.5 * side, 0.9 - 0.7 * band);
        g.push(
            center + d * radius,
            Vec3::new(0.035, 0.035, 0.008).ln(),
            rotation_to(d),
            logit(0.95),
            splat::sh::rgb_to_sh_dc(color),
            &[],
        );
    }
    // A box with a checkered skin.
    let (bc, half) = (Vec3::new(0.55, 0.05, 0.25), 0.35);
    for _ in 0..9_000 {
        let mut p = Vec3::new(
            rng.uniform(-1.0, 1.0) as f32,
            rng.uniform(-1.0, 1.0) as f32,
            rng.uniform(-1.0, 1.0) as f32,
        );
        let axis = (rng.next_u64() % 3) as usize;
        p[axis] = if rng.next_u64().is_multiple_of(2) {
            -1.0
        } else {
            1.0
        };
        let (u, v) = (
            (p[(axis + 1) % 3] + 1.0) * 3.0,
            (p[(axis + 2) % 3] + 1.0) * 3.0,
        );
        let check = ((u as i32 + v as i32) % 2) as f32;
        let mut normal = Vec3::ZERO;
        normal[axis] = p[axis];
        g.push(
            bc + p * half,
            Vec3::new(0.03, 0.03, 0.006).ln(),
            rotation_to(normal),
            logit(0.95),
            splat::sh::rgb_to_sh_dc(Vec3::new(0.9, 0.8, 0.2) * (0.25 + 0.75 * check)),
            &[],
        );
    }
    // A ground disc below both, with rings.
    for _ in 0..10_000 {
        let r = 2.0 * (rng.uniform(0.0, 1.0) as f32).sqrt();
        let a = rng.uniform(0.0, std::f64::consts::TAU) as f32;
        let ring = ((r * 6.0).sin() > 0.0) as u8 as f32;
        push_flat_y(
            &mut g,
            Vec3::new(r * a.cos(), 0.42, r * a.sin()),
            0.04,
            Vec3::new(0.3 + 0.4 * ring, 0.35, 0.3),
        );
    }
    g
}

/// A flat splat lying in the y = const plane.
fn push_flat_y(g: &mut Gaussians, at: Vec3, half: f32, color: Vec3) {
    g.push(
        at,
        Vec3::new(half, half * 0.05, half).ln(),
        [1.0, 0.0, 0.0, 0.0],
        logit(0.95),
        splat::sh::rgb_to_sh_dc(color),
        &[],
    );
}

/// The rotation `(w, x, y, z)` taking +z to the unit vector `n`: a flat splat's normal.
fn rotation_to(n: Vec3) -> [f32; 4] {
    let q = glam::Quat::from_rotation_arc(Vec3::Z, n.normalize_or(Vec3::Z));
    [q.w, q.x, q.y, q.z]
}

/// Cameras on a ring around the origin, every one looking at it, alternating between two
/// heights (as a turntable capture walks around an object).
pub fn cameras_around(o: &ProceduralOptions) -> Vec<Camera> {
    let mut rng = SplitMix64::new(o.seed ^ 0xA10D);
    (0..o.views)
        .map(|i| {
            let angle =
                std::f64::consts::TAU * i as f64 / o.views as f64 + rng.uniform(-0.05, 0.05);
            let elevation: f64 = if i % 2 == 0 { 0.3 } else { 0.6 };
            let distance = 3.6 + rng.uniform(-0.2, 0.2);
            let eye = DVec3::new(
                distance * elevation.cos() * angle.sin(),
                -distance * elevation.sin(),
                -distance * elevation.cos() * angle.cos(),
            );
            look_at(&format!("view{i:03}"), eye, DVec3::ZERO, o)
        })
        .collect()
}

/// Writes the all-around capture (LLFF layout, no SfM points) and returns its path.
pub fn write_capture_around(dest: &Path, o: &ProceduralOptions) -> Result<PathBuf> {
    let truth = ground_truth_around(o.seed);
    let cams = cameras_around(o);
    let mut writer = LlffWriter::create(dest, 1, BitDepth::Eight)?;
    for (c, img) in cams.iter().zip(render_views(&truth, &cams)?) {
        writer.add(
            c,
            Bounds {
                near: 1.2,
                far: 6.5,
            },
            &img,
        )?;
    }
    Ok(writer.finish()?)
}

fn render_views(truth: &Gaussians, cams: &[Camera]) -> Result<Vec<scenes::Photo>> {
    let settings = RenderSettings::default();
    cams.par_iter()
        .map(|c| {
            let out = splat::render(truth, &splat_camera(c), &settings)?;
            Ok(pixels_to_rgb(
                &out.color
                    .iter()
                    .map(|p| p.clamp(Vec3::ZERO, Vec3::ONE))
                    .collect::<Vec<_>>(),
                c.width,
                c.height,
            ))
        })
        .collect()
}

/// Writes the clean capture (LLFF layout plus `sparse/0/points3D.txt`: a jittered subset of
/// the true centres, as SfM would give) and returns its path.
pub fn write_capture(dest: &Path, o: &ProceduralOptions) -> Result<PathBuf> {
    let truth = ground_truth(o.seed);
    let cams = cameras(o);
    let images = render_views(&truth, &cams)?;
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_ring_surrounds_the_scene_and_the_grid_faces_it() {
        let o = ProceduralOptions {
            views: 24,
            ..Default::default()
        };
        assert!(scenes::capture::surrounds(&cameras_around(&o)));
        assert!(!scenes::capture::surrounds(&cameras(&o)));
    }
}
