//! Forward and forward+backward at 504×378 with 10k / 100k / 300k Gaussians (SH degree 3),
//! on 1 and 2 rayon threads, and PLY write/read of a 300k-Gaussian SH degree 3 file.
//!
//! Also prints, outside criterion's timing loops, the work counts the README's FLOP floor is
//! built on and the peak heap of one call of each kind, measured with the counting global
//! allocator below (`memory …` lines on stderr).

use std::hint::black_box;

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use glam::Vec3;
use splat::formats::ply::{read_ply, write_ply};
use splat::synthetic::{benchmark_camera, random_box_scene};
use splat::{Gaussians, RenderSettings, render, render_backward, render_for_backward};

/// Global allocator that forwards to the system allocator and keeps the live heap bytes and
/// their high-water mark in atomics.
mod heap {
    use std::alloc::{GlobalAlloc, Layout, System};
    use std::sync::atomic::{AtomicUsize, Ordering::Relaxed};

    pub struct Counting;

    static CURRENT: AtomicUsize = AtomicUsize::new(0);
    static PEAK: AtomicUsize = AtomicUsize::new(0);

    fn grow(n: usize) {
        let now = CURRENT.fetch_add(n, Relaxed) + n;
        // Plain load first: the read-modify-write only happens when a new peak is set.
        if now > PEAK.load(Relaxed) {
            PEAK.fetch_max(now, Relaxed);
        }
    }

    fn shrink(n: usize) {
        CURRENT.fetch_sub(n, Relaxed);
    }

    // SAFETY: every call forwards to `System` with the caller's arguments unchanged; the
    // counters only observe sizes.
    unsafe impl GlobalAlloc for Counting {
        unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
            let p = unsafe { System.alloc(layout) };
            if !p.is_null() {
                grow(layout.size());
            }
            p
        }

        unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
            let p = unsafe { System.alloc_zeroed(layout) };
            if !p.is_null() {
                grow(layout.size());
            }
            p
        }

        unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
            unsafe { System.dealloc(ptr, layout) };
            shrink(layout.size());
        }

        unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
            let p = unsafe { System.realloc(ptr, layout, new_size) };
            if !p.is_null() {
                if new_size >= layout.size() {
                    grow(new_size - layout.size());
                } else {
                    shrink(layout.size() - new_size);
                }
            }
            p
        }
    }

    /// Runs `f` and returns its result with the peak heap bytes allocated during the call on
    /// top of what was live before it (the result itself counts, as it is alive at the end).
    pub fn peak_during<R>(f: impl FnOnce() -> R) -> (R, usize) {
        let base = CURRENT.load(Relaxed);
        PEAK.store(base, Relaxed);
        let r = f();
        (r, PEAK.load(Relaxed).saturating_sub(base))
    }
}

#[global_allocator]
static GLOBAL: heap::Counting = heap::Counting;

/// FLOP model (elementary operations, `exp` counted as one): see the README.
const FWD_PER_GAUSSIAN: f64 = 400.0;
const FWD_PER_BLEND: f64 = 24.0;
const BWD_PER_GAUSSIAN: f64 = 1000.0;
const BWD_PER_BLEND: f64 = 60.0;

/// Heap bytes of the parameters of `g` (what a model costs before any rendering).
fn model_bytes(g: &Gaussians) -> usize {
    use std::mem::size_of_val;
    size_of_val(g.means.as_slice())
        + size_of_val(g.log_scales.as_slice())
        + size_of_val(g.rotations.as_slice())
        + size_of_val(g.logit_opacities.as_slice())
        + size_of_val(g.sh_dc.as_slice())
        + size_of_val(g.sh_rest.as_slice())
}

