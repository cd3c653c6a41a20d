//! The wgpu rasterizer against the CPU renderer (and so against the f64 reference), and its
//! sort and scan against CPU ones. Without an adapter these tests print why and pass, unless
//! `METASPLAT_REQUIRE_GPU=1` (set by CI after installing lavapipe) makes that a failure.

mod common;

use common::{random_scene, test_camera};
use glam::Vec3;
use splat::gpu::GpuRasterizer;
use splat::{Camera, CpuRasterizer, Gaussians, PixelGradients, Rasterizer, RenderSettings};

fn gpu() -> Option<GpuRasterizer> {
    match GpuRasterizer::new() {
        Ok(g) => {
            eprintln!("GPU tests on {}", g.context().describe());
            Some(g)
        }
        Err(e) if std::env::var("METASPLAT_REQUIRE_GPU").is_ok_and(|v| v == "1") => {
            panic!("METASPLAT_REQUIRE_GPU=1 but there is no GPU: {e}")
        }
        Err(e) => {
            eprintln!("SKIP: GPU tests need a wgpu adapter (e.g. lavapipe): {e}");
            None
        }
    }
}

/// Largest absolute difference of colour, alpha and depth (depth relative to max(1, depth)).
fn compare(gpu: &GpuRasterizer, g: &Gaussians, cam: &Camera, s: &RenderSettings) -> f32 {
    let cpu = CpuRasterizer;
    let want = cpu.render(&cpu.upload(g).unwrap(), cam, s).unwrap();
    let got = gpu.render(&gpu.upload(g).unwrap(), cam, s).unwrap();
    let mut err = 0.0f32;
    for i in 0..want.color.len() {
        err = err.max((want.color[i] - got.color[i]).abs().max_element());
        err = err.max((want.alpha[i] - got.alpha[i]).abs());
        err = err.max((want.depth[i] - got.depth[i]).abs() / want.depth[i].max(1.0));
    }
    assert_eq!(want.visible, got.visible, "culling differs");
    for (a, b) in want.radii.iter().zip(&got.radii) {
        assert!(
            (a[0] - b[0]).abs() <= 1 && (a[1] - b[1]).abs() <= 1,
            "radius {a:?} vs {b:?}"
        );
    }
    // Work of the same size: the GPU blends what the CPU blends (up to threshold ties).
    let (a, b) = (want.num_blended as f64, got.num_blended as f64);
    assert!((a - b).abs() <= 1e-3 * a.max(1.0), "blended {a} vs {b}");
    eprintln!("{} splats: max error {err:e}, {a} pairs blended", g.len());
    err
}

#[test]
fn forward_matches_the_cpu_renderer() {
    let Some(gpu) = gpu() else { return };
    let cam = test_camera(53, 37, 45.0);
    for (seed, n, deg, aa, scales) in [
        (1, 40, 0, false, (0.05, 0.3)),
        (2, 40, 1, true, (0.05, 0.3)),
        (3, 40, 2, false, (0.05, 0.3)),
        (4, 60, 3, true, (0.05, 0.3)),
        // Many small Gaussians.
        (5, 2000, 3, false, (0.005, 0.03)),
        // Large, overlapping: opaque layers and the transmittance stop.
        (6, 300, 1, false, (0.2, 0.8)),
    ] {
        let g = random_scene(seed, n, 3, scales, 1.2);
        let s = RenderSettings {
            sh_degree: deg,
            background: Vec3::new(0.2, 0.5, 0.9),
            antialiased: aa,
        };
        let err = compare(&gpu, &g, &cam, &s);
        assert!(err <= 1e-4, "seed {seed}: max error {err}");
        let alpha = CpuRasterizer.render(&&g, &cam, &s).unwrap().alpha;
        assert!(
            alpha.iter().any(|a| *a > 0.5),
            "seed {seed}: the scene is not in view"
        );
    }
}

