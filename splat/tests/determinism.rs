//! Same input, same bits, for any rayon thread count.

mod common;

use base::SplitMix64;
use common::{random_scene, test_camera};
use glam::Vec3;
use splat::{CpuRasterizer, PixelGradients, Rasterizer, RenderSettings};

fn run(threads: usize) -> Vec<u32> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    pool.install(|| {
        let cam = test_camera(70, 45, 60.0);
        let g = random_scene(42, 3000, 3, (0.01, 0.2), 1.5);
        let s = RenderSettings {
            sh_degree: 3,
            background: Vec3::new(0.5, 0.5, 0.5),
            antialiased: true,
        };
        let cpu = CpuRasterizer;
        let scene = cpu.upload(&g).unwrap();
        let (out, saved) = cpu.render_for_backward(&scene, &cam, &s).unwrap();
        let mut rng = SplitMix64::new(1);
        let v: Vec<Vec3> = rng.normal_rgb(cam.num_pixels());
        let pixel = PixelGradients {
            color: &v,
            alpha: Some(&out.alpha),
            depth: Some(&out.depth),
        };
        let gr = cpu.backward(&scene, &saved, pixel).unwrap();
        let mut bits = Vec::new();
        bits.extend(
            out.color
                .iter()
                .flat_map(|c| c.to_array())
                .map(f32::to_bits),
        );
        bits.extend(out.alpha.iter().chain(&out.depth).map(|v| v.to_bits()));
        let p = &gr.params;
        bits.extend(
            p.means
                .iter()
                .chain(&p.log_scales)
                .chain(&p.sh_dc)
                .chain(&p.sh_rest)
                .flat_map(|c| c.to_array())
                .map(f32::to_bits),
        );
        bits.extend(
            p.rotations
                .iter()
                .flatten()
                .chain(&p.logit_opacities)
                .map(|v| v.to_bits()),
        );
        bits.extend(
            gr.means2d
                .iter()
                .chain(&gr.means2d_abs)
                .flatten()
                .map(|v| v.to_bits()),
        );
        bits
    })
}

#[test]
fn bit_identical_across_thread_counts_and_runs() {
    let reference = run(1);
    assert!(reference.iter().any(|&b| b != 0));
    for threads in [1, 2, 3, 5] {
        assert!(run(threads) == reference, "{threads} threads differ");
    }
}