fn mb(bytes: usize) -> f64 {
    bytes as f64 / 1e6
}

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
        let blended = out.num_blended as f64;
        let fwd = visible * FWD_PER_GAUSSIAN + blended * FWD_PER_BLEND;
        let bwd = visible * BWD_PER_GAUSSIAN + blended * BWD_PER_BLEND;
        eprintln!(
            "n={n}: visible={visible} tile_intersections={} blended_pairs={blended} \
             forward_flops={:.3e} forward_backward_flops={:.3e}",
            out.num_intersections,
            fwd,
            fwd + bwd
        );
        drop(out);
        for threads in [1usize, 2] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            let forward = || pool.install(|| render(black_box(&g), &cam, &settings).unwrap());
            let forward_backward = || {
                pool.install(|| {
                    let (out, saved) = render_for_backward(black_box(&g), &cam, &settings).unwrap();
                    let grads = render_backward(&g, &saved, &v_color, None, None).unwrap();
                    (out, grads)
                })
            };
            // Peak heap of one call, measured on a second call so one-off lazy allocations
            // (rayon's worker registry) are not counted.
            drop(forward());
            let (_, fwd_peak) = heap::peak_during(forward);
            drop(forward_backward());
            let (_, fb_peak) = heap::peak_during(forward_backward);
            eprintln!(
                "memory n={n} threads={threads}: model={:.1} MB, peak heap above the model: \
                 forward={:.1} MB forward_backward={:.1} MB",
                mb(model_bytes(&g)),
                mb(fwd_peak),
                mb(fb_peak)
            );

            let id = format!("{n}/{threads}t");
            group.bench_function(BenchmarkId::new("forward", &id), |b| b.iter(forward));
            group.bench_function(BenchmarkId::new("forward_backward", &id), |b| {
                b.iter(forward_backward)
            });
        }
    }
    group.finish();
}

/// On-CPU nanoseconds of the calling thread (Linux `schedstat`; 0 elsewhere).
fn thread_cpu_ns() -> u64 {
    std::fs::read_to_string("/proc/thread-self/schedstat")
        .ok()
        .and_then(|s| s.split_whitespace().next()?.parse().ok())
        .unwrap_or(0)
}

/// Write (temp file + fsync + rename) and read of a 300k-Gaussian SH degree 3 INRIA file
/// (62 float32 properties, 74 MB) on the target directory's disk.
fn bench_ply(c: &mut Criterion) {
    let n = 300_000;
    let g = random_box_scene(1, n, 3);
    let dir = tempfile::tempdir_in(env!("CARGO_TARGET_TMPDIR")).unwrap();
    let path = dir.path().join("scene_300k_sh3.ply");
    let ((), write_peak) = heap::peak_during(|| write_ply(&path, &g).unwrap());
    let file_bytes = std::fs::metadata(&path).unwrap().len() as usize;
    let (back, read_peak) = heap::peak_during(|| read_ply(&path).unwrap());
    assert!(back == g, "PLY round trip changed the model");
    eprintln!(
        "memory ply n={n}: file={:.1} MB model={:.1} MB, peak heap: write={:.1} MB \
         read={:.1} MB (read includes the returned model)",
        mb(file_bytes),
        mb(model_bytes(&g)),
        mb(write_peak),
        mb(read_peak)
    );
    drop(back);
    // Load-insensitive companion to criterion's wall times: the best of 5 calls, wall and
    // on-CPU time of this thread (the write's fsync wait is wall time only).
    let best = |f: &mut dyn FnMut()| {
        let (mut wall, mut cpu) = (f64::INFINITY, f64::INFINITY);
        for _ in 0..5 {
            let (t, c) = (std::time::Instant::now(), thread_cpu_ns());
            f();
            wall = wall.min(t.elapsed().as_secs_f64() * 1e3);
            cpu = cpu.min((thread_cpu_ns() - c) as f64 / 1e6);
        }
        (wall, cpu)
    };
    let (ww, wc) = best(&mut || write_ply(&path, &g).unwrap());
    let (rw, rc) = best(&mut || drop(read_ply(&path).unwrap()));
    eprintln!(
        "time ply n={n} (best of 5): write {ww:.0} ms wall / {wc:.0} ms cpu, \
         read {rw:.0} ms wall / {rc:.0} ms cpu"
    );

    let mut group = c.benchmark_group("ply");
    group.sample_size(10);
    group.warm_up_time(std::time::Duration::from_millis(500));
    group.measurement_time(std::time::Duration::from_secs(5));
    group.bench_function("write_300k_sh3", |b| {
        b.iter(|| write_ply(&path, black_box(&g)).unwrap())
    });
    group.bench_function("read_300k_sh3", |b| {
        b.iter(|| read_ply(black_box(&path)).unwrap())
    });
    group.finish();
}

criterion_group!(benches, bench, bench_ply);
criterion_main!(benches);