#[test]
fn needles_and_hard_cases_stay_finite_and_match() {
    let Some(gpu) = gpu() else { return };
    let cam = test_camera(40, 30, 35.0);
    let mut g = random_scene(9, 200, 0, (0.01, 0.4), 1.0);
    // Needles: one axis thousands of times longer than another.
    for i in 0..g.len() {
        g.log_scales[i].x = -9.0;
        g.log_scales[i].y += 1.0;
    }
    // Non-finite parameters are culled, as on the CPU.
    g.means[3].x = f32::NAN;
    g.log_scales[4].z = f32::INFINITY;
    g.logit_opacities[5] = f32::NAN;
    g.rotations[6] = [0.0; 4];
    let s = RenderSettings::default();
    let err = compare(&gpu, &g, &cam, &s);
    assert!(err <= 1e-4, "max error {err}");
    let out = gpu.render(&gpu.upload(&g).unwrap(), &cam, &s).unwrap();
    assert!(out.color.iter().all(|c| c.is_finite()));
    assert!(out.depth.iter().chain(&out.alpha).all(|v| v.is_finite()));
    // Their gradients (the projection backward runs on the GPU too) stay finite and match.
    let v_color = vec![Vec3::new(0.7, -0.4, 0.2); cam.num_pixels()];
    let pixel = PixelGradients::color(&v_color);
    let cpu = CpuRasterizer;
    let cs = cpu.upload(&g).unwrap();
    let (_, saved) = cpu.render_for_backward(&cs, &cam, &s).unwrap();
    let want = cpu.backward(&cs, &saved, pixel).unwrap();
    let gs = gpu.upload(&g).unwrap();
    let (_, saved) = gpu.render_for_backward(&gs, &cam, &s).unwrap();
    let got = gpu.backward(&gs, &saved, pixel).unwrap();
    assert!(got.params.is_finite(), "a needle's gradient is not finite");
    // A zero quaternion is the identity rotation; the non-finite splats are culled.
    for i in 3..=5 {
        assert_eq!(
            got.params.means[i],
            Vec3::ZERO,
            "culled splat {i} has a gradient"
        );
    }
    let e = rel(&got.params.packed(), &want.params.packed());
    assert!(e <= 1e-3, "needle gradients differ by {e:e} (relative)");
    // An empty scene is the background.
    let empty = Gaussians::new(0);
    let bg = RenderSettings {
        background: Vec3::new(0.1, 0.2, 0.3),
        ..s
    };
    let out = gpu.render(&gpu.upload(&empty).unwrap(), &cam, &bg).unwrap();
    assert!(out.color.iter().all(|c| *c == bg.background));
}

#[test]
fn a_larger_image_with_many_tiles_matches() {
    let Some(gpu) = gpu() else { return };
    let cam = test_camera(260, 190, 220.0);
    let g = random_scene(11, 5000, 1, (0.01, 0.08), 1.3);
    let s = RenderSettings {
        sh_degree: 1,
        ..Default::default()
    };
    let err = compare(&gpu, &g, &cam, &s);
    assert!(err <= 1e-4, "max error {err}");
}

#[test]
fn radix_sort_is_stable_and_matches_a_cpu_sort() {
    let Some(gpu) = gpu() else { return };
    let mut rng = base::SplitMix64::new(5);
    for n in [1usize, 255, 256, 257, 5000, 70_000] {
        // Few distinct keys, so many duplicates; values record the input order.
        let hi: Vec<u32> = (0..n).map(|_| (rng.next_u64() % 37) as u32).collect();
        let lo: Vec<u32> = (0..n)
            .map(|_| (rng.next_u64() % 5) as u32 * 0x1234_5677)
            .collect();
        let vals: Vec<u32> = (0..n as u32).collect();
        let got = gpu.sort_pairs(&hi, &lo, &vals, 6).unwrap();
        let mut want: Vec<(u32, u32, u32)> = (0..n).map(|i| (hi[i], lo[i], vals[i])).collect();
        want.sort_by_key(|&(h, l, _)| (h, l)); // stable
        assert_eq!(got, want, "n = {n}");
    }
}

