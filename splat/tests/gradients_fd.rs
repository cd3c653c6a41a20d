//! Analytic gradients (f32) against central finite differences of the f64 reference renderer.

mod common;

use base::SplitMix64;
use common::reference::{RefCamera, render_ref};
use common::{GROUP_NAMES, flatten, group_of, params_per_gaussian, random_scene, test_camera};
use glam::Vec3;
use splat::{Camera, Gaussians, RenderSettings, render_backward, render_for_backward};

const BG: [f64; 3] = [0.3, 0.1, 0.6];

/// Few large, semi-transparent Gaussians filling a tiny image: every pixel/Gaussian pair has
/// α far above 1/255 and below 0.99, transmittance stays far above 1e-4.
fn fd_scene(seed: u64, clamped_one: bool) -> (Gaussians, Camera) {
    let cam = test_camera(13, 11, 14.0);
    let mut g = random_scene(seed, 5, 3, (0.8, 2.0), 0.6);
    for o in &mut g.logit_opacities {
        *o = o.clamp(-1.0, 1.0);
    }
    if clamped_one {
        // Far outside the frustum so the Jacobian clamp is active for this one.
        let p_cam = Vec3::new(4.5, 0.3, 3.5);
        g.means[0] = cam.rotation.transpose() * (p_cam - cam.translation);
        g.log_scales[0] = Vec3::splat(1.3);
    }
    (g, cam)
}

fn check(seed: u64, deg: u32, antialiased: bool, clamped_one: bool) {
    let (g, cam) = fd_scene(seed, clamped_one);
    let rcam = RefCamera::from(&cam);
    let params = flatten(&g);
    let base = render_ref(&params, 3, &rcam, deg, BG, antialiased);
    assert!(
        base.margin > 1e-3,
        "seed {seed}: FD scene too close to a threshold ({})",
        base.margin
    );
    let npix = cam.num_pixels();
    let mut rng = SplitMix64::new(seed ^ 0xfeed);
    let w: Vec<[f64; 3]> = (0..npix)
        .map(|_| {
            [
                rng.uniform(-1.0, 1.0),
                rng.uniform(-1.0, 1.0),
                rng.uniform(-1.0, 1.0),
            ]
        })
        .collect();
    let u: Vec<f64> = (0..npix).map(|_| rng.uniform(-1.0, 1.0)).collect();
    let r: Vec<f64> = (0..npix).map(|_| rng.uniform(-0.3, 0.3)).collect();
    let loss = |p: &[f64]| {
        let img = render_ref(p, 3, &rcam, deg, BG, antialiased);
        let mut l = 0.0;
        for i in 0..npix {
            l += (0..3).map(|ch| w[i][ch] * img.color[i][ch]).sum::<f64>();
            l += u[i] * img.alpha[i] + r[i] * img.depth[i];
        }
        l
    };

    let settings = RenderSettings {
        sh_degree: deg,
        background: Vec3::from_array(BG.map(|v| v as f32)),
        antialiased,
    };
    let (_, saved) = render_for_backward(&g, &cam, &settings).unwrap();
    let v_color: Vec<Vec3> = w
        .iter()
        .map(|c| Vec3::new(c[0] as f32, c[1] as f32, c[2] as f32))
        .collect();
    let v_alpha: Vec<f32> = u.iter().map(|&v| v as f32).collect();
    let v_depth: Vec<f32> = r.iter().map(|&v| v as f32).collect();
    let grads = render_backward(&g, &saved, &v_color, Some(&v_alpha), Some(&v_depth)).unwrap();
    let analytic = flatten(&grads.params);

    let ppg = params_per_gaussian(3);
    let h = 1e-6;
    let mut numeric = vec![0.0; params.len()];
    for k in 0..params.len() {
        let mut p = params.clone();
        p[k] += h;
        let lp = loss(&p);
        p[k] -= 2.0 * h;
        let lm = loss(&p);
        numeric[k] = (lp - lm) / (2.0 * h);
    }
    // Per-group scale so tiny entries are judged against the group's magnitude.
    let mut scale = [0.0f64; 6];
    for (k, n) in numeric.iter().enumerate() {
        let gi = group_of(k % ppg);
        scale[gi] = scale[gi].max(n.abs());
    }
    let mut nonzero = [false; 6];
    for k in 0..params.len() {
        let gi = group_of(k % ppg);
        let (a, n) = (analytic[k], numeric[k]);
        let tol = 2e-3 * n.abs() + 2e-4 * scale[gi] + 1e-6;
        assert!(
            (a - n).abs() <= tol,
            "seed {seed} deg {deg} aa {antialiased}: gaussian {} {} [{}]: analytic {a}, fd {n}",
            k / ppg,
            GROUP_NAMES[gi],
            k % ppg
        );
        if n.abs() > 1e-3 {
            nonzero[gi] = true;
        }
    }
    // Every group the degree uses must actually have been exercised.
    for (gi, name) in GROUP_NAMES.iter().enumerate() {
        let expected = gi < 5 || deg > 0;
        assert_eq!(nonzero[gi], expected, "seed {seed} deg {deg}: group {name}");
    }
}

#[test]
fn gradients_match_finite_differences_all_sh_degrees() {
    for deg in 0..=3 {
        for seed in 0..3 {
            check(seed + 10 * deg as u64, deg, false, false);
        }
    }
}

#[test]
fn gradients_match_finite_differences_antialiased() {
    for seed in 100..103 {
        check(seed, 3, true, false);
    }
}

#[test]
fn gradients_match_finite_differences_with_jacobian_clamp() {
    for seed in 200..203 {
        check(seed, 2, seed % 2 == 0, true);
    }
}
