//! The tiled f32 renderer against the brute-force f64 reference.

mod common;

use common::reference::{RefCamera, render_ref};
use common::{flatten, random_scene, test_camera};
use glam::Vec3;
use splat::{RenderSettings, render};

fn compare(seed: u64, n: usize, deg: u32, antialiased: bool, scales: (f64, f64)) {
    let cam = test_camera(53, 37, 45.0);
    let g = random_scene(seed, n, 3, scales, 1.2);
    let bg = Vec3::new(0.2, 0.5, 0.9);
    let settings = RenderSettings {
        sh_degree: deg,
        background: bg,
        antialiased,
    };
    let out = render(&g, &cam, &settings).unwrap();
    let r = render_ref(
        &flatten(&g),
        3,
        &RefCamera::from(&cam),
        deg,
        [0.2, 0.5, 0.9],
        antialiased,
    );
    assert!(
        r.margin > 1e-5,
        "seed {seed}: scene too close to a threshold ({})",
        r.margin
    );
    let mut max_err = 0.0f64;
    for i in 0..out.color.len() {
        for ch in 0..3 {
            max_err = max_err.max((out.color[i][ch] as f64 - r.color[i][ch]).abs());
        }
        max_err = max_err.max((out.alpha[i] as f64 - r.alpha[i]).abs());
        let depth_err = (out.depth[i] as f64 - r.depth[i]).abs() / r.depth[i].max(1.0);
        max_err = max_err.max(depth_err);
    }
    assert!(
        max_err < 1e-5,
        "seed {seed} deg {deg} aa {antialiased}: max error {max_err}"
    );
    // The comparison must have had something to compare.
    let covered = r.alpha.iter().filter(|&&a| a > 0.1).count();
    assert!(
        covered > out.alpha.len() / 10,
        "seed {seed}: scene barely covers the image"
    );
}

#[test]
fn tiled_matches_reference_on_random_scenes() {
    for seed in 0..6u64 {
        for deg in 0..=3 {
            compare(seed, 60, deg, seed % 2 == 1, (0.02, 0.4));
        }
    }
}

#[test]
fn tiled_matches_reference_with_many_small_gaussians() {
    for seed in 10..13u64 {
        compare(seed, 400, 1, false, (0.005, 0.08));
    }
}

#[test]
fn tiled_matches_reference_with_opaque_layers() {
    // Dense, large Gaussians push most pixels to the transmittance stop.
    for seed in 20..23u64 {
        let cam = test_camera(40, 33, 35.0);
        let mut g = random_scene(seed, 80, 0, (0.2, 0.8), 1.0);
        for o in &mut g.logit_opacities {
            *o += 4.0;
        }
        let out = render(&g, &cam, &RenderSettings::default()).unwrap();
        let r = render_ref(&flatten(&g), 0, &RefCamera::from(&cam), 0, [0.0; 3], false);
        let saturated = out.alpha.iter().filter(|&&a| a > 0.98).count();
        assert!(saturated > out.alpha.len() / 2);
        for i in 0..out.color.len() {
            for ch in 0..3 {
                let e = (out.color[i][ch] as f64 - r.color[i][ch]).abs();
                assert!(e < 1e-5, "seed {seed} pixel {i}: error {e}");
            }
        }
    }
}

#[test]
fn tiled_matches_reference_with_needle_gaussians() {
    // Very anisotropic, randomly rotated Gaussians stress the per-row span bounds.
    for seed in 30..34u64 {
        let cam = test_camera(61, 43, 50.0);
        let mut g = random_scene(seed, 120, 0, (0.01, 0.05), 1.2);
        for (i, s) in g.log_scales.iter_mut().enumerate() {
            s[i % 3] = 0.6f32.ln();
        }
        let settings = RenderSettings {
            antialiased: seed % 2 == 0,
            ..Default::default()
        };
        let out = render(&g, &cam, &settings).unwrap();
        let r = render_ref(
            &flatten(&g),
            0,
            &RefCamera::from(&cam),
            0,
            [0.0; 3],
            settings.antialiased,
        );
        for i in 0..out.color.len() {
            let e = (0..3)
                .map(|ch| (out.color[i][ch] as f64 - r.color[i][ch]).abs())
                .fold(0.0, f64::max);
            assert!(e < 1e-5, "seed {seed} pixel {i}: error {e}");
        }
    }
}

#[test]
fn every_entry_point_renders_the_same_image() {
    use splat::{CpuRasterizer, Rasterizer, reference::render_reference, render_for_backward};
    let cam = test_camera(41, 29, 40.0);
    let g = random_scene(17, 60, 2, (0.02, 0.2), 1.2);
    let settings = RenderSettings {
        sh_degree: 2,
        background: Vec3::new(0.1, 0.3, 0.2),
        antialiased: true,
    };
    let plain = render(&g, &cam, &settings).unwrap();
    let (train, saved) = render_for_backward(&g, &cam, &settings).unwrap();
    assert_eq!(saved.camera(), &cam);
    let cpu = CpuRasterizer;
    let scene = cpu.upload(&g).unwrap();
    let traited = cpu.render(&scene, &cam, &settings).unwrap();
    for other in [&train, &traited] {
        assert_eq!(plain.color, other.color);
        assert_eq!(plain.alpha, other.alpha);
        assert_eq!(plain.depth, other.depth);
        assert_eq!(plain.radii, other.radii);
        assert_eq!(plain.num_blended, other.num_blended);
    }
    assert!(plain.num_blended > 0);
    // The convenience entry of the f64 reference agrees with the tiled renderer.
    let r = render_reference(&g, &cam, &settings);
    let err = plain
        .color
        .iter()
        .zip(&r.color)
        .flat_map(|(a, b)| (0..3).map(move |c| (a[c] as f64 - b[c]).abs()))
        .fold(0.0f64, f64::max);
    assert!(err < 1e-4, "colour error {err}");
}
