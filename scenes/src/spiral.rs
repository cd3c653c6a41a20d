//! The LLFF novel-view spiral (`render_path_spiral` of the NeRF code): around the mean pose,
//! radii from the 90th percentile of the camera offsets, two turns, looking at the focus
//! depth LLFF derives from the scene bounds.

use crate::{Bounds, Camera, Rigid};
use glam::{DMat3, DVec3};

fn percentile90(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(f64::total_cmp);
    let pos = 0.9 * (v.len() - 1) as f64;
    let (lo, hi) = (pos.floor() as usize, pos.ceil() as usize);
    v[lo] + (v[hi] - v[lo]) * (pos - lo as f64)
}

/// `frames` cameras on the spiral; intrinsics of `cameras[0]`. Empty input gives no frames.
pub fn spiral(cameras: &[Camera], bounds: &[Bounds], frames: usize) -> Vec<Camera> {
    let Some(first) = cameras.first() else {
        return Vec::new();
    };
    let n = cameras.len() as f64;
    let c2w: Vec<Rigid> = cameras
        .iter()
        .map(|c| c.world_to_camera.inverse())
        .collect();
    let center = c2w.iter().map(|p| p.translation).sum::<DVec3>() / n;
    let forward = c2w
        .iter()
        .map(|p| p.rotation.z_axis)
        .sum::<DVec3>()
        .normalize_or(DVec3::Z);
    let down_mean = c2w.iter().map(|p| p.rotation.y_axis).sum::<DVec3>();
    let right = down_mean.cross(forward).normalize_or(DVec3::X);
    let down = forward.cross(right);
    let avg = DMat3::from_cols(right, down, forward);

    let near = bounds.iter().map(|b| b.near).fold(f64::INFINITY, f64::min);
    let far = bounds.iter().map(|b| b.far).fold(0.0, f64::max);
    let focus = if near.is_finite() && near > 0.0 && far > 0.0 {
        let (close, inf, dt) = (near * 0.9, far * 5.0, 0.75);
        1.0 / ((1.0 - dt) / close + dt / inf)
    } else {
        1.0
    };
    let local: Vec<DVec3> = c2w
        .iter()
        .map(|p| avg.transpose() * (p.translation - center))
        .collect();
    let rads = DVec3::new(
        percentile90(local.iter().map(|v| v.x.abs()).collect()),
        percentile90(local.iter().map(|v| v.y.abs()).collect()),
        percentile90(local.iter().map(|v| v.z.abs()).collect()),
    );
    let target = center + forward * focus;
    (0..frames)
        .map(|k| {
            let theta = 2.0 * std::f64::consts::TAU * k as f64 / frames as f64;
            let offset = DVec3::new(
                theta.cos() * rads.x,
                theta.sin() * rads.y,
                (theta * 0.5).sin() * rads.z,
            );
            let eye = center + avg * offset;
            let f = (target - eye).normalize_or(forward);
            let r = down.cross(f).normalize_or(right);
            let d = f.cross(r);
            let rotation = DMat3::from_cols(r, d, f).transpose();
            Camera {
                name: format!("spiral{k:03}"),
                world_to_camera: Rigid {
                    rotation,
                    translation: -(rotation * eye),
                },
                distortion: None,
                ..first.clone()
            }
        })
        .collect()
}

