//! The CPU blending kernels: the rules of [`crate::reference::scalar_blend`], computed for
//! blocks of [`LANES`] pixels of a tile row at once.
//!
//! The scalar reference visits a tile's splats front to back and lets each update the pixels
//! of its box, one at a time, with branches. Here each splat updates the eight-pixel blocks of
//! the tile rows its box covers, every per-pixel decision of the rule (inside the box, `σ` in
//! range, `α ≥ 1/255`, transmittance stop) becomes a lane mask, and the tile's state is kept as
//! structure of arrays. Two builds of each kernel: intrinsics ([`intrinsics`], AVX2 and
//! AVX-512VL, chosen at run time by [`base::isa`]; `METASPLAT_NO_AVX2` turns them off) and
//! portable lane loops ([`portable`]) for every other CPU. The compiler does not vectorise the
//! loops (RESULTS.md has the attempt); they are the operation-for-operation twin of the
//! intrinsics, which the tests check bit for bit.
//!
//! Each pixel still sees its splats in list order with the same operations in the same order
//! as the scalar reference, so the kernels agree with it up to the exponential: they use
//! [`crate::cpu::exp::exp_neg`], a polynomial whose relative error against the exact `e^(−σ)`
//! is below [`crate::cpu::exp::EXP_REL_ERROR`] (tested), where the reference calls the C
//! library's `expf`. No lane mixes with another, and the portable loops fuse a multiply-add
//! (`mul_add`, exactly rounded everywhere) wherever the intrinsics do, so the builds give
//! identical bits. The backward sums each splat's per-lane contributions in lane vectors and
//! reduces them once per splat, in a fixed order: results do not depend on the thread count.

use std::mem::MaybeUninit;

use glam::Vec3;

use crate::cpu::lanes::LANES;
use crate::cpu::stages::{IsectGrad, PixelGrads, PixelOut, Splat, TileSink};

mod intrinsics;
mod portable;

use intrinsics::{avx2, avx512};
use portable::{backward_splat, forward_tile_lanes};

/// One lane vector of the portable builds.
type Lanes = [f32; LANES];

/// Tile state, structure of arrays, rows of [`STRIDE`] pixels (a tile row is two blocks).
const STRIDE: usize = crate::conventions::TILE_SIZE as usize;
const TILE_PX: usize = STRIDE * STRIDE;

/// Blends one tile (already gathered: `splats` is its list, front to back) and writes its
/// pixels into `sink`; returns the number of blended pairs. Splats are visited in order; each
/// blends the blocks of the tile rows its box covers. Same outputs as
/// [`crate::reference::scalar_blend::forward_tile`] up to the exponential. `blended_blocks[k]` (one per splat
/// of the list) gets the set of blocks in which splat `k` blended a pixel, bit
/// `row · 2 + column` (see [`block_bit`]): the blocks its backward has to visit.
///
/// # Safety
/// No other call writes the same tile into `sink` at the same time ([`TileSink::write_tile`]).
pub unsafe fn forward_tile(
    splats: &[Splat],
    (x0, y0, w, h): (u32, u32, u32, u32),
    background: Vec3,
    sink: &TileSink,
    blended_blocks: &mut [u32],
) -> u64 {
    let mut st = TileState {
        tr: [1.0; TILE_PX],
        c: [[0.0; TILE_PX]; 3],
        depth: [0.0; TILE_PX],
        last: [0; TILE_PX],
        done: [0; TILE_PX],
    };
    let blended = forward_tile_dispatch(
        splats,
        (x0, y0, w, h),
        &mut st,
        Isa::chosen(),
        blended_blocks,
    );
    // SAFETY: the caller's promise.
    unsafe {
        sink.write_tile((x0, y0, w, h), |lx, ly| {
            let i = ly * STRIDE + lx;
            let t = st.tr[i];
            let a = 1.0 - t;
            PixelOut {
                color: Vec3::new(st.c[0][i], st.c[1][i], st.c[2][i]) + background * t,
                alpha: a,
                depth: if a > 0.0 { st.depth[i] / a } else { 0.0 },
                final_t: t,
                n_contrib: st.last[i],
            }
        })
    };
    blended
}

struct TileState {
    tr: [f32; TILE_PX],
    c: [[f32; TILE_PX]; 3],
    depth: [f32; TILE_PX],
    last: [u32; TILE_PX],
    /// All bits set once the pixel's transmittance has stopped it (a lane mask).
    done: [i32; TILE_PX],
}

