//! The CPU and GPU paths side by side in one process, for sizes too large for criterion's ten
//! samples on a software adapter (1M splats on lavapipe takes seconds per call) and as the
//! one script to run on a real GPU: forward, and a whole training step (forward, backward,
//! Adam; on the GPU the resident step), median wall milliseconds of `repeats` calls after one
//! warm-up, with the GPU image's largest difference from the CPU image.
//! `cargo run --release -p splat --example gpu_step -- [splats] [scale] [repeats] [export-dir]`
//! (scale 1: 504×378, 2: 1008×756). With an export folder it also writes the scene
//! (`scene.ply`), the camera (`camera.json`), the CPU image (`cpu_rgb.f32`, row-major RGB) and
//! these timings (`ours.json`), for `benches/gsplat/side_by_side.py` to render the same view.

use std::time::Instant;

use glam::Vec3;
use splat::gpu::{GpuRasterizer, GpuTraining};
use splat::optim::{Adam, LearningRates};
use splat::synthetic::{benchmark_camera, random_box_scene};
use splat::{CpuRasterizer, PixelGradients, Rasterizer, RenderSettings};

/// Median wall milliseconds of `repeats` calls of `f`, after one call not timed.
fn median_ms(repeats: usize, mut f: impl FnMut()) -> f64 {
    f();
    let mut t: Vec<f64> = (0..repeats)
        .map(|_| {
            let start = Instant::now();
            f();
            start.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    t.sort_by(f64::total_cmp);
    t[t.len() / 2]
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let n: usize = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(100_000);
    let scale: u32 = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(1).max(1);
    let repeats: usize = args.get(3).and_then(|s| s.parse().ok()).unwrap_or(3).max(1);
    let gpu = match GpuRasterizer::new() {
        Ok(g) => g,
        Err(e) => {
            eprintln!("no GPU: {e}");
            std::process::exit(1);
        }
    };
    let g = random_box_scene(0, n, 3);
    let cam = benchmark_camera().resized(504 * scale, 378 * scale);
    let settings = RenderSettings {
        sh_degree: 3,
        ..Default::default()
    };
    let v = vec![Vec3::splat(1e-3); cam.num_pixels()];
    let lr = LearningRates::default();
    let cpu = CpuRasterizer;

    let cs = cpu.upload(&g).unwrap();
    let want = cpu.render(&cs, &cam, &settings).unwrap();
    let cpu_fwd = median_ms(repeats, || {
        cpu.render(&cs, &cam, &settings).unwrap();
    });
    let cpu_fb = median_ms(repeats, || {
        let (_, s) = cpu.render_for_backward(&cs, &cam, &settings).unwrap();
        cpu.backward(&cs, &s, PixelGradients::color(&v)).unwrap();
    });
    let (mut model, mut adam) = (g.clone(), Adam::new(&g));
    let cpu_step = median_ms(repeats, || {
        let cs = cpu.upload(&model).unwrap();
        let (_, s) = cpu.render_for_backward(&cs, &cam, &settings).unwrap();
        let grads = cpu.backward(&cs, &s, PixelGradients::color(&v)).unwrap();
        adam.step(&mut model, &grads.params, &lr).unwrap();
    });
    let head = format!(
        "{}x{} {n} splats, CPU {} threads, GPU {}: forward CPU {cpu_fwd:.1} ms",
        cam.width,
        cam.height,
        rayon::current_num_threads(),
        gpu.context().describe(),
    );
    // A scene larger than the device binds in one buffer is refused with an error: say so.
    let gs = match gpu.upload(&g) {
        Ok(gs) => gs,
        Err(e) => {
            println!(
                "{head}; forward+backward CPU {cpu_fb:.1} ms; training step CPU {cpu_step:.1} ms; {e}"
            );
            return;
        }
    };
    let got = gpu.render(&gs, &cam, &settings).unwrap();
    let err = want
        .color
        .iter()
        .zip(&got.color)
        .map(|(a, b)| (*a - *b).abs().max_element())
        .fold(0.0f32, f32::max);
    let gpu_fwd = median_ms(repeats, || {
        gpu.render(&gs, &cam, &settings).unwrap();
    });
    // Through the interface, as the criterion bench measures it: the gradients come back to
    // the host (the resident step below keeps them on the GPU).
    let gpu_fb = median_ms(repeats, || {
        let (_, s) = gpu.render_for_backward(&gs, &cam, &settings).unwrap();
        gpu.backward(&gs, &s, PixelGradients::color(&v)).unwrap();
    });
    drop(gs);
    let mut t = GpuTraining::new(&gpu, &g, &Adam::new(&g)).unwrap();
    let gpu_step = median_ms(repeats, || {
        let (_, s) = t.render_for_backward(&cam, &settings).unwrap();
        t.step(
            &s,
            PixelGradients::color(&v),
            &lr,
            splat::Regularisers::default(),
        )
        .unwrap();
    });
    if let Some(dir) = args.get(4) {
        export(
            std::path::Path::new(dir),
            &g,
            &cam,
            &want.color,
            [cpu_fwd, gpu_fwd, cpu_fb, gpu_fb, cpu_step, gpu_step],
        )
        .expect("writing the export folder");
    }
    println!(
        "{head}, GPU {gpu_fwd:.1} ms; forward+backward CPU {cpu_fb:.1} ms, GPU {gpu_fb:.1} ms; \
         training step CPU {cpu_step:.1} ms, GPU {gpu_step:.1} ms; max |GPU - CPU| colour {err:e}"
    );
}

fn export(
    dir: &std::path::Path,
    g: &splat::Gaussians,
    cam: &splat::Camera,
    rgb: &[Vec3],
    [cpu_fwd, gpu_fwd, cpu_fb, gpu_fb, cpu_step, gpu_step]: [f64; 6],
) -> std::io::Result<()> {
    std::fs::create_dir_all(dir)?;
    // Written as every output of the project is: a temporary beside the file, renamed on success.
    let write = |name: &str, bytes: &[u8]| {
        base::write_atomically(&dir.join(name), |w| std::io::Write::write_all(w, bytes))
    };
    splat::formats::ply::write_ply(dir.join("scene.ply"), g).map_err(std::io::Error::other)?;
    let r = cam.rotation;
    let t = cam.translation;
    // Row-major world-to-camera matrix.
    let view = [
        [r.x_axis.x, r.y_axis.x, r.z_axis.x, t.x],
        [r.x_axis.y, r.y_axis.y, r.z_axis.y, t.y],
        [r.x_axis.z, r.y_axis.z, r.z_axis.z, t.z],
        [0.0, 0.0, 0.0, 1.0],
    ];
    write(
        "camera.json",
        format!(
            "{{\"width\": {}, \"height\": {}, \"fx\": {}, \"fy\": {}, \"cx\": {}, \"cy\": {}, \"near\": {}, \"far\": {}, \"world_to_camera\": {:?}}}\n",
            cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy, cam.near, cam.far, view
        )
        .as_bytes(),
    )?;
    let bytes: Vec<u8> = rgb
        .iter()
        .flat_map(|c| c.to_array())
        .flat_map(f32::to_le_bytes)
        .collect();
    write("cpu_rgb.f32", &bytes)?;
    write(
        "ours.json",
        format!(
            "{{\"splats\": {}, \"cpu_forward_ms\": {cpu_fwd}, \"gpu_forward_ms\": {gpu_fwd}, \"cpu_forward_backward_ms\": {cpu_fb}, \"gpu_forward_backward_ms\": {gpu_fb}, \"cpu_step_ms\": {cpu_step}, \"gpu_step_ms\": {gpu_step}}}\n",
            g.len()
        )
        .as_bytes(),
    )
}
