//! The vectorised pixel-block kernels against the scalar per-splat kernels they replace: the
//! same pixels blended, images and gradients equal up to the polynomial exponential and the
//! order of sums.

mod common;

use common::{random_scene, test_camera};
use glam::Vec3;
use splat::BlendKernels;
use splat::cpu::render::render_for_backward_with;
use splat::{RenderSettings, render_backward};

fn max_rel(a: &[f32], b: &[f32]) -> f32 {
    let scale = b.iter().fold(0.0f32, |m, v| m.max(v.abs())).max(1e-12);
    a.iter()
        .zip(b)
        .fold(0.0f32, |m, (x, y)| m.max((x - y).abs()))
        / scale
}

#[test]
fn blocks_match_the_scalar_kernels() {
    for (seed, n, deg, size) in [
        (1u64, 300, 0u32, (61, 47)),
        (2, 2000, 3, (130, 97)),
        (3, 6000, 1, (200, 150)),
    ] {
        let g = random_scene(seed, n, deg, (0.01, 0.4), 1.5);
        let cam = test_camera(size.0, size.1, 0.9 * size.0 as f32);
        let s = RenderSettings {
            sh_degree: deg,
            background: Vec3::new(0.1, 0.2, 0.3),
            antialiased: false,
        };
        let (fast, fs) = render_for_backward_with(&g, &cam, &s, BlendKernels::Lanes).unwrap();
        let (slow, ss) = render_for_backward_with(&g, &cam, &s, BlendKernels::Scalar).unwrap();
        // The same decisions (a pair whose α sits within the exponential's error of 1/255
        // could flip; none does here) and images within the exponential's error.
        assert_eq!(fast.num_blended, slow.num_blended, "seed {seed}");
        let flat = |v: &[Vec3]| v.iter().flat_map(|p| p.to_array()).collect::<Vec<f32>>();
        let e = max_rel(&flat(&fast.color), &flat(&slow.color));
        assert!(e < 2e-6, "seed {seed}: colour differs by {e:e}");
        assert!(max_rel(&fast.alpha, &slow.alpha) < 2e-6);
        assert!(max_rel(&fast.depth, &slow.depth) < 2e-6);
        // Gradients of the same pixel gradients, with alpha and depth terms.
        let v: Vec<Vec3> = (0..cam.num_pixels())
            .map(|i| {
                Vec3::new(
                    (i % 7) as f32 - 3.0,
                    (i % 5) as f32 - 2.0,
                    (i % 3) as f32 - 1.0,
                ) * 1e-2
            })
            .collect();
        let va: Vec<f32> = (0..cam.num_pixels())
            .map(|i| ((i % 11) as f32 - 5.0) * 1e-3)
            .collect();
        let vd: Vec<f32> = (0..cam.num_pixels())
            .map(|i| ((i % 13) as f32 - 6.0) * 1e-3)
            .collect();
        let gf = render_backward(&g, &fs, &v, Some(&va), Some(&vd)).unwrap();
        let gs = render_backward(&g, &ss, &v, Some(&va), Some(&vd)).unwrap();
        let e = max_rel(&gf.params.packed(), &gs.params.packed());
        assert!(e < 5e-5, "seed {seed}: parameter gradients differ by {e:e}");
        let m2 = |v: &[[f32; 2]]| v.iter().flatten().copied().collect::<Vec<f32>>();
        assert!(max_rel(&m2(&gf.means2d), &m2(&gs.means2d)) < 5e-5);
        assert!(max_rel(&m2(&gf.means2d_abs), &m2(&gs.means2d_abs)) < 5e-5);
    }
}

#[test]
fn blocks_give_the_same_bits_for_any_thread_count() {
    let g = random_scene(9, 3000, 2, (0.01, 0.3), 1.5);
    let cam = test_camera(150, 110, 140.0);
    let s = RenderSettings {
        sh_degree: 2,
        ..Default::default()
    };
    let v = vec![Vec3::splat(1e-2); cam.num_pixels()];
    let run = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| {
                let (o, st) = render_for_backward_with(&g, &cam, &s, BlendKernels::Lanes).unwrap();
                let gr = render_backward(&g, &st, &v, None, None).unwrap();
                (o.color, gr.params.packed())
            })
    };
    assert_eq!(run(1), run(3));
}
