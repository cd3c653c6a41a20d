use super::*;
use crate::cpu::stages::local_box;

/// The intrinsics builds this CPU runs, with a note of those it cannot.
fn simd_builds() -> Vec<Isa> {
    let v: Vec<Isa> = Isa::available()
        .into_iter()
        .filter(|&i| i != Isa::Portable)
        .collect();
    if v.len() < 2 {
        eprintln!("SKIP (in part): this CPU runs only {v:?} of the intrinsics builds");
    }
    v
}

/// Every tile of a random scene through each intrinsics build and the portable loop.
#[test]
fn simd_and_portable_kernels_give_the_same_bits() {
    let g = crate::synthetic::random_box_scene(5, 20_000, 1);
    let cam = crate::synthetic::benchmark_camera().resized(252, 189);
    let pos = cam.position();
    let projected: Vec<_> = (0..g.len())
        .map(|i| {
            crate::reference::scalar_project::project_one(&g, i, &cam, 1, false, pos)
                .unwrap_or_default()
        })
        .collect();
    let bins = crate::cpu::tiles::bin(&projected, cam.width, cam.height);
    let splats: Vec<Splat> = projected.iter().map(Splat::new).collect();
    let mut checked = 0;
    for t in 0..bins.num_tiles() {
        let list = crate::cpu::stages::gather(&bins, &splats, t);
        let tile = crate::cpu::stages::tile_pixels(&bins, t, cam.width, cam.height);
        let run = |isa| {
            let mut st = TileState {
                tr: [1.0; TILE_PX],
                c: [[0.0; TILE_PX]; 3],
                depth: [0.0; TILE_PX],
                last: [0; TILE_PX],
                done: [0; TILE_PX],
            };
            let mut blocks = vec![0; list.len()];
            let n = forward_tile_dispatch(&list, tile, &mut st, isa, &mut blocks);
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            (
                n,
                bits(&st.tr),
                bits(&st.c[0]),
                bits(&st.c[2]),
                bits(&st.depth),
                st.last,
                blocks,
            )
        };
        let want = run(Isa::Portable);
        for isa in simd_builds() {
            assert!(run(isa) == want, "tile {t}, {isa:?}");
        }
        checked += list.len();
    }
    assert!(checked > 10_000, "the scene barely touches the image");
}

/// The backward of every tile of a random scene, with made-up pixel gradients, through
/// each intrinsics build and the portable loop.
#[test]
fn simd_and_portable_backward_give_the_same_bits() {
    let g = crate::synthetic::random_box_scene(6, 20_000, 1);
    let cam = crate::synthetic::benchmark_camera().resized(252, 189);
    let settings = crate::RenderSettings {
        sh_degree: 1,
        ..Default::default()
    };
    let (out, _) = crate::render_for_backward(&g, &cam, &settings).unwrap();
    let pos = cam.position();
    let projected: Vec<_> = (0..g.len())
        .map(|i| {
            crate::reference::scalar_project::project_one(&g, i, &cam, 1, false, pos)
                .unwrap_or_default()
        })
        .collect();
    let bins = crate::cpu::tiles::bin(&projected, cam.width, cam.height);
    let splats: Vec<Splat> = projected.iter().map(Splat::new).collect();
    let (mut compared, mut skipped) = (0, 0);
    for t in 0..bins.num_tiles() {
        let list = crate::cpu::stages::gather(&bins, &splats, t);
        let tile = crate::cpu::stages::tile_pixels(&bins, t, cam.width, cam.height);
        let mut fwd = TileState {
            tr: [1.0; TILE_PX],
            c: [[0.0; TILE_PX]; 3],
            depth: [0.0; TILE_PX],
            last: [0; TILE_PX],
            done: [0; TILE_PX],
        };
        let mut blocks = vec![0; list.len()];
        forward_tile_dispatch(&list, tile, &mut fwd, Isa::Portable, &mut blocks);
        let start = BackState {
            tr: fwd.tr,
            last: fwd.last,
            v_c: std::array::from_fn(|c| {
                std::array::from_fn(|i| ((i * 7 + c) % 13) as f32 * 0.01 - 0.06)
            }),
            v_dsum: std::array::from_fn(|i| (i % 5) as f32 * 0.003),
            v_final: std::array::from_fn(|i| (i % 3) as f32 * -0.002),
            behind: [[0.0; TILE_PX]; 3],
            behind_z: [0.0; TILE_PX],
        };
        let kmax = fwd.last.iter().copied().max().unwrap_or(0);
        // `all`: every block of each box, as without the forward's block sets.
        let run = |isa, all: bool| {
            let mut st = Box::new(start.clone());
            let sums: Vec<[u32; SUMS]> = (0..kmax)
                .rev()
                .map(|k| {
                    let set = if all { u32::MAX } else { blocks[k as usize] };
                    backward_splat_with(&list[k as usize], k, tile, &mut st, isa, set)
                        .map(f32::to_bits)
                })
                .collect();
            (
                sums,
                st.tr.map(f32::to_bits),
                st.behind[1].map(f32::to_bits),
            )
        };
        let want = run(Isa::Portable, true);
        // Visiting only the blocks where the forward blended changes no bit.
        assert!(run(Isa::Portable, false) == want, "tile {t}: block sets");
        for isa in simd_builds() {
            assert!(run(isa, false) == want, "tile {t}, {isa:?}");
            assert!(run(isa, true) == want, "tile {t}, {isa:?}, every block");
        }
        compared += kmax;
        skipped += blocks
            .iter()
            .zip(&list)
            .filter_map(|(&b, sp)| {
                let full = box_blocks(local_box(sp, tile.0, tile.1, tile.2, tile.3)?);
                Some((full & !b).count_ones() as usize)
            })
            .sum::<usize>();
    }
    assert!(
        compared > 5_000 && out.num_blended > 0,
        "too little was compared"
    );
    // The block sets do leave blocks out (this scene has box corners outside ellipses).
    assert!(skipped > 1_000, "only {skipped} blocks left out");
}

/// The block set of every box in a tile against the blocks its rows and columns touch.
#[test]
fn box_blocks_are_the_blocks_a_box_touches() {
    for ly0 in 0..STRIDE {
        for ly1 in ly0..STRIDE {
            for lx0 in 0..STRIDE {
                for lx1 in lx0..STRIDE {
                    let mut want = 0u32;
                    for ly in ly0..=ly1 {
                        for lx in lx0..=lx1 {
                            want |= block_bit(ly, lx / LANES * LANES);
                        }
                    }
                    assert_eq!(box_blocks([lx0, lx1, ly0, ly1]), want);
                }
            }
        }
    }
}
