//! Forward and forward+backward at 504×378 with 10k / 100k / 300k Gaussians (SH degree 3),
//! on 1 and 2 rayon threads. Also prints the work counts the README's FLOP floor is built on.

use std::hint::black_box;

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use glam::Vec3;
use splat::synthetic::{benchmark_camera, random_box_scene};
use splat::{RenderSettings, render, render_backward};

/// FLOP model (elementary operations, `exp` counted as one): see the README.
const FWD_PER_GAUSSIAN: f64 = 400.0;
const FWD_PER_BLEND: f64 = 24.0;
const BWD_PER_GAUSSIAN: f64 = 1000.0;
const BWD_PER_BLEND: f64 = 60.0;

fn bench(c: &mut Criterion) {
    let cam = benchmark_camera();
    let settings = RenderSettings {
        sh_degree: 3,
        ..Default::default()
    };
    let v_color = vec![Vec3::splat(1e-3); cam.num_pixels()];
    let mut group = c.benchmark_group("render_504x378");
    group.sample_size(10);
    group.warm_up_time(std::time::Duration::from_millis(500));
    group.measurement_time(std::time::Duration::from_secs(3));
    for n in [10_000usize, 100_000, 300_000] {
        let g = random_box_scene(0, n, 3);
        let out = render(&g, &cam, &settings).unwrap();
        let visible = out.visible.iter().filter(|v| **v).count() as f64;
        let blended = out.num_blended() as f64;
        let fwd = visible * FWD_PER_GAUSSIAN + blended * FWD_PER_BLEND;
        let bwd = visible * BWD_PER_GAUSSIAN + blended * BWD_PER_BLEND;
        eprintln!(
            "n={n}: visible={visible} tile_intersections={} blended_pairs={blended} \
             forward_flops={:.3e} forward_backward_flops={:.3e}",
            out.num_intersections(),
            fwd,
            fwd + bwd
        );
        for threads in [1usize, 2] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            let id = format!("{n}/{threads}t");
            group.bench_function(BenchmarkId::new("forward", &id), |b| {
                b.iter(|| pool.install(|| render(black_box(&g), &cam, &settings).unwrap()))
            });
            group.bench_function(BenchmarkId::new("forward_backward", &id), |b| {
                b.iter(|| {
                    pool.install(|| {
                        let out = render(black_box(&g), &cam, &settings).unwrap();
                        render_backward(&g, &cam, &settings, &out, &v_color, None, None).unwrap()
                    })
                })
            });
        }
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
