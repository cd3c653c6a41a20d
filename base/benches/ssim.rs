//! SSIM with its gradient at 504×378 and 1008×756: the fast separable path beside the direct
//! loops it must equal (bit for bit, see tests/metrics.rs), in one run; and the value alone.

use std::hint::black_box;

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use glam::Vec3;

fn image(seed: u64, n: usize) -> Vec<Vec3> {
    base::SplitMix64::new(seed).uniform_rgb(n)
}

fn bench(c: &mut Criterion) {
    let mut group = c.benchmark_group("ssim");
    group.sample_size(10);
    group.measurement_time(std::time::Duration::from_secs(3));
    for (w, h) in [(504u32, 378u32), (1008, 756)] {
        let n = (w * h) as usize;
        let (a, b) = (image(1, n), image(2, n));
        let id = format!("{w}x{h}");
        group.bench_function(BenchmarkId::new("direct_with_gradient", &id), |bch| {
            bch.iter(|| base::ssim_reference::ssim(black_box(&a), &b, w, h))
        });
        group.bench_function(BenchmarkId::new("fast_with_gradient", &id), |bch| {
            bch.iter(|| base::ssim(black_box(&a), &b, w, h).unwrap())
        });
        group.bench_function(BenchmarkId::new("fast_value", &id), |bch| {
            bch.iter(|| base::ssim_value(black_box(&a), &b, w, h).unwrap())
        });
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