/// The builds of the kernels: the project's one choice ([`base::isa`]).
pub use base::isa::Isa;

/// Blends a tile with the kernels of `isa`, which must be [`Isa::available`].
fn forward_tile_dispatch(
    splats: &[Splat],
    tile: (u32, u32, u32, u32),
    st: &mut TileState,
    isa: Isa,
    blocks: &mut [u32],
) -> u64 {
    debug_assert!(Isa::available().contains(&isa));
    assert_eq!(blocks.len(), splats.len(), "one block set per splat");
    blocks.fill(0);
    match isa {
        // SAFETY: the CPU has the build's instruction set (its caller's promise).
        #[cfg(target_arch = "x86_64")]
        Isa::Avx2 => unsafe { avx2::forward_tile_lanes(splats, tile, st, blocks) },
        #[cfg(target_arch = "x86_64")]
        Isa::Avx512 => unsafe { avx512::forward_tile_lanes(splats, tile, st, blocks) },
        _ => forward_tile_lanes(splats, tile, st, blocks),
    }
}

/// The bit of a tile's block set for the block of tile row `ly` starting at column `bx`.
#[inline(always)]
pub(crate) fn block_bit(ly: usize, bx: usize) -> u32 {
    1 << (ly * BLOCKS_PER_ROW + bx / LANES)
}

/// Blocks per tile row (a block set has one bit per block of the tile).
const BLOCKS_PER_ROW: usize = STRIDE / LANES;
const _: () = assert!(STRIDE * STRIDE / LANES <= 32);

/// The set of blocks covered by the box `[lx0, lx1] × [ly0, ly1]` (tile-local pixels).
#[inline]
fn box_blocks([lx0, lx1, ly0, ly1]: [usize; 4]) -> u32 {
    // The box's columns of blocks within one row, repeated for each of its rows: rows are
    // BLOCKS_PER_ROW bits apart, so the product of the row bits and the column bits has no
    // carries.
    let (c0, c1) = (lx0 / LANES, lx1 / LANES);
    let cols = (1u32 << (c1 + 1)) - (1u32 << c0);
    let rows: u32 = (ly0..=ly1).map(|ly| 1u32 << (ly * BLOCKS_PER_ROW)).sum();
    rows * cols
}

/// Per-splat gradient sums, in lanes while a splat is visited and reduced once when it is
/// done: mean2d (2), |mean2d| (2), conic (3), colour (3), opacity, depth.
const SUMS: usize = 12;
// The vector reduction takes the sums four at a time.
const _: () = assert!(SUMS.is_multiple_of(4));

/// What the backward keeps per pixel of a tile, structure of arrays (see
/// `scalar_blend::backward_tile` for what each is).
#[derive(Clone)]
struct BackState {
    tr: [f32; TILE_PX],
    last: [u32; TILE_PX],
    v_c: [[f32; TILE_PX]; 3],
    v_dsum: [f32; TILE_PX],
    v_final: [f32; TILE_PX],
    behind: [[f32; TILE_PX]; 3],
    behind_z: [f32; TILE_PX],
}

impl BackState {
    fn zeroed() -> Self {
        BackState {
            tr: [0.0; TILE_PX],
            last: [0; TILE_PX],
            v_c: [[0.0; TILE_PX]; 3],
            v_dsum: [0.0; TILE_PX],
            v_final: [0.0; TILE_PX],
            behind: [[0.0; TILE_PX]; 3],
            behind_z: [0.0; TILE_PX],
        }
    }
}

/// The backward's per-tile state, kept by a worker from one tile to the next.
pub struct BackScratch(Box<BackState>);

impl Default for BackScratch {
    fn default() -> Self {
        BackScratch(Box::new(BackState::zeroed()))
    }
}

