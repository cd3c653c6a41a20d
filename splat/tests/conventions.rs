//! The documented conventions the wgpu renderer must reproduce.

use glam::{Mat3, Vec3};
use splat::conventions::TILE_SIZE;
use splat::cpu::project::quat_to_rotmat;
use splat::{Camera, Gaussians, RenderSettings, render};

fn dot_scene(points: &[Vec3]) -> Gaussians {
    let mut g = Gaussians::new(0);
    for p in points {
        g.push(
            *p,
            Vec3::splat(-6.0),
            [1.0, 0.0, 0.0, 0.0],
            8.0,
            Vec3::splat(1.0),
            &[],
        );
    }
    g
}

fn brightest(out: &splat::RenderOutput) -> (u32, u32) {
    let i = (0..out.alpha.len())
        .max_by(|&a, &b| out.alpha[a].total_cmp(&out.alpha[b]))
        .unwrap();
    (i as u32 % out.width, i as u32 / out.width)
}

#[test]
fn opencv_axes_and_pixel_centres() {
    // Identity pose: camera at the origin looking down +z, +x right, +y down.
    let cam = Camera {
        fx: 50.0,
        fy: 50.0,
        cx: 20.0,
        cy: 15.0,
        width: 40,
        height: 30,
        rotation: Mat3::IDENTITY,
        translation: Vec3::ZERO,
        near: 0.01,
        far: 100.0,
    };
    let s = RenderSettings::default();
    // Projects to (20, 15): the corner shared by pixels 19/20 and 14/15; nudged by a quarter
    // pixel it lands in pixel (20, 15), whose centre is (20.5, 15.5).
    let out = render(
        &dot_scene(&[Vec3::new(0.5 / 50.0, 0.5 / 50.0, 1.0)]),
        &cam,
        &s,
    )
    .unwrap();
    assert_eq!(brightest(&out), (20, 15));
    let out = render(&dot_scene(&[Vec3::new(0.21, 0.01, 1.0)]), &cam, &s).unwrap();
    assert_eq!(brightest(&out), (30, 15), "+x is right");
    let out = render(&dot_scene(&[Vec3::new(0.01, 0.21, 1.0)]), &cam, &s).unwrap();
    assert_eq!(brightest(&out), (20, 25), "+y is down");
    let out = render(&dot_scene(&[Vec3::new(0.0, 0.0, -1.0)]), &cam, &s).unwrap();
    assert!(out.alpha.iter().all(|&a| a == 0.0), "-z is behind");
}

#[test]
fn look_at_keeps_up_up() {
    let cam = Camera::look_at(
        Vec3::new(0.0, 0.0, -5.0),
        Vec3::ZERO,
        Vec3::Y,
        40.0,
        40.0,
        32,
        32,
    );
    assert!(cam.validate().is_ok());
    assert!((cam.position() - Vec3::new(0.0, 0.0, -5.0)).length() < 1e-5);
    let s = RenderSettings::default();
    let out = render(&dot_scene(&[Vec3::new(0.0, 1.0, 0.0)]), &cam, &s).unwrap();
    assert!(brightest(&out).1 < 16, "world up appears in the upper half");
    let out = render(&dot_scene(&[Vec3::new(1.0, 0.0, 0.0)]), &cam, &s).unwrap();
    // Looking down +z with +y up, world +x is on the left (right-handed world).
    assert!(brightest(&out).0 < 16);
}

#[test]
fn tiles_are_16_pixels_and_radius_bounds_the_footprint() {
    assert_eq!(TILE_SIZE, 16);
    let cam = Camera::look_at(Vec3::ZERO, Vec3::Z, -Vec3::Y, 60.0, 60.0, 64, 48);
    let mut g = Gaussians::new(0);
    g.push(
        Vec3::new(0.1, -0.05, 3.0),
        Vec3::new(-2.0, -3.0, -2.5),
        [0.9, 0.2, 0.3, -0.1],
        1.0,
        Vec3::ZERO,
        &[],
    );
    let out = render(&g, &cam, &RenderSettings::default()).unwrap();
    let [rx, ry] = out.radii[0];
    assert!(rx > 0 && ry > 0);
    // Every touched pixel's centre lies within the radius box around the projected mean.
    let m = (60.0 * 0.1 / 3.0 + 32.0, 60.0 * -0.05 / 3.0 + 24.0);
    let mut touched = 0;
    for (i, &a) in out.alpha.iter().enumerate() {
        if a > 0.0 {
            touched += 1;
            let (px, py) = ((i % 64) as f32 + 0.5, (i / 64) as f32 + 0.5);
            assert!((px - m.0).abs() <= rx as f32 && (py - m.1).abs() <= ry as f32);
        }
    }
    assert!(touched > 4);
}

#[test]
fn quaternions_are_w_x_y_z_and_unnormalised() {
    // 90° about +z: (w, x, y, z) = (cos 45°, 0, 0, sin 45°), at any length.
    let h = std::f32::consts::FRAC_1_SQRT_2;
    let (r, _, _) = quat_to_rotmat([3.0 * h, 0.0, 0.0, 3.0 * h]);
    assert!((r * Vec3::X - Vec3::Y).length() < 1e-6);
    assert!((r.determinant() - 1.0).abs() < 1e-6);
    let (r, _, _) = quat_to_rotmat([0.0; 4]);
    assert_eq!(r, Mat3::IDENTITY);
}

#[test]
fn a_resized_camera_sees_the_same_view() {
    let cam = Camera::look_at(
        Vec3::new(0.3, -0.2, -3.0),
        Vec3::ZERO,
        Vec3::new(0.0, -1.0, 0.0),
        60.0,
        60.0,
        64,
        48,
    );
    let p = Vec3::new(0.35, 0.2, 0.1);
    let project = |c: &Camera| {
        let q = c.rotation * p + c.translation;
        (c.fx * q.x / q.z + c.cx, c.fy * q.y / q.z + c.cy)
    };
    let (u, v) = project(&cam);
    // Same aspect ratio: a plain rescale of the image.
    let half = cam.resized(32, 24);
    half.validate().unwrap();
    let (uh, vh) = project(&half);
    assert!((uh - u / 2.0).abs() < 1e-4 && (vh - v / 2.0).abs() < 1e-4);
    // A wider window: the vertical view and the pixel shape are kept, the centre stays centred.
    let wide = cam.resized(128, 48);
    let (uw, vw) = project(&wide);
    assert!(
        (vw - v).abs() < 1e-4,
        "vertical position moved: {v} -> {vw}"
    );
    assert!((uw - (u + 32.0)).abs() < 1e-4, "horizontal: {u} -> {uw}");
    assert_eq!(wide.fx / wide.fy, cam.fx / cam.fy);
    // And the renderer agrees: the dot lands where the projection says.
    let out = render(&dot_scene(&[p]), &half, &RenderSettings::default()).unwrap();
    assert_eq!(brightest(&out), (uh as u32, vh as u32));
}
