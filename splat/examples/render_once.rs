//! Renders a synthetic scene (optionally with the backward pass) and prints wall and CPU times
//! and work counts. Used for peak-memory measurement (`/usr/bin/time -v`) next to the
//! criterion benchmarks, and for load-insensitive CPU-time comparisons on a shared machine:
//! `cargo run --release -p splat --example render_once -- 100000 backward [repeats] [scalar]`
//! (`scalar`: the per-splat reference kernels instead of the vectorised pixel blocks), or
//! `-- scene.ply backward [repeats] [blocks|scalar] [focal]` for a PLY file seen from the same
//! camera pose.

use std::time::Instant;

// The allocator of the `metasplat` binary, so the page faults of fresh buffers are what the
// trainer sees.
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

use splat::BlendKernels;
use splat::cpu::render::render_for_backward_with;
use splat::synthetic::{benchmark_camera, random_box_scene};
use splat::{RenderSettings, render_backward};

/// On-CPU nanoseconds of all threads of this process (Linux `schedstat`); 0 elsewhere.
fn cpu_ns() -> u64 {
    let Ok(dir) = std::fs::read_dir("/proc/self/task") else {
        return 0;
    };
    dir.flatten()
        .filter_map(|e| std::fs::read_to_string(e.path().join("schedstat")).ok())
        .filter_map(|s| s.split_whitespace().next()?.parse::<u64>().ok())
        .sum()
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    // The scene: a count of synthetic splats, or a PLY file (rendered from the same camera
    // pose, with the focal length of the fifth argument if given).
    let ply = args.get(1).filter(|s| s.ends_with(".ply"));
    let n: usize = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(100_000);
    let backward = args.get(2).is_some_and(|s| s == "backward");
    let repeats: u32 = args.get(3).and_then(|s| s.parse().ok()).unwrap_or(1).max(1);
    let kernels = if args.get(4).is_some_and(|s| s == "scalar") {
        BlendKernels::Scalar
    } else {
        BlendKernels::Lanes
    };
    let (g, cam) = match ply {
        Some(path) => {
            let g = splat::formats::ply::read_ply(path).expect("PLY");
            let mut cam = benchmark_camera();
            if let Some(f) = args.get(5).and_then(|s| s.parse::<f32>().ok()) {
                (cam.fx, cam.fy) = (f, f);
            }
            (g, cam)
        }
        None => (random_box_scene(0, n, 3), benchmark_camera()),
    };
    let s = RenderSettings {
        sh_degree: g.sh_degree,
        ..Default::default()
    };
    let v = vec![glam::Vec3::splat(1e-3); cam.num_pixels()];
    let (mut fwd_wall, mut fwd_cpu, mut bwd_wall, mut bwd_cpu) = (0.0, 0.0, 0.0, 0.0);
    let mut checksum = 0.0;
    let mut out = None;
    // Per call CPU milliseconds, for medians that one slow call on a shared machine (or the
    // first call's page faults) does not move.
    let (mut fwd_calls, mut bwd_calls) = (Vec::new(), Vec::new());
    for _ in 0..repeats {
        let (t, c) = (Instant::now(), cpu_ns());
        let (o, saved) = render_for_backward_with(&g, &cam, &s, kernels).expect("render");
        fwd_wall += t.elapsed().as_secs_f64();
        fwd_cpu += (cpu_ns() - c) as f64 * 1e-9;
        fwd_calls.push((cpu_ns() - c) as f64 * 1e-6);
        if backward {
            let (t, c) = (Instant::now(), cpu_ns());
            let gr = render_backward(&g, &saved, &v, None, None).expect("backward");
            bwd_wall += t.elapsed().as_secs_f64();
            bwd_cpu += (cpu_ns() - c) as f64 * 1e-9;
            bwd_calls.push((cpu_ns() - c) as f64 * 1e-6);
            checksum = gr.params.logit_opacities.iter().sum::<f32>();
        }
        out = Some(o);
    }
    let out = out.unwrap();
    let r = repeats as f64 * 1e-3;
    println!(
        "n={n} visible={} tile_pairs={} blended_pairs={} forward: wall {:.1} ms cpu {:.1} ms",
        out.visible.iter().filter(|v| **v).count(),
        out.num_intersections,
        out.num_blended,
        fwd_wall / r,
        fwd_cpu / r
    );
    if backward {
        println!(
            "backward: wall {:.1} ms cpu {:.1} ms (checksum {checksum})",
            bwd_wall / r,
            bwd_cpu / r
        );
    }
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied().unwrap_or(0.0)
    };
    println!(
        "median cpu per call: forward {:.1} ms, backward {:.1} ms",
        median(&mut fwd_calls),
        median(&mut bwd_calls)
    );
}
