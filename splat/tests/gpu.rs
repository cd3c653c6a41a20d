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

/// Largest elementwise difference relative to the larger magnitude (with a floor of `floor`).
fn max_rel(a: &[f32], b: &[f32], floor: f32) -> f32 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs() / x.abs().max(y.abs()).max(floor))
        .fold(0.0, f32::max)
}

/// The GPU optimiser against the CPU one on the same gradients: every group's own learning
/// rate, bias correction over several steps, the opacity and scale penalties, and a non-finite gradient
/// that both skip (the GPU also reports it).
#[test]
fn gpu_adam_matches_the_cpu_optimiser() {
    let Some(gpu) = gpu() else { return };
    let mut model = random_scene(31, 300, 3, (0.02, 0.3), 1.2);
    let lr = splat::optim::LearningRates {
        means: 1e-3,
        ..Default::default()
    };
    let reg = splat::Regularisers {
        opacity: 0.5,
        scale: 0.3,
    };
    let mut adam = splat::optim::Adam::new(&model);
    let mut resident = splat::gpu::GpuTraining::new(&gpu, &model, &adam).unwrap();
    let mut rng = base::SplitMix64::new(8);
    for step in 0..4 {
        let mut grads = Gaussians::zeros(model.len(), model.sh_degree);
        let mut values = grads.packed();
        for v in &mut values {
            *v = rng.normal() as f32 * 10f32.powi((rng.next_u64() % 5) as i32 - 3);
        }
        grads = Gaussians::from_packed(&values, model.sh_degree).unwrap();
        if step == 2 {
            grads.means[7].y = f32::NAN;
        }
        let report = resident.apply_gradients(&grads, &lr, reg).unwrap();
        assert_eq!(report.nonfinite_gradient, step == 2);
        assert!(!report.nonfinite_parameter);
        // The CPU: the penalties' gradients added as the CPU trainer adds them.
        reg.add_gradients(&mut grads, &model);
        adam.step(&mut model, &grads, &lr).unwrap();
    }
    let (got, got_adam) = resident.download().unwrap();
    assert_eq!(got_adam.steps_taken(), adam.steps_taken());
    let e = max_rel(&got.packed(), &model.packed(), 1e-3);
    let (m, v) = adam.moments();
    let (gm, gv) = got_adam.moments();
    let em = max_rel(&gm.packed(), &m.packed(), 1e-9);
    let ev = max_rel(&gv.packed(), &v.packed(), 1e-12);
    eprintln!("Adam on the GPU: parameters {e:e}, m {em:e}, v {ev:e}");
    assert!(e <= 1e-5 && em <= 1e-5 && ev <= 1e-5, "{e:e} {em:e} {ev:e}");
    assert!(got.means[7].is_finite());
}

/// A resident training step (render, backward and Adam on the GPU; the loss gradient from the
/// host) against the same step on the CPU.
#[test]
fn a_resident_training_step_matches_the_cpu_step() {
    let Some(gpu) = gpu() else { return };
    let cam = test_camera(61, 43, 50.0);
    let model = random_scene(41, 400, 3, (0.02, 0.3), 1.2);
    let s = RenderSettings {
        sh_degree: 2,
        ..Default::default()
    };
    let lr = splat::optim::LearningRates::default();
    let np = cam.num_pixels();
    let mut rng = base::SplitMix64::new(5);
    let v_color: Vec<Vec3> = rng.normal_rgb(np);
    let pixel = PixelGradients::color(&v_color);

    let cpu = CpuRasterizer;
    let scene = cpu.upload(&model).unwrap();
    let (_, saved) = cpu.render_for_backward(&scene, &cam, &s).unwrap();
    let grads = cpu.backward(&scene, &saved, pixel).unwrap();
    let mut want = model.clone();
    splat::optim::Adam::new(&model)
        .step(&mut want, &grads.params, &lr)
        .unwrap();

    let mut resident =
        splat::gpu::GpuTraining::new(&gpu, &model, &splat::optim::Adam::new(&model)).unwrap();
    let (out, saved) = resident.render_for_backward(&cam, &s).unwrap();
    assert_eq!(out.color.len(), np);
    let report = resident
        .step(&saved, pixel, &lr, splat::Regularisers::default())
        .unwrap();
    assert!(!report.nonfinite_gradient && !report.nonfinite_parameter);
    let e2d = (rel(&report.means2d.concat(), &grads.means2d.concat())) as f32;
    let (got, _) = resident.download().unwrap();
    // Adam's first step moves each value by about its learning rate times the gradient's sign,
    // so compare the updates; a gradient within rounding of zero may flip its sign.
    let delta = |a: &Gaussians| -> Vec<f32> {
        a.packed()
            .iter()
            .zip(model.packed())
            .map(|(x, y)| x - y)
            .collect()
    };
    let e = rel(&delta(&got), &delta(&want));
    eprintln!("resident step: update differs by {e:e}, screen gradients by {e2d:e}");
    assert!(e2d <= 1e-3, "screen-space mean gradients differ by {e2d:e}");
    assert!(e <= 1e-2, "the update differs by {e:e} (relative)");

    // Later steps reuse the first step's working buffers (the same view needs no more), and a
    // render whose buffers a later render took cannot be backpropagated.
    let held = resident.scratch_bytes();
    assert!(held > 0);
    for _ in 0..3 {
        let (_, saved) = resident.render_for_backward(&cam, &s).unwrap();
        resident
            .step(&saved, pixel, &lr, splat::Regularisers::default())
            .unwrap();
    }
    assert_eq!(
        resident.scratch_bytes(),
        held,
        "working buffers were reallocated"
    );
    // Reused buffers' old contents do not matter: a step in them equals the same step in
    // fresh ones, bit for bit.
    let (state, adam) = resident.download().unwrap();
    let mut fresh = splat::gpu::GpuTraining::new(&gpu, &state, &adam).unwrap();
    for t in [&mut resident, &mut fresh] {
        let (_, saved) = t.render_for_backward(&cam, &s).unwrap();
        t.step(&saved, pixel, &lr, splat::Regularisers::default())
            .unwrap();
    }
    assert_eq!(resident.download().unwrap().0, fresh.download().unwrap().0);
    let (_, old) = resident.render_for_backward(&cam, &s).unwrap();
    let (_, _new) = resident.render_for_backward(&cam, &s).unwrap();
    let err = resident
        .step(&old, pixel, &lr, splat::Regularisers::default())
        .unwrap_err()
        .to_string();
    assert!(err.contains("reused"), "{err}");
}

