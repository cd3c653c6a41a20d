//! Speed against error of the imaging model: forward blur (both modes, 1 and 2 threads) at
//! LLFF (504×378) and sensor (1215²) sizes, the adjoint, the Wiener bank, one propagation.
//! Before timing, each blur's error against the direct f64 spatially varying convolution is
//! measured on random pixels and printed.

#[path = "../tests/reference/mod.rs"]
mod reference;

use aberration::optics::{Propagator, SimConfig};
use aberration::{BlurMode, BlurPlan, Image, PsfGrid, wiener_bank};
use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::time::Duration;

fn random_image(w: usize, h: usize, seed: u64) -> Image {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut img = Image::new(w, h);
    img.data.iter_mut().for_each(|v| *v = rng.random::<f32>());
    img
}

/// A 9×9 grid of 135-px PSFs shaped like the metalens ones (a core on a wide halo), each
/// one different so no shortcut applies.
fn metalens_like_grid() -> PsfGrid {
    let (g, k) = (9, 135);
    let c = (k / 2) as f32;
    let mut data = Vec::with_capacity(g * g * 3 * k * k);
    for gi in 0..g * g {
        for ch in 0..3 {
            let s = 1.5 + 0.3 * ch as f32 + 0.05 * gi as f32;
            for y in 0..k {
                for x in 0..k {
                    let (dx, dy) = (x as f32 - c - 0.02 * gi as f32, y as f32 - c);
                    let r2 = dx * dx + dy * dy;
                    data.push((-r2 / (2.0 * s * s)).exp() + 0.02 * (-r2.sqrt() / 30.0).exp());
                }
            }
        }
    }
    PsfGrid::from_planar(g, k, data).unwrap()
}

fn sampled_error(x: &Image, psf: &PsfGrid, y: &Image, mode: BlurMode, samples: usize) -> f64 {
    let mut rng = ChaCha8Rng::seed_from_u64(99);
    (0..samples)
        .map(|_| {
            let (px, py, ch) = (
                rng.random_range(0..x.width),
                rng.random_range(0..x.height),
                rng.random_range(0..3),
            );
            let exact = reference::direct_pixel(x, psf, mode == BlurMode::Tiled, py, px, ch);
            (y.get(px, py, ch) as f64 - exact).abs()
        })
        .fold(0.0, f64::max)
}

fn blur(c: &mut Criterion) {
    let native = metalens_like_grid();
    let mut group = c.benchmark_group("blur_forward");
    group
        .sample_size(10)
        .measurement_time(Duration::from_secs(4))
        .warm_up_time(Duration::from_secs(1));
    for (w, h) in [(504usize, 378usize), (1215, 1215)] {
        let psf = native.for_image(w, h, None).unwrap();
        let x = random_image(w, h, 1);
        for mode in [BlurMode::Tiled, BlurMode::Blend] {
            let plan = BlurPlan::new(&psf, w, h, mode).unwrap();
            let y = plan.apply(&x).unwrap();
            let err = sampled_error(&x, &psf, &y, mode, 300);
            eprintln!(
                "{mode} {w}x{h} (K={}): max |fast - direct f64| over 300 random pixels = {err:.2e}; spectra {:.0} MB",
                psf.size(),
                plan.spectra_bytes() as f64 / 1e6
            );
            group.throughput(Throughput::Elements((w * h) as u64));
            for threads in [1, 2] {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap();
                group.bench_function(
                    BenchmarkId::new(format!("{mode}_{w}x{h}"), format!("{threads}t")),
                    |b| b.iter(|| pool.install(|| plan.apply(&x).unwrap())),
                );
            }
            if w == 504 {
                group.bench_function(
                    BenchmarkId::new(format!("{mode}_{w}x{h}_adjoint"), "2t"),
                    |b| b.iter(|| plan.adjoint(&x).unwrap()),
                );
                group.bench_function(
                    BenchmarkId::new(format!("{mode}_{w}x{h}_plan"), "2t"),
                    |b| b.iter(|| BlurPlan::new(&psf, w, h, mode).unwrap()),
                );
            }
        }
    }
    group.finish();

    let mut group = c.benchmark_group("wiener_bank");
    group
        .sample_size(10)
        .measurement_time(Duration::from_secs(4));
    let psf = native.for_image(504, 378, None).unwrap();
    let x = random_image(504, 378, 2);
    group.throughput(Throughput::Elements(504 * 378));
    group.bench_function("bank13_504x378", |b| {
        b.iter(|| wiener_bank(&x, &psf).unwrap())
    });
    group.finish();

    let mut group = c.benchmark_group("psf_simulation");
    group
        .sample_size(10)
        .measurement_time(Duration::from_secs(8));
    let cfg = SimConfig::default();
    let prop = Propagator::new(cfg.fft_size, cfg.lens.pitch_um);
    let transfer = prop.transfer(511.0, cfg.lens.focal_um);
    group.bench_function("one_propagation_3000", |b| {
        b.iter(|| prop.focal_window(&cfg.lens, 511.0, 0.2, &transfer, 200.0, 150))
    });
    group.finish();
}

criterion_group!(benches, blur);
criterion_main!(benches);
