//! Restorer speed: inference ms per megapixel for each config, tiled against whole-image
//! inference (time and error), training steps per second, and peak resident memory.
//!
//! `cargo bench -p restore --bench restore` (`-- tiny` for the tiny config only).

use burn::module::Module;
use burn::optim::{AdamWConfig, GradientsParams};
use burn::tensor::{Device, Distribution, Tensor, TensorData};
use criterion::{Criterion, criterion_group, criterion_main};
use restore::infer::run_tile;
use restore::tiles::{Planes, tiled};
use restore::{RestorerConfig, RestorerNet};
use std::time::Instant;

// The binary's allocator, so the numbers are what `metasplat restore` gets.
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

/// Peak resident set since the last reset (Linux; 0 elsewhere).
fn peak_rss_mb() -> f64 {
    let s = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    s.lines()
        .find(|l| l.starts_with("VmHWM:"))
        .and_then(|l| l.split_whitespace().nth(1)?.parse::<f64>().ok())
        .map_or(0.0, |kb| kb / 1024.0)
}

fn reset_peak_rss() {
    // "5" resets the peak RSS counter (Linux ≥ 4.0).
    let _ = std::fs::write("/proc/self/clear_refs", "5");
}

/// The stream the timings have always used.
fn random_planes(c: usize, h: usize, w: usize) -> Planes {
    restore::speed::planes(c, h, w, 0x1234_5678)
}

fn inference(c: &mut Criterion) {
    let device = Device::flex();
    let side = 256;
    let mut g = c.benchmark_group("restore");
    g.sample_size(10);
    for cfg in [
        RestorerConfig::tiny(),
        RestorerConfig::small(),
        RestorerConfig::paper(),
    ] {
        device.seed(0);
        let net = RestorerNet::new(&cfg, &device);
        let x = random_planes(39, side, side);
        reset_peak_rss();
        let base = peak_rss_mb();
        let _ = run_tile(&net, &x, &device);
        let peak = peak_rss_mb() - base;
        let t = Instant::now();
        let _ = run_tile(&net, &x, &device);
        let ms = t.elapsed().as_secs_f64() * 1e3;
        println!(
            "{:>5}: {} params, {side}x{side} forward {ms:.0} ms = {:.0} ms/MP, peak RSS +{peak:.0} MB",
            cfg.name,
            net.num_params(),
            ms / (side * side) as f64 * 1e6
        );
        g.bench_function(format!("{}_forward_{side}", cfg.name), |b| {
            b.iter(|| run_tile(&net, &x, &device))
        });
    }
    g.finish();
}

/// The network's global operations (channel attention, per-channel fusion gates) see only
/// the tile, so tiling is not exact: its error against whole-image inference is printed.
fn tiled_against_whole(c: &mut Criterion) {
    let device = Device::flex();
    device.seed(0);
    let cfg = RestorerConfig::tiny();
    let net = RestorerNet::new(&cfg, &device);
    let x = random_planes(39, 512, 512);
    let t = Instant::now();
    let whole = run_tile(&net, &x, &device);
    let t_whole = t.elapsed().as_secs_f64();
    for (tile, overlap) in [(256, 32), (256, 64), (128, 32)] {
        reset_peak_rss();
        let base = peak_rss_mb();
        let t = Instant::now();
        let y = tiled(&x, tile, overlap, |p| {
            Ok::<_, ()>(run_tile(&net, p, &device))
        })
        .unwrap();
        let secs = t.elapsed().as_secs_f64();
        let (mut max, mut sum) = (0.0f32, 0.0f64);
        for (a, b) in y.data.iter().zip(&whole.data) {
            max = max.max((a - b).abs());
            sum += (a - b).abs() as f64;
        }
        println!(
            "tiny 512x512: tiles {tile}/{overlap}: {secs:.2} s vs whole {t_whole:.2} s; |tiled - whole| max {max:.2e} mean {:.2e}; peak RSS +{:.0} MB",
            sum / y.data.len() as f64,
            peak_rss_mb() - base
        );
    }
    let mut g = c.benchmark_group("restore");
    g.sample_size(10);
    g.bench_function("tiny_tiled_512", |b| {
        b.iter(|| tiled(&x, 256, 32, |p| Ok::<_, ()>(run_tile(&net, p, &device))).unwrap())
    });
    g.finish();
}

fn training(c: &mut Criterion) {
    let device = Device::flex().autodiff();
    device.seed(0);
    let mut g = c.benchmark_group("restore");
    g.sample_size(10);
    for (cfg, batch) in [(RestorerConfig::tiny(), 4), (RestorerConfig::small(), 2)] {
        let s = cfg.crop;
        let mut net = RestorerNet::new(&cfg, &device);
        let mut optim = AdamWConfig::new().init();
        let x = Tensor::<4>::random([batch, 39, s, s], Distribution::Default, &device);
        let y = Tensor::<4>::from_data(
            TensorData::new(vec![0.5f32; batch * 3 * s * s], [batch, 3, s, s]),
            &device,
        );
        reset_peak_rss();
        let base = peak_rss_mb();
        let t = Instant::now();
        let steps = 3;
        for _ in 0..steps {
            let loss = (net.forward(x.clone()) - y.clone()).abs().mean();
            let grads = GradientsParams::from_grads(loss.backward(), &net);
            net = optim.step(3e-4, net, grads);
        }
        let per = t.elapsed().as_secs_f64() / steps as f64;
        println!(
            "{:>5}: training step (batch {batch}, {s}x{s} crops) {per:.2} s = {:.2} steps/s, peak RSS +{:.0} MB",
            cfg.name,
            1.0 / per,
            peak_rss_mb() - base
        );
        g.bench_function(format!("{}_train_step", cfg.name), |b| {
            b.iter(|| {
                let loss = (net.forward(x.clone()) - y.clone()).abs().mean();
                GradientsParams::from_grads(loss.backward(), &net)
            })
        });
    }
    g.finish();
}

criterion_group!(benches, inference, tiled_against_whole, training);
criterion_main!(benches);
