//! Degenerate inputs: nothing may panic and no NaN/Inf may reach images or gradients.

mod common;

use base::SplitMix64;
use common::reference::{RefCamera, render_ref};
use common::{flatten, random_scene, test_camera};
use glam::{Mat3, Vec3};
use splat::{
    Camera, Gaussians, Gradients, RenderOutput, RenderSettings, render, render_backward,
    render_for_backward,
};

fn identity_camera(width: u32, height: u32) -> Camera {
    Camera {
        fx: width as f32,
        fy: width as f32,
        cx: width as f32 / 2.0,
        cy: height as f32 / 2.0,
        width,
        height,
        rotation: Mat3::IDENTITY,
        translation: Vec3::ZERO,
        near: 0.01,
        far: 1000.0,
    }
}

/// Renders and back-propagates random pixel gradients under every setting combination,
/// asserting everything is finite. Returns the degree-0 results for further checks.
fn run_all(g: &Gaussians, cam: &Camera) -> (RenderOutput, Gradients) {
    let mut rng = SplitMix64::new(7);
    let npix = cam.num_pixels();
    let v_color: Vec<Vec3> = rng.normal_rgb(npix);
    let v_alpha: Vec<f32> = (0..npix).map(|_| rng.normal() as f32).collect();
    let v_depth: Vec<f32> = (0..npix).map(|_| rng.normal() as f32).collect();
    let mut first = None;
    for deg in 0..=g.sh_degree {
        for antialiased in [false, true] {
            let s = RenderSettings {
                sh_degree: deg,
                background: Vec3::new(0.1, 0.2, 0.3),
                antialiased,
            };
            let (out, saved) = render_for_backward(g, cam, &s).unwrap();
            assert!(out.color.iter().all(|c| c.is_finite()), "colour not finite");
            assert!(
                out.alpha
                    .iter()
                    .all(|a| a.is_finite() && (0.0..=1.0).contains(a))
            );
            assert!(out.depth.iter().all(|d| d.is_finite()));
            let gr = render_backward(g, &saved, &v_color, Some(&v_alpha), Some(&v_depth)).unwrap();
            let p = &gr.params;
            assert!(p.means.iter().all(|v| v.is_finite()), "mean grad");
            assert!(p.log_scales.iter().all(|v| v.is_finite()), "scale grad");
            assert!(
                p.rotations.iter().flatten().all(|v| v.is_finite()),
                "rot grad"
            );
            assert!(
                p.logit_opacities.iter().all(|v| v.is_finite()),
                "opacity grad"
            );
            assert!(p.sh_dc.iter().all(|v| v.is_finite()), "dc grad");
            assert!(p.sh_rest.iter().all(|v| v.is_finite()), "rest grad");
            assert!(gr.means2d.iter().flatten().all(|v| v.is_finite()));
            assert!(gr.means2d_abs.iter().flatten().all(|v| v.is_finite()));
            if first.is_none() {
                first = Some((out, gr));
            }
        }
    }
    first.unwrap()
}

fn one(g: &mut Gaussians, mean: Vec3, log_scale: Vec3, q: [f32; 4], logit: f32) {
    let rest = vec![Vec3::splat(0.3); g.rest_count()];
    g.push(mean, log_scale, q, logit, Vec3::new(0.5, -0.2, 0.1), &rest);
}

#[test]
fn gaussians_at_behind_and_on_the_near_plane() {
    let cam = identity_camera(24, 18);
    let mut g = Gaussians::new(3);
    let s = Vec3::splat(-1.0);
    one(&mut g, Vec3::ZERO, s, [1.0, 0.0, 0.0, 0.0], 2.0); // at the camera centre
    one(
        &mut g,
        Vec3::new(0.0, 0.0, -1.0),
        s,
        [1.0, 0.0, 0.0, 0.0],
        2.0,
    ); // behind
    one(
        &mut g,
        Vec3::new(0.0, 0.0, cam.near),
        s,
        [1.0, 0.2, 0.0, 0.0],
        2.0,
    ); // on near
    one(
        &mut g,
        Vec3::new(0.001, 0.0, cam.near),
        Vec3::splat(-8.0),
        [1.0; 4],
        2.0,
    );
    one(
        &mut g,
        Vec3::new(5.0, 0.0, 1e-3),
        s,
        [1.0, 0.0, 0.0, 0.0],
        2.0,
    ); // inside near
    let (out, _) = run_all(&g, &cam);
    assert!(!out.visible[0] && !out.visible[1] && !out.visible[4]);
    // z == near is kept (gsplat culls only z < near).
    assert!(out.visible[2]);
}