/// `frames` cameras along the capture's cameras in their order, each pose between two
/// neighbours (centres interpolated linearly, orientations by slerp), so the path passes
/// through every camera; intrinsics of the nearer neighbour. One camera gives itself.
pub fn through_cameras(cameras: &[Camera], frames: usize) -> Vec<Camera> {
    let (n, frames) = (cameras.len(), frames.max(1));
    if n == 0 {
        return Vec::new();
    }
    (0..frames)
        .map(|k| {
            let s = if frames == 1 {
                0.0
            } else {
                k as f64 * (n - 1) as f64 / (frames - 1) as f64
            };
            let i = (s.floor() as usize).min(n.saturating_sub(2));
            let t = if n == 1 { 0.0 } else { s - i as f64 };
            let (a, b) = (&cameras[i], &cameras[(i + 1).min(n - 1)]);
            let (pa, pb) = (a.camera_to_world(), b.camera_to_world());
            let (qa, qb) = (
                glam::DQuat::from_mat3(&pa.rotation),
                glam::DQuat::from_mat3(&pb.rotation),
            );
            let rotation = DMat3::from_quat(qa.slerp(qb, t).normalize());
            let centre = pa.translation.lerp(pb.translation, t);
            let near = if t < 0.5 { a } else { b };
            Camera {
                name: format!("frame{k:05}"),
                world_to_camera: Rigid {
                    rotation,
                    translation: centre,
                }
                .inverse(),
                distortion: None,
                ..near.clone()
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An LLFF-like 4 × 3 grid of cameras, slightly out of line, looking at a point 8 ahead.
    fn grid() -> Vec<Camera> {
        (0..12)
            .map(|i| {
                let (c, r) = ((i % 4) as f64, (i / 4) as f64);
                let wobble = ((i * 7 % 5) as f64 - 2.0) * 0.02;
                let eye = DVec3::new(
                    (c / 3.0 - 0.5) * 1.2 + wobble,
                    (r / 2.0 - 0.5) * 0.8,
                    wobble,
                );
                let forward = (DVec3::new(0.0, 0.0, 8.0) - eye).normalize();
                let right = DVec3::Y.cross(forward).normalize();
                let rotation = DMat3::from_cols(right, forward.cross(right), forward).transpose();
                Camera {
                    name: format!("view{i:03}"),
                    width: 160,
                    height: 120,
                    fx: 144.0,
                    fy: 144.0,
                    cx: 80.0,
                    cy: 60.0,
                    world_to_camera: Rigid {
                        rotation,
                        translation: -(rotation * eye),
                    },
                    distortion: None,
                }
            })
            .collect()
    }

    #[test]
    fn spiral_circles_the_mean_pose_and_looks_at_the_focus() {
        let cams = grid();
        let bounds = vec![
            Bounds {
                near: 4.0,
                far: 12.0
            };
            cams.len()
        ];
        let path = spiral(&cams, &bounds, 40);
        assert_eq!(path.len(), 40);
        let mean = cams.iter().map(|c| c.center()).sum::<DVec3>() / cams.len() as f64;
        let focus = 1.0 / (0.25 / 3.6 + 0.75 / 60.0);
        let forward = cams
            .iter()
            .map(|c| c.world_to_camera.rotation.transpose() * DVec3::Z)
            .sum::<DVec3>()
            .normalize();
        let spread = cams
            .iter()
            .map(|c| (c.center() - mean).length())
            .fold(0.0, f64::max);
        for c in &path {
            let r = c.world_to_camera.rotation;
            assert!((r * r.transpose()).abs_diff_eq(DMat3::IDENTITY, 1e-9));
            assert!((r.determinant() - 1.0).abs() < 1e-9);
            // Within the cameras' spread of the mean centre, looking at the focus point.
            assert!((c.center() - mean).length() <= spread * 1.01);
            let target = mean + forward * focus;
            let p = c.world_to_camera.apply(target);
            assert!(
                p.z > 0.0 && p.x.abs() < 1e-6 * p.z && p.y.abs() < 1e-6 * p.z,
                "{p}"
            );
        }
        // It moves: frames differ and return near the start after the loop.
        assert!((path[0].center() - path[10].center()).length() > 0.1 * spread);
        assert!(spiral(&[], &[], 5).is_empty());
    }

    #[test]
    fn the_path_through_the_cameras_passes_through_each_of_them() {
        let cams = grid();
        let per = 4;
        let path = through_cameras(&cams, (cams.len() - 1) * per + 1);
        assert_eq!(path.len(), (cams.len() - 1) * per + 1);
        for (i, c) in cams.iter().enumerate() {
            let p = &path[i * per];
            let diff = (p.world_to_camera.to_mat4() - c.world_to_camera.to_mat4())
                .to_cols_array()
                .iter()
                .fold(0.0f64, |m, v| m.max(v.abs()));
            assert!(diff < 1e-9, "frame {} is {diff} from camera {i}", i * per);
        }
        // Between two cameras: halfway along, a rotation, facing between them.
        let mid = &path[per / 2];
        let r = mid.world_to_camera.rotation;
        assert!((r * r.transpose()).abs_diff_eq(DMat3::IDENTITY, 1e-9));
        let expect = (cams[0].center() + cams[1].center()) / 2.0;
        assert!((mid.center() - expect).length() < 1e-9);
        assert_eq!(through_cameras(&cams[..1], 5).len(), 5);
        assert!(through_cameras(&[], 5).is_empty());
    }
}