/// Backward of [`forward_tile`] for one gathered tile: `out[k]` gets splat `k`'s gradient,
/// its lanes summed in a fixed order, and every slot of `out` is written (zero for splats
/// behind every pixel's last contributor). With `blended_blocks` (the forward's, one set per
/// splat) a splat visits only the blocks where it blended: in any other block every lane's
/// contribution is masked off, so the results are the same to the bit. Same results as [`crate::reference::scalar_blend::backward_tile`]
/// up to the exponential and the order of the sums.
#[allow(clippy::too_many_arguments)]
pub fn backward_tile(
    splats: &[Splat],
    tile: (u32, u32, u32, u32),
    image_width: u32,
    background: Vec3,
    pix: &PixelGrads,
    out: &mut [MaybeUninit<IsectGrad>],
    blended_blocks: Option<&[u32]>,
    scratch: &mut BackScratch,
) {
    let (x0, y0, w, h) = tile;
    // Every tile starts from zeros, edge tiles' unused lanes included, as from a fresh state.
    let st = &mut *scratch.0;
    *st = BackState::zeroed();
    let mut kmax = 0;
    let isa = Isa::chosen();
    for ly in 0..h as usize {
        for lx in 0..w as usize {
            let i = ly * STRIDE + lx;
            let idx = (y0 as usize + ly) * image_width as usize + x0 as usize + lx;
            let vc = pix.v_color[idx];
            st.tr[i] = pix.final_t[idx];
            st.last[i] = pix.n_contrib[idx];
            kmax = kmax.max(st.last[i] as usize);
            (st.v_c[0][i], st.v_c[1][i], st.v_c[2][i]) = (vc.x, vc.y, vc.z);
            (st.v_dsum[i], st.v_final[i]) = pix.depth_and_final(idx, background);
        }
    }
    let list = BackList {
        splats,
        blocks: blended_blocks,
        kmax,
    };
    match isa {
        // SAFETY: the CPU has the build's instruction set (`Isa::chosen` is available).
        #[cfg(target_arch = "x86_64")]
        Isa::Avx2 => unsafe { avx2::backward_list(&list, tile, st, out) },
        #[cfg(target_arch = "x86_64")]
        Isa::Avx512 => unsafe { avx512::backward_list(&list, tile, st, out) },
        _ => backward_list(&list, tile, st, out, backward_splat),
    }
}

/// A tile's list as the backward walks it: the splats, the forward's block sets (without
/// them every block of each box) and the end of the pixels' lists.
struct BackList<'a> {
    splats: &'a [Splat],
    blocks: Option<&'a [u32]>,
    kmax: usize,
}

/// The backward of a tile's list, back to front, one write per slot (the caller relies on
/// every slot being written), with `splat` as the per-splat kernel. Generic so that each
/// build compiles it around its own kernel, inlined.
#[inline(always)]
fn backward_list(
    list: &BackList,
    tile: (u32, u32, u32, u32),
    st: &mut BackState,
    out: &mut [MaybeUninit<IsectGrad>],
    mut splat: impl FnMut(&Splat, u32, (u32, u32, u32, u32), &mut BackState, u32) -> [f32; SUMS],
) {
    for (k, slot) in out.iter_mut().enumerate().rev() {
        let blocks = list.blocks.map_or(u32::MAX, |b| b[k]);
        let sums = if k < list.kmax && blocks != 0 {
            splat(&list.splats[k], k as u32, tile, st, blocks)
        } else {
            [0.0; SUMS]
        };
        slot.write(IsectGrad {
            mean2d: glam::Vec2::new(sums[0], sums[1]),
            mean2d_abs: glam::Vec2::new(sums[2], sums[3]),
            conic: [sums[4], sums[5], sums[6]],
            color: Vec3::new(sums[7], sums[8], sums[9]),
            opacity: sums[10],
            depth: sums[11],
        });
    }
}

/// [`backward_splat`] with the kernels of `isa`, which must be [`Isa::available`] (the same
/// bits with any): the tests' way to run one build's kernel.
#[cfg(test)]
fn backward_splat_with(
    s: &Splat,
    k: u32,
    tile: (u32, u32, u32, u32),
    st: &mut BackState,
    isa: Isa,
    blocks: u32,
) -> [f32; SUMS] {
    match isa {
        // SAFETY: the CPU has the build's instruction set (its caller's promise).
        #[cfg(target_arch = "x86_64")]
        Isa::Avx2 => unsafe { avx2::backward_splat(s, k, tile, st, blocks) },
        #[cfg(target_arch = "x86_64")]
        Isa::Avx512 => unsafe { avx512::backward_splat(s, k, tile, st, blocks) },
        _ => backward_splat(s, k, tile, st, blocks),
    }
}

#[cfg(test)]
mod tests;