#[test]
fn extreme_scales_quaternions_and_opacities() {
    let cam = identity_camera(20, 16);
    let mut g = Gaussians::new(2);
    let p = Vec3::new(0.1, -0.05, 3.0);
    let q = [0.9, 0.1, -0.3, 0.2];
    one(&mut g, p, Vec3::splat(1e-8f32.ln()), q, 1.0);
    one(&mut g, p, Vec3::splat(1e4f32.ln()), q, 1.0);
    one(&mut g, p, Vec3::new(1e-8f32.ln(), 0.0, 1e4f32.ln()), q, 1.0);
    one(&mut g, p, Vec3::splat(-2.0), [0.0; 4], 1.0);
    one(&mut g, p, Vec3::splat(-2.0), [1e30, -2e30, 3e30, 1e30], 1.0);
    one(
        &mut g,
        p,
        Vec3::splat(-2.0),
        [f32::MAX, f32::MAX, 0.0, 0.0],
        1.0,
    );
    one(&mut g, p, Vec3::splat(-2.0), [1e-30, 0.0, 1e-30, 0.0], 1.0);
    one(&mut g, p, Vec3::splat(-2.0), q, 60.0);
    one(&mut g, p, Vec3::splat(-2.0), q, -60.0);
    one(&mut g, p, Vec3::splat(-2.0), q, f32::NAN);
    one(
        &mut g,
        Vec3::new(f32::NAN, 0.0, 1.0),
        Vec3::splat(-2.0),
        q,
        0.0,
    );
    one(&mut g, p, Vec3::splat(80.0), q, 0.0); // scale overflows f32
    let (out, grads) = run_all(&g, &cam);
    assert!(!out.visible[8], "opacity sigmoid(-60) is below 1/255");
    assert!(
        !out.visible[9] && !out.visible[10],
        "NaN parameters are culled"
    );
    assert_eq!(grads.params.logit_opacities[9], 0.0);
    // Something was drawn: the hard cases did not knock out the whole image.
    assert!(out.alpha.iter().any(|&a| a > 0.5));
}

#[test]
fn ten_thousand_gaussians_on_one_pixel() {
    let cam = identity_camera(16, 16);
    let mut g = Gaussians::new(1);
    let mut rng = SplitMix64::new(3);
    for i in 0..10_000 {
        // All centred on pixel (8, 8), tiny, at slightly different depths.
        let z = 2.0 + i as f32 * 1e-4;
        let mean = Vec3::new(0.5 / 16.0 * z, 0.5 / 16.0 * z, z);
        one(
            &mut g,
            mean,
            Vec3::splat(-7.0),
            [1.0, rng.normal() as f32, 0.0, 0.0],
            rng.uniform(-2.0, 4.0) as f32,
        );
    }
    let (out, grads) = run_all(&g, &cam);
    let c = 8 * 16 + 8;
    assert!(out.alpha[c] > 0.98, "alpha {}", out.alpha[c]);
    // The transmittance stop means only the front few receive gradient.
    let touched = grads
        .params
        .logit_opacities
        .iter()
        .filter(|&&v| v != 0.0)
        .count();
    assert!(
        touched > 0 && touched < 1000,
        "{touched} Gaussians got gradient"
    );
}

#[test]
fn empty_scene_and_one_pixel_image() {
    let cam = identity_camera(9, 7);
    let (out, grads) = run_all(&Gaussians::new(3), &cam);
    assert!(out.color.iter().all(|&c| c == Vec3::new(0.1, 0.2, 0.3)));
    assert!(out.alpha.iter().all(|&a| a == 0.0));
    assert!(grads.params.is_empty());

    let cam = test_camera(1, 1, 2.0);
    let g = random_scene(5, 50, 3, (0.05, 0.5), 1.0);
    let (out, _) = run_all(&g, &cam);
    let r = render_ref(
        &flatten(&g),
        3,
        &RefCamera::from(&cam),
        0,
        [0.1, 0.2, 0.3],
        false,
    );
    assert!(r.alpha[0] > 0.1);
    for ch in 0..3 {
        assert!((out.color[0][ch] as f64 - r.color[0][ch]).abs() < 1e-5);
    }
}

#[test]
fn bad_inputs_are_typed_errors() {
    let g = random_scene(1, 10, 1, (0.1, 0.3), 1.0);
    let cam = test_camera(8, 8, 8.0);
    let s = RenderSettings::default();
    let mut bad = cam.clone();
    bad.near = 0.0;
    assert!(matches!(
        render(&g, &bad, &s),
        Err(splat::SplatError::InvalidCamera(_))
    ));
    bad = cam.clone();
    bad.width = 0;
    assert!(render(&g, &bad, &s).is_err());
    let too_high = RenderSettings {
        sh_degree: 2,
        ..s.clone()
    };
    assert!(render(&g, &cam, &too_high).is_err());
    let mut broken = g.clone();
    broken.sh_dc.pop();
    assert!(matches!(
        render(&broken, &cam, &s),
        Err(splat::SplatError::SizeMismatch { .. })
    ));
    let (_, saved) = render_for_backward(&g, &cam, &s).unwrap();
    let v = vec![Vec3::ONE; 3];
    assert!(render_backward(&g, &saved, &v, None, None).is_err());
    let v = vec![Vec3::ONE; 64];
    let fewer = g.gather(&(0..g.len() - 1).collect::<Vec<_>>());
    assert!(render_backward(&fewer, &saved, &v, None, None).is_err());
    let nan = vec![Vec3::NAN; 64];
    assert!(render_backward(&g, &saved, &nan, None, None).is_err());
    let short = vec![1.0; 5];
    assert!(render_backward(&g, &saved, &v, None, Some(&short)).is_err());
}