#[test]
fn exclusive_scan_matches_a_cpu_scan() {
    let Some(gpu) = gpu() else { return };
    let mut rng = base::SplitMix64::new(8);
    for n in [1usize, 256, 257, 65_536, 70_001] {
        let v: Vec<u32> = (0..n).map(|_| (rng.next_u64() % 9) as u32).collect();
        let mut want = Vec::with_capacity(n);
        let mut acc = 0u32;
        for x in &v {
            want.push(acc);
            acc += x;
        }
        assert_eq!(gpu.exclusive_scan(&v).unwrap(), want, "n = {n}");
    }
}

/// `|a − b| / |b|` over one parameter group (0 when both are 0).
fn rel(a: &[f32], b: &[f32]) -> f64 {
    let d: f64 = a.iter().zip(b).map(|(x, y)| ((x - y) as f64).powi(2)).sum();
    let n: f64 = b.iter().map(|y| (*y as f64).powi(2)).sum();
    if n == 0.0 { d.sqrt() } else { (d / n).sqrt() }
}

fn flat3(v: &[Vec3]) -> Vec<f32> {
    v.iter().flat_map(|c| c.to_array()).collect()
}

#[test]
fn backward_matches_the_cpu_backward() {
    let Some(gpu) = gpu() else { return };
    let cam = test_camera(61, 43, 50.0);
    let mut rng = base::SplitMix64::new(3);
    for (seed, n, deg, aa) in [(21, 80, 0, false), (22, 80, 3, true), (23, 1500, 2, false)] {
        let g = random_scene(seed, n, 3, (0.02, 0.3), 1.2);
        let s = RenderSettings {
            sh_degree: deg,
            background: Vec3::new(0.3, 0.1, 0.6),
            antialiased: aa,
        };
        let np = cam.num_pixels();
        let mut r = || rng.normal() as f32;
        let v_color: Vec<Vec3> = (0..np).map(|_| Vec3::new(r(), r(), r())).collect();
        let v_alpha: Vec<f32> = (0..np).map(|_| r()).collect();
        let v_depth: Vec<f32> = (0..np).map(|_| r()).collect();
        let pixel = PixelGradients {
            color: &v_color,
            alpha: Some(&v_alpha),
            depth: Some(&v_depth),
        };
        let cpu = CpuRasterizer;
        let cs = cpu.upload(&g).unwrap();
        let (_, saved) = cpu.render_for_backward(&cs, &cam, &s).unwrap();
        let want = cpu.backward(&cs, &saved, pixel).unwrap();
        let gs = gpu.upload(&g).unwrap();
        let (_, saved) = gpu.render_for_backward(&gs, &cam, &s).unwrap();
        let got = gpu.backward(&gs, &saved, pixel).unwrap();
        let (w, h) = (&want.params, &got.params);
        let groups = [
            ("means", rel(&flat3(&h.means), &flat3(&w.means))),
            (
                "log_scales",
                rel(&flat3(&h.log_scales), &flat3(&w.log_scales)),
            ),
            (
                "rotations",
                rel(&h.rotations.concat(), &w.rotations.concat()),
            ),
            ("opacities", rel(&h.logit_opacities, &w.logit_opacities)),
            ("sh_dc", rel(&flat3(&h.sh_dc), &flat3(&w.sh_dc))),
            ("sh_rest", rel(&flat3(&h.sh_rest), &flat3(&w.sh_rest))),
            (
                "means2d",
                rel(&got.means2d.concat(), &want.means2d.concat()),
            ),
            (
                "means2d_abs",
                rel(&got.means2d_abs.concat(), &want.means2d_abs.concat()),
            ),
        ];
        eprintln!("seed {seed}: {groups:?}");
        for (name, e) in groups {
            assert!(e <= 1e-3, "seed {seed}: {name} differs by {e:e} (relative)");
        }
        assert!(
            flat3(&w.means).iter().any(|v| *v != 0.0),
            "no gradient at all"
        );
    }
}