/// A scene larger than one binding (1M splats at SH 3 on lavapipe) is projected, backpropagated
/// and optimised in pieces: the same scene split into many small pieces renders, differentiates
/// and trains bit for bit as in one piece.
#[test]
fn a_scene_bound_in_pieces_matches_one_bound_whole() {
    let Some(whole) = gpu() else { return };
    let model = random_scene(43, 1000, 3, (0.02, 0.3), 1.2);
    let stride = 14 + 3 * model.rest_count() as u64;
    let split = whole.clone().with_binding_limit(3 * 64 * 4 * stride - 1);
    let pieces = split.chunks(model.len() as u32, stride as u32);
    assert_eq!(pieces.len(), 8, "{pieces:?}");
    assert_eq!(whole.chunks(model.len() as u32, stride as u32).len(), 1);

    let cam = test_camera(61, 43, 50.0);
    let s = RenderSettings {
        sh_degree: 3,
        ..Default::default()
    };
    let np = cam.num_pixels();
    let mut rng = base::SplitMix64::new(9);
    let v_color: Vec<Vec3> = (0..np)
        .map(|_| Vec3::new(rng.normal() as f32, rng.normal() as f32, 1.0))
        .collect();
    let pixel = PixelGradients::color(&v_color);
    let run = |r: &GpuRasterizer| {
        let scene = r.upload(&model).unwrap();
        let (out, saved) = r.render_for_backward(&scene, &cam, &s).unwrap();
        let grads = r.backward(&scene, &saved, pixel).unwrap();
        assert!(out.num_intersections > 0);
        (out.color, out.alpha, out.radii, grads.params, grads.means2d)
    };
    assert!(
        run(&split) == run(&whole),
        "a split render or backward differs"
    );

    let lr = splat::optim::LearningRates::default();
    let train = |r: &GpuRasterizer| {
        let adam = splat::optim::Adam::new(&model);
        let mut t = splat::gpu::GpuTraining::new(r, &model, &adam).unwrap();
        for _ in 0..2 {
            let (_, saved) = t.render_for_backward(&cam, &s).unwrap();
            t.step(
                &saved,
                pixel,
                &lr,
                splat::Regularisers {
                    opacity: 0.01,
                    scale: 0.01,
                },
            )
            .unwrap();
        }
        let (g, adam) = t.download().unwrap();
        let (m, v) = adam.moments();
        (g, m.clone(), v.clone())
    };
    let (a, b) = (train(&split), train(&whole));
    assert_ne!(a.0, model, "training did not move the model");
    assert!(a == b, "split training differs");
}

