//! The GPU rasterizer beside the CPU one, side by side in one run: forward, forward+backward
//! and a whole resident training step (forward, backward and Adam on the GPU, the model left
//! there; the CPU's step adds its Adam) at 504×378 and 1008×756 with 10k and 100k Gaussians
//! (SH degree 3), and 1M with `METASPLAT_BENCH_1M=1` (minutes per row on a software
//! adapter), on whatever adapter wgpu finds (lavapipe on CI-class machines). Prints, outside
//! the timing loops, the adapter and the GPU path's largest error against the CPU image
//! (`error …` lines on stderr). Without an adapter it says so and measures nothing.

use std::hint::black_box;

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use glam::Vec3;
use splat::gpu::{GpuRasterizer, GpuTraining};
use splat::optim::{Adam, LearningRates};
use splat::synthetic::{benchmark_camera, random_box_scene};
use splat::{CpuRasterizer, PixelGradients, Rasterizer, RenderSettings};

fn bench(c: &mut Criterion) {
    let gpu = match GpuRasterizer::new() {
        Ok(g) => g,
        Err(e) => {
            eprintln!("no GPU benchmark: {e}");
            return;
        }
    };
    eprintln!("adapter: {}", gpu.context().describe());
    let settings = RenderSettings {
        sh_degree: 3,
        ..Default::default()
    };
    let cpu = CpuRasterizer;
    let mut group = c.benchmark_group("cpu_vs_gpu");
    group.sample_size(10);
    group.warm_up_time(std::time::Duration::from_millis(300));
    group.measurement_time(std::time::Duration::from_secs(3));
    for scale in [1u32, 2] {
        let cam = benchmark_camera().resized(504 * scale, 378 * scale);
        let v_color = vec![Vec3::splat(1e-3); cam.num_pixels()];
        let big = std::env::var("METASPLAT_BENCH_1M").is_ok_and(|v| v == "1");
        let sizes: &[usize] = if big {
            &[10_000, 100_000, 1_000_000]
        } else {
            &[10_000, 100_000]
        };
        for &n in sizes {
            let g = random_box_scene(0, n, 3);
            let (cs, gs) = (cpu.upload(&g).unwrap(), gpu.upload(&g).unwrap());
            let want = cpu.render(&cs, &cam, &settings).unwrap();
            let got = gpu.render(&gs, &cam, &settings).unwrap();
            let err = want
                .color
                .iter()
                .zip(&got.color)
                .map(|(a, b)| (*a - *b).abs().max_element())
                .fold(0.0f32, f32::max);
            eprintln!(
                "error {}x{} n={n}: max |GPU - CPU| colour {err:e}",
                cam.width, cam.height
            );
            let id = format!("{}x{}/{n}", cam.width, cam.height);
            group.bench_function(BenchmarkId::new("cpu_forward", &id), |b| {
                b.iter(|| cpu.render(&cs, black_box(&cam), &settings).unwrap())
            });
            group.bench_function(BenchmarkId::new("gpu_forward", &id), |b| {
                b.iter(|| gpu.render(&gs, black_box(&cam), &settings).unwrap())
            });
            group.bench_function(BenchmarkId::new("cpu_forward_backward", &id), |b| {
                b.iter(|| {
                    let (_, s) = cpu.render_for_backward(&cs, &cam, &settings).unwrap();
                    cpu.backward(&cs, &s, PixelGradients::color(&v_color))
                        .unwrap()
                })
            });
            group.bench_function(BenchmarkId::new("gpu_forward_backward", &id), |b| {
                b.iter(|| {
                    let (_, s) = gpu.render_for_backward(&gs, &cam, &settings).unwrap();
                    gpu.backward(&gs, &s, PixelGradients::color(&v_color))
                        .unwrap()
                })
            });
            let lr = LearningRates::default();
            group.bench_function(BenchmarkId::new("cpu_train_step", &id), |b| {
                let (mut model, mut adam) = (g.clone(), Adam::new(&g));
                b.iter(|| {
                    let grads = {
                        let cs = cpu.upload(&model).unwrap();
                        let (_, s) = cpu.render_for_backward(&cs, &cam, &settings).unwrap();
                        cpu.backward(&cs, &s, PixelGradients::color(&v_color))
                            .unwrap()
                    };
                    adam.step(&mut model, &grads.params, &lr).unwrap();
                })
            });
            group.bench_function(BenchmarkId::new("gpu_train_step", &id), |b| {
                let mut t = GpuTraining::new(&gpu, &g, &Adam::new(&g)).unwrap();
                b.iter(|| {
                    let (_, s) = t.render_for_backward(&cam, &settings).unwrap();
                    t.step(
                        &s,
                        PixelGradients::color(&v_color),
                        &lr,
                        splat::Regularisers::default(),
                    )
                    .unwrap()
                })
            });
        }
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
