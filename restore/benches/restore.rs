//! Restorer memory and tiling: peak resident memory of a forward pass and of a training step
//! per config, and tiled against whole-image inference (time and error). Forward and step
//! times are `metasplat bench restorer`'s (restore::speed), not repeated here; the window
//! attention kernel alone is timed here (inference, and training's forward and backward), to
//! compare builds of it, and the dense 3×3 kernel beside burn's convolution it replaced.
//!
//! `cargo bench -p restore --bench restore` (`-- tiny` for the tiny config only,
//! `-- window_attention`, `-- window_train` or `-- dense3` for a kernel's timing; the memory
//! and tiling figures print on every run, whatever the filter).

use burn::module::Module;
use burn::tensor::Device;
use criterion::{Criterion, criterion_group, criterion_main};
use restore::infer::run_tile;
use restore::net::kernels::Kernels;
use restore::speed::{Workload, time_workload};
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

/// Peak resident memory of one forward pass per config (times: `metasplat bench restorer`).
fn inference_memory(_: &mut Criterion) {
    let device = Device::flex();
    let side = 256;
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
        println!(
            "{:>5}: {} params, {side}x{side} forward: peak RSS +{:.0} MB",
            cfg.name,
            net.num_params(),
            peak_rss_mb() - base
        );
    }
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

/// Peak resident memory of the training step `restorer train` takes (restore::speed's, so
/// the bench and the binary measure one step), beside the estimate it refuses batches with.
fn training_memory(_: &mut Criterion) {
    for (cfg, batch) in [(RestorerConfig::tiny(), 4), (RestorerConfig::small(), 2)] {
        let workload = Workload::TrainStep {
            batch,
            side: cfg.crop,
        };
        reset_peak_rss();
        let base = peak_rss_mb();
        time_workload(&cfg, workload, Kernels::Fast, 2, 1, 0, &Device::flex()).unwrap();
        println!(
            "{:>5}: {}: peak RSS +{:.0} MB (estimate {:.0} MB)",
            cfg.name,
            workload.describe(),
            peak_rss_mb() - base,
            cfg.training_bytes(batch, cfg.crop) as f64 / (1 << 20) as f64
        );
    }
}

/// A `tiny` full-resolution layer's attention inputs at `side`² (16 channels, two heads of 8,
/// 4² windows with 6² keys, the position terms on): maps `q, k, v` and an output gradient
/// from one stream, scaled apart (the timing does not depend on the values), and the
/// position embeddings and logits.
struct WindowInputs {
    maps: [Vec<f32>; 4],
    pos: [Vec<f32>; 3],
    dims: [usize; 3],
}

const HEADS: usize = 2;
const WIN: usize = 4;
const KWIN: usize = 6;

impl WindowInputs {
    fn new(side: usize) -> Self {
        let ch = 16;
        let map = |scale| {
            random_planes(ch, side, side)
                .data
                .iter()
                .map(|v| v * scale)
                .collect::<Vec<f32>>()
        };
        let small = |n: usize| {
            (0..n)
                .map(|i| ((i % 13) as f32 - 6.0) * 0.01)
                .collect::<Vec<f32>>()
        };
        WindowInputs {
            maps: [map(0.5), map(0.7), map(1.0), map(0.3)],
            pos: [
                small(WIN * WIN * ch),
                small(KWIN * KWIN * ch),
                small(HEADS * WIN.pow(2) * KWIN.pow(2)),
            ],
            dims: [ch, side, side],
        }
    }

    fn spec(&self) -> restore::net::window_direct::WindowSpec<'_> {
        restore::net::window_direct::WindowSpec {
            heads: HEADS,
            win: WIN,
            kwin: KWIN,
            share: 1,
            pos_q: Some(&self.pos[0]),
            pos_k: Some(&self.pos[1]),
            bias: Some(&self.pos[2]),
        }
    }
}

/// The window attention kernel on one 512² map, as `metasplat restore` runs it.
fn window_attention(c: &mut Criterion) {
    use restore::net::window_direct::attend_maps;
    let x = WindowInputs::new(512);
    let (spec, [q, k, v, _]) = (x.spec(), &x.maps);
    let mut g = c.benchmark_group("kernels");
    g.sample_size(20);
    g.bench_function("window_attention_512", |b| {
        b.iter(|| attend_maps(q, k, v, x.dims, &spec).unwrap())
    });
    g.finish();
}

/// The window attention's training pass at a `tiny` step's size (a 128² map: four 64² crops'
/// pixels): the forward that keeps its softmax rows, and the backward from them.
fn window_attention_train(c: &mut Criterion) {
    use restore::net::window_direct::attend_maps_keeping;
    use restore::net::window_train::attend_backward;
    let x = WindowInputs::new(128);
    let (spec, [q, k, v, dout], dims) = (x.spec(), &x.maps, x.dims);
    let mut g = c.benchmark_group("kernels");
    g.sample_size(20);
    g.bench_function("window_train_128/forward", |b| {
        b.iter(|| attend_maps_keeping(q, k, v, dims, &spec).unwrap())
    });
    let (_, kept) = attend_maps_keeping(q, k, v, dims, &spec).unwrap();
    g.bench_function("window_train_128/backward", |b| {
        b.iter(|| attend_backward(q, k, v, dout, dims, &spec, Some(&kept)))
    });
    g.finish();
}

/// The dense 3×3 convolution of `tiny`'s full-resolution layers (the down-sampling's 16 → 8
/// and the output's 32 → 3) at 512²: the direct kernel beside burn's CPU convolution (im2col
/// and a matrix product), which it replaced, on the same values.
fn dense3(c: &mut Criterion) {
    use burn::tensor::module::conv2d;
    use burn::tensor::ops::ConvOptions;
    use burn::tensor::{Tensor, TensorData};
    use restore::net::dense_direct::dense3;
    let side = 512;
    let mut g = c.benchmark_group("kernels");
    g.sample_size(10);
    for (cin, cout) in [(16, 8), (32, 3)] {
        let x = random_planes(cin, side, side).data;
        let weight: Vec<f32> = (0..cout * cin * 9)
            .map(|i| ((i % 17) as f32 - 8.0) * 0.01)
            .collect();
        let d = [1, cin, side, side];
        g.bench_function(format!("dense3_512_{cin}to{cout}/direct"), |b| {
            b.iter(|| dense3(&x, &weight, cout, d))
        });
        let device = Device::flex();
        let xt = Tensor::<4>::from_data(TensorData::new(x.clone(), d), &device);
        let wt =
            Tensor::<4>::from_data(TensorData::new(weight.clone(), [cout, cin, 3, 3]), &device);
        let options = ConvOptions::new([1, 1], [1, 1], [1, 1], 1);
        g.bench_function(format!("dense3_512_{cin}to{cout}/burn"), |b| {
            b.iter(|| conv2d(xt.clone(), wt.clone(), None, options.clone()).into_data())
        });
    }
    g.finish();
}

criterion_group!(
    benches,
    window_attention,
    window_attention_train,
    dense3,
    inference_memory,
    tiled_against_whole,
    training_memory
);
criterion_main!(benches);