/// The two trainers behind one interface: the same steps (render, a loss gradient from the
/// host, backward, the opacity penalty, Adam) with an edit of the host model between them (a
/// prune and a new SH band, as the hooks make) give the same model on the GPU as on the CPU:
/// the edit reaches the GPU before its next render, and the host copy a hook reads is the one
/// the GPU stepped. The GPU trainer refuses a step without its own render.
#[test]
fn the_gpu_trainer_follows_the_cpu_trainer_through_steps_and_edits() {
    use splat::SplatTrainer;
    let Some(gpu) = gpu() else { return };
    let cam = test_camera(57, 41, 50.0);
    let model = random_scene(43, 300, 1, (0.02, 0.3), 1.2);
    let adam = splat::optim::Adam::new(&model);
    let lr = splat::optim::LearningRates {
        means: 1e-3,
        ..Default::default()
    };
    let mut cpu = splat::CpuTrainer::new(model.clone(), adam.clone()).unwrap();
    let mut on_gpu = splat::gpu::GpuTrainer::new(&gpu, model, adam).unwrap();
    let target: Vec<Vec3> = base::SplitMix64::new(3).normal_rgb(cam.num_pixels());
    fn settings<T: SplatTrainer>(t: &T) -> RenderSettings {
        RenderSettings {
            sh_degree: t.sh_degree(),
            ..Default::default()
        }
    }
    fn steps<T: SplatTrainer>(
        t: &mut T,
        cam: &Camera,
        target: &[Vec3],
        lr: &splat::optim::LearningRates,
    ) {
        for _ in 0..3 {
            let (out, saved) = t.render(cam, &settings(t)).unwrap();
            // The gradient of ½‖render − target‖².
            let v: Vec<Vec3> = out.color.iter().zip(target).map(|(a, b)| *a - *b).collect();
            let reg = splat::Regularisers {
                opacity: 0.3,
                scale: 0.2,
            };
            let report = t.step(saved, PixelGradients::color(&v), lr, reg).unwrap();
            assert!(!report.nonfinite_gradient && !report.nonfinite_parameter);
            assert_eq!(report.means2d.len(), t.len());
        }
    }
    fn edit<T: SplatTrainer>(t: &mut T) {
        let (model, adam) = t.host_mut().unwrap();
        let mask: Vec<bool> = (0..model.len()).map(|i| i % 7 == 3).collect();
        let sources = splat::densify::prune_gaussians(model, &mask).unwrap();
        adam.remap(&sources).unwrap();
        model.set_sh_degree(2);
        adam.set_sh_degree(2);
    }
    // Adam's normalised steps magnify float rounding where gradients are tiny, so parameters
    // are compared relative to a floor of 1e-2; a missed edit or a stale host copy differs by
    // whole steps (and in shape or step count).
    let compare = |cpu: &mut splat::CpuTrainer, on_gpu: &mut splat::gpu::GpuTrainer| {
        let (want, want_adam) = cpu.host().unwrap();
        let (want, steps) = (want.packed(), want_adam.steps_taken());
        let (got, got_adam) = on_gpu.host().unwrap();
        assert_eq!(
            got_adam.steps_taken(),
            steps,
            "the host copy is not the GPU's"
        );
        assert_eq!(got.packed().len(), want.len());
        max_rel(&got.packed(), &want, 1e-2)
    };
    steps(&mut cpu, &cam, &target, &lr);
    steps(&mut on_gpu, &cam, &target, &lr);
    let before = compare(&mut cpu, &mut on_gpu);
    edit(&mut cpu);
    edit(&mut on_gpu);
    assert_eq!((on_gpu.len(), on_gpu.sh_degree()), (cpu.len(), 2));
    // The edited model is the one the GPU renders next.
    let (want, _) = cpu.render(&cam, &settings(&cpu)).unwrap();
    let (got, _) = on_gpu.render(&cam, &settings(&on_gpu)).unwrap();
    let image = max_rel(
        &want
            .color
            .iter()
            .flat_map(|c| c.to_array())
            .collect::<Vec<_>>(),
        &got.color
            .iter()
            .flat_map(|c| c.to_array())
            .collect::<Vec<_>>(),
        1.0,
    );
    steps(&mut cpu, &cam, &target, &lr);
    steps(&mut on_gpu, &cam, &target, &lr);
    let after = compare(&mut cpu, &mut on_gpu);
    eprintln!(
        "GPU trainer against the CPU one: {before:e} before the edit, render after it {image:e}, {after:e} three steps later"
    );
    assert!(image <= 1e-4, "{image:e}");
    assert!(before <= 1e-4 && after <= 1e-3, "{before:e} {after:e}");
    // A render of another trainer is no render of this one's.
    let (model, adam) = on_gpu.into_host().unwrap();
    let (_, saved) = on_gpu_again(&gpu, &model, &adam)
        .render(&cam, &RenderSettings::default())
        .unwrap();
    let v = vec![Vec3::ZERO; cam.num_pixels()];
    let err = on_gpu_again(&gpu, &model, &adam).step(
        saved,
        PixelGradients::color(&v),
        &lr,
        splat::Regularisers::default(),
    );
    assert!(err.is_err(), "a step before the trainer's own render");
}

fn on_gpu_again(
    gpu: &GpuRasterizer,
    model: &Gaussians,
    adam: &splat::optim::Adam,
) -> splat::gpu::GpuTrainer {
    splat::gpu::GpuTrainer::new(gpu, model.clone(), adam.clone()).unwrap()
}
