//! The GPU rasterizer beside the CPU one, side by side in one run: forward and
//! forward+backward at 504×378 and 1008×756 with 10k and 100k Gaussians (SH degree 3), on
//! whatever adapter wgpu finds (lavapipe on CI-class machines). Prints, outside the timing
//! loops, the adapter and the GPU path's largest error against the CPU image (`error …`
//! lines on stderr). Without an adapter it says so and measures nothing.

use std::hint::black_box;

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use glam::Vec3;
use splat::gpu::GpuRasterizer;
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
        for n in [10_000usize, 100_000] {
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
        }
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
