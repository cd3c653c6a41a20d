//! The fast CPU blending kernels: [`crate::raster`]'s rules, computed for blocks of
//! [`LANES`] pixels of a tile row at once.
//!
//! `raster` visits a tile's splats front to back and lets each update the pixels of its box,
//! one at a time, with branches. Here each splat updates the eight-pixel blocks of the tile
//! rows its box covers, every per-pixel decision of the rule (inside the box, `σ` in range,
//! `α ≥ 1/255`, transmittance stop) becomes a lane mask, and the tile's state is kept as
//! structure of arrays. Two builds of each kernel: AVX2 intrinsics, chosen at run time when
//! the CPU has AVX2 and FMA (`METASPLAT_NO_AVX2` turns them off), and portable lane loops for every
//! other CPU. The compiler does not vectorise the loops (RESULTS.md has the attempt); they are
//! the operation-for-operation twin of the intrinsics, which the tests check bit for bit.
//!
//! Each pixel still sees its splats in list order with the same operations in the same order
//! as `raster`, so the kernels agree with it up to the exponential: they use [`exp_neg`], a
//! polynomial whose relative error against the exact `e^(−σ)` is below [`EXP_REL_ERROR`]
//! (tested), where `raster` calls the C library's `expf`. No lane mixes with another, and the
//! portable loops fuse a multiply-add (`mul_add`, exactly rounded everywhere) wherever the
//! intrinsics do, so the AVX2 and portable builds give identical bits. The backward
//! sums each splat's per-lane contributions in lane vectors and reduces them once per splat,
//! in a fixed order: results do not depend on the thread count.

use std::mem::MaybeUninit;

use glam::Vec3;

use crate::conventions::{ALPHA_THRESHOLD, MAX_ALPHA, TRANSMITTANCE_MIN};
use crate::raster::{IsectGrad, PixelGrads, PixelOut, Splat, TileSink, local_box};

/// Pixels per block: one AVX2 register of `f32`.
pub const LANES: usize = 8;
type Lanes = [f32; LANES];

/// Bound on the relative error of [`exp_neg`] for `σ` in `[0, 87]` (checked in the tests
/// against the float64 exponential).
pub const EXP_REL_ERROR: f64 = 3e-7;

/// `e^(−σ)` for `σ ≥ 0` (inputs are clamped to `[0, 87]`, where the result stays normal):
/// Cody–Waite range reduction to `r ∈ [−ln2/2, ln2/2]` and Cephes' degree-6 polynomial for
/// `e^r`, scaled by `2^n` through the exponent bits. Pure arithmetic, so it vectorises.
#[inline(always)]
pub fn exp_neg(sigma: f32) -> f32 {
    const LOG2E: f32 = std::f32::consts::LOG2_E;
    const LN2_HI: f32 = 0.693_359_4;
    const LN2_LO: f32 = -2.121_944_4e-4;
    // Adding and removing 1.5·2²³ rounds to the nearest integer without a rounding call.
    const ROUND: f32 = 12_582_912.0;
    let x = -sigma.clamp(0.0, 87.0);
    let n = x.mul_add(LOG2E, ROUND) - ROUND;
    let r = (-n).mul_add(LN2_HI, x);
    let r = (-n).mul_add(LN2_LO, r);
    let p: f32 = 1.987_569_1e-4;
    let p = p.mul_add(r, 1.398_199_9e-3);
    let p = p.mul_add(r, 8.333_452e-3);
    let p = p.mul_add(r, 4.166_579_6e-2);
    let p = p.mul_add(r, 1.666_666_5e-1);
    let p = p.mul_add(r, 0.5);
    let e = (p * r).mul_add(r, r) + 1.0;
    e * f32::from_bits(((n as i32 + 127) << 23) as u32)
}

/// Tile state, structure of arrays, rows of [`STRIDE`] pixels (a tile row is two blocks).
const STRIDE: usize = crate::conventions::TILE_SIZE as usize;
const TILE_PX: usize = STRIDE * STRIDE;

/// Blends one tile (already gathered: `splats` is its list, front to back) and writes its
/// pixels into `sink`; returns the number of blended pairs. Splats are visited in order; each
/// blends the blocks of the tile rows its box covers. Same outputs as
/// [`crate::raster::forward_tile`] up to the exponential. `blended_blocks[k]` (one per splat
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

/// The portable kernel: lane loops the AVX2 kernel mirrors operation for operation.
// The lane index addresses several arrays in lockstep, as the vector code does.
#[allow(clippy::needless_range_loop)]
fn forward_tile_lanes(
    splats: &[Splat],
    (x0, y0, w, h): (u32, u32, u32, u32),
    st: &mut TileState,
    blocks: &mut [u32],
) -> u64 {
    let mut blended = 0u64;
    let mut n_done = 0usize;
    let n = (w * h) as usize;
    let lane_x: Lanes = std::array::from_fn(|l| l as f32);
    for (k, s) in splats.iter().enumerate() {
        if n_done == n {
            break;
        }
        let Some(bounds) = local_box(s, x0, y0, w, h) else {
            continue;
        };
        let [lx0, lx1, ly0, ly1] = bounds.map(|v| v as i32);
        let (m, [ca, cb, cc], o, cut) = (s.mean(), s.conic(), s.opacity(), s.sigma_cut());
        let (col, z) = (s.color(), s.depth());
        let b0 = lx0 as usize / LANES * LANES;
        let mut set = 0u32;
        for ly in ly0 as usize..=ly1 as usize {
            let dy = m.y - ((y0 as usize + ly) as f32 + 0.5);
            let mut bx = b0;
            while bx <= lx1 as usize {
                let row = ly * STRIDE + bx;
                let dx0 = m.x - ((x0 as usize + bx) as f32 + 0.5);
                let mut count = 0u32;
                let mut stops = 0usize;
                for l in 0..LANES {
                    let i = row + l;
                    let lx = (bx + l) as i32;
                    let dx = dx0 - lane_x[l];
                    let sigma = 0.5f32.mul_add((ca * dx).mul_add(dx, cc * dy * dy), cb * dx * dy);
                    let alpha = MAX_ALPHA.min(o * exp_neg(sigma));
                    let live = st.done[i] == 0 && lx0 <= lx && lx <= lx1;
                    let ok = live && (0.0..=cut).contains(&sigma) && alpha >= ALPHA_THRESHOLD;
                    let tr = st.tr[i];
                    let next_t = tr * (1.0 - alpha);
                    let stop = ok && next_t <= TRANSMITTANCE_MIN;
                    let blend = ok && !stop;
                    let wgt = alpha * tr;
                    st.c[0][i] = if blend {
                        col.x.mul_add(wgt, st.c[0][i])
                    } else {
                        st.c[0][i]
                    };
                    st.c[1][i] = if blend {
                        col.y.mul_add(wgt, st.c[1][i])
                    } else {
                        st.c[1][i]
                    };
                    st.c[2][i] = if blend {
                        col.z.mul_add(wgt, st.c[2][i])
                    } else {
                        st.c[2][i]
                    };
                    st.depth[i] = if blend {
                        z.mul_add(wgt, st.depth[i])
                    } else {
                        st.depth[i]
                    };
                    st.tr[i] = if blend { next_t } else { tr };
                    st.last[i] = if blend { k as u32 + 1 } else { st.last[i] };
                    st.done[i] |= -(stop as i32);
                    count += blend as u32;
                    stops += stop as usize;
                }
                blended += count as u64;
                set |= if count > 0 { block_bit(ly, bx) } else { 0 };
                n_done += stops;
                bx += LANES;
            }
        }
        blocks[k] = set;
    }
    blended
}

/// A build of the intrinsics kernels for one instruction set: [`forward_tile_lanes`] and
/// [`backward_splat`] with the same operations in the same order on eight lanes at once (fused
/// multiply-adds exactly where the portable loop calls `mul_add`, so the bits equal the
/// portable loop's). The AVX-512 build is the same source: AVX-512VL gives the compiler 32
/// vector registers instead of 16, so the backward's twelve lane sums stay out of memory.
macro_rules! simd_kernels {
    ($module:ident, $features:literal) => {
        #[cfg(target_arch = "x86_64")]
        mod $module {
            use std::arch::x86_64::*;

            use std::mem::MaybeUninit;

            use crate::blocks::{
                BLOCKS_PER_ROW, BackList, BackState, LANES, STRIDE, SUMS, TILE_PX, TileState,
                block_bit, box_blocks,
            };
            use crate::conventions::{ALPHA_THRESHOLD, MAX_ALPHA, TRANSMITTANCE_MIN};
            use crate::raster::IsectGrad;
            use crate::raster::{Splat, local_box};

            /// [`crate::blocks::exp_neg`] on eight lanes.
            #[inline]
            #[target_feature(enable = $features)]
            fn exp_neg(sigma: __m256) -> __m256 {
                let x = _mm256_sub_ps(
                    _mm256_setzero_ps(),
                    _mm256_min_ps(
                        _mm256_max_ps(sigma, _mm256_setzero_ps()),
                        _mm256_set1_ps(87.0),
                    ),
                );
                let round = _mm256_set1_ps(12_582_912.0);
                let n = _mm256_sub_ps(
                    _mm256_fmadd_ps(x, _mm256_set1_ps(std::f32::consts::LOG2_E), round),
                    round,
                );
                let r = _mm256_fnmadd_ps(n, _mm256_set1_ps(0.693_359_4), x);
                let r = _mm256_fnmadd_ps(n, _mm256_set1_ps(-2.121_944_4e-4), r);
                let step = |p: __m256, c: f32| _mm256_fmadd_ps(p, r, _mm256_set1_ps(c));
                let p = _mm256_set1_ps(1.987_569_1e-4);
                let p = step(p, 1.398_199_9e-3);
                let p = step(p, 8.333_452e-3);
                let p = step(p, 4.166_579_6e-2);
                let p = step(p, 1.666_666_5e-1);
                let p = step(p, 0.5);
                let e = _mm256_add_ps(
                    _mm256_fmadd_ps(_mm256_mul_ps(p, r), r, r),
                    _mm256_set1_ps(1.0),
                );
                let bits = _mm256_slli_epi32::<23>(_mm256_add_epi32(
                    _mm256_cvttps_epi32(n),
                    _mm256_set1_epi32(127),
                ));
                _mm256_mul_ps(e, _mm256_castsi256_ps(bits))
            }

            /// # Safety
            /// The CPU must have AVX2, FMA and POPCNT.
            #[target_feature(enable = $features)]
            pub unsafe fn forward_tile_lanes(
                splats: &[Splat],
                (x0, y0, w, h): (u32, u32, u32, u32),
                st: &mut TileState,
                blocks: &mut [u32],
            ) -> u64 {
                let mut blended = 0u64;
                let mut n_done = 0usize;
                let n = (w * h) as usize;
                let lane_f = _mm256_setr_ps(0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0);
                let lane_i = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
                let (half, one) = (_mm256_set1_ps(0.5), _mm256_set1_ps(1.0));
                let (max_alpha, thr, tmin) = (
                    _mm256_set1_ps(MAX_ALPHA),
                    _mm256_set1_ps(ALPHA_THRESHOLD),
                    _mm256_set1_ps(TRANSMITTANCE_MIN),
                );
                for (k, s) in splats.iter().enumerate() {
                    if n_done == n {
                        break;
                    }
                    let Some(bounds) = local_box(s, x0, y0, w, h) else {
                        continue;
                    };
                    let [lx0, lx1, ly0, ly1] = bounds.map(|v| v as i32);
                    let (m, [ca, cb, cc], o, cut) =
                        (s.mean(), s.conic(), s.opacity(), s.sigma_cut());
                    let (col, z) = (s.color(), s.depth());
                    let (ca, cb, cc, o) = (
                        _mm256_set1_ps(ca),
                        _mm256_set1_ps(cb),
                        _mm256_set1_ps(cc),
                        _mm256_set1_ps(o),
                    );
                    let cut = _mm256_set1_ps(cut);
                    let (cr, cg, cbl, zz) = (
                        _mm256_set1_ps(col.x),
                        _mm256_set1_ps(col.y),
                        _mm256_set1_ps(col.z),
                        _mm256_set1_ps(z),
                    );
                    let next_k = _mm256_set1_epi32(k as i32 + 1);
                    let b0 = lx0 as usize / LANES * LANES;
                    let mut set = 0u32;
                    for ly in ly0 as usize..=ly1 as usize {
                        let dy = _mm256_set1_ps(m.y - ((y0 as usize + ly) as f32 + 0.5));
                        let cdydy = _mm256_mul_ps(_mm256_mul_ps(cc, dy), dy);
                        let mut bx = b0;
                        while bx <= lx1 as usize {
                            let i = ly * STRIDE + bx;
                            let dx0 = m.x - ((x0 as usize + bx) as f32 + 0.5);
                            let dx = _mm256_sub_ps(_mm256_set1_ps(dx0), lane_f);
                            let sigma = _mm256_fmadd_ps(
                                half,
                                _mm256_fmadd_ps(_mm256_mul_ps(ca, dx), dx, cdydy),
                                _mm256_mul_ps(_mm256_mul_ps(cb, dx), dy),
                            );
                            // Lanes inside the box (its columns lx0..=lx1) and not finished.
                            let lx = _mm256_add_epi32(_mm256_set1_epi32(bx as i32), lane_i);
                            let inside = _mm256_andnot_si256(
                                _mm256_or_si256(
                                    _mm256_cmpgt_epi32(_mm256_set1_epi32(lx0), lx),
                                    _mm256_cmpgt_epi32(lx, _mm256_set1_epi32(lx1)),
                                ),
                                _mm256_set1_epi32(-1),
                            );
                            // SAFETY: `i + 8 <= TILE_PX`: a block starts at a multiple of 8 inside a
                            // row of STRIDE (16) pixels.
                            let (p_tr, p_done) = unsafe {
                                (
                                    st.tr.as_mut_ptr().add(i),
                                    st.done.as_mut_ptr().add(i) as *mut __m256i,
                                )
                            };
                            let done = unsafe { _mm256_loadu_si256(p_done) };
                            let live = _mm256_castsi256_ps(_mm256_andnot_si256(done, inside));
                            let near = _mm256_and_ps(
                                _mm256_and_ps(
                                    live,
                                    _mm256_cmp_ps::<_CMP_GE_OQ>(sigma, _mm256_setzero_ps()),
                                ),
                                _mm256_cmp_ps::<_CMP_LE_OQ>(sigma, cut),
                            );
                            // A block of the box's corners, outside the ellipse, skips the exponential.
                            if _mm256_movemask_ps(near) == 0 {
                                bx += LANES;
                                continue;
                            }
                            let alpha = _mm256_min_ps(max_alpha, _mm256_mul_ps(o, exp_neg(sigma)));
                            let ok = _mm256_and_ps(near, _mm256_cmp_ps::<_CMP_GE_OQ>(alpha, thr));
                            let okm = _mm256_movemask_ps(ok);
                            if okm == 0 {
                                bx += LANES;
                                continue;
                            }
                            let tr = unsafe { _mm256_loadu_ps(p_tr) };
                            let next_t = _mm256_mul_ps(tr, _mm256_sub_ps(one, alpha));
                            let stop = _mm256_and_ps(ok, _mm256_cmp_ps::<_CMP_LE_OQ>(next_t, tmin));
                            let blend = _mm256_andnot_ps(stop, ok);
                            let wgt = _mm256_mul_ps(alpha, tr);
                            let add = |p: *mut f32, c: __m256| {
                                // SAFETY: as above, for every channel array.
                                unsafe {
                                    let v = _mm256_loadu_ps(p);
                                    let nv = _mm256_fmadd_ps(c, wgt, v);
                                    _mm256_storeu_ps(p, _mm256_blendv_ps(v, nv, blend));
                                }
                            };
                            unsafe {
                                add(st.c[0].as_mut_ptr().add(i), cr);
                                add(st.c[1].as_mut_ptr().add(i), cg);
                                add(st.c[2].as_mut_ptr().add(i), cbl);
                                add(st.depth.as_mut_ptr().add(i), zz);
                                _mm256_storeu_ps(p_tr, _mm256_blendv_ps(tr, next_t, blend));
                                let p_last = st.last.as_mut_ptr().add(i) as *mut __m256i;
                                let last = _mm256_loadu_si256(p_last);
                                _mm256_storeu_si256(
                                    p_last,
                                    _mm256_blendv_epi8(last, next_k, _mm256_castps_si256(blend)),
                                );
                                _mm256_storeu_si256(
                                    p_done,
                                    _mm256_or_si256(done, _mm256_castps_si256(stop)),
                                );
                            }
                            let blend_bits = _mm256_movemask_ps(blend);
                            blended += blend_bits.count_ones() as u64;
                            set |= if blend_bits != 0 {
                                block_bit(ly, bx)
                            } else {
                                0
                            };
                            n_done += _mm256_movemask_ps(stop).count_ones() as usize;
                            bx += LANES;
                        }
                    }
                    blocks[k] = set;
                }
                blended
            }

            /// [`crate::blocks::backward_list`] around this build's kernel, so that the
            /// kernel is inlined into the walk over the list.
            ///
            /// # Safety
            /// The CPU must have AVX2, FMA and POPCNT.
            #[target_feature(enable = $features)]
            pub unsafe fn backward_list(
                list: &BackList,
                tile: (u32, u32, u32, u32),
                st: &mut BackState,
                out: &mut [MaybeUninit<IsectGrad>],
            ) {
                crate::blocks::backward_list(list, tile, st, out, |s, k, t, st, b| {
                    // SAFETY: the caller's promise.
                    unsafe { backward_splat(s, k, t, st, b) }
                })
            }

            /// [`crate::blocks::backward_splat`] on eight lanes.
            ///
            /// # Safety
            /// The CPU must have AVX2, FMA and POPCNT.
            #[target_feature(enable = $features)]
            #[inline]
            pub unsafe fn backward_splat(
                s: &Splat,
                k: u32,
                (x0, y0, w, h): (u32, u32, u32, u32),
                st: &mut BackState,
                blocks: u32,
            ) -> [f32; SUMS] {
                let Some(bounds) = local_box(s, x0, y0, w, h) else {
                    return [0.0; SUMS];
                };
                let [lx0, lx1, _, _] = bounds.map(|v| v as i32);
                let (m, [ca, cb, cc], o, cut) = (s.mean(), s.conic(), s.opacity(), s.sigma_cut());
                let (col, z) = (s.color(), s.depth());
                let set = _mm256_set1_ps;
                let (ca, cb, cc, o, cut) = (set(ca), set(cb), set(cc), set(o), set(cut));
                let (cx, cy, cz, zz) = (set(col.x), set(col.y), set(col.z), set(z));
                let (half, one, zero) = (set(0.5), set(1.0), _mm256_setzero_ps());
                let (max_alpha, thr) = (set(MAX_ALPHA), set(ALPHA_THRESHOLD));
                let sign = set(-0.0);
                let lane_f = _mm256_setr_ps(0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0);
                let lane_i = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
                // `k < last` as a signed compare: counts stay far below 2³¹.
                let kv = _mm256_set1_epi32(k as i32);
                let mut acc = [zero; SUMS];
                // The box's blocks in which the forward blended this splat, row by row.
                let mut todo = blocks & box_blocks(bounds);
                while todo != 0 {
                    let b = todo.trailing_zeros() as usize;
                    todo &= todo - 1;
                    let (ly, bx) = (b / BLOCKS_PER_ROW, b % BLOCKS_PER_ROW * LANES);
                    let dy = set(m.y - ((y0 as usize + ly) as f32 + 0.5));
                    {
                        let i = ly * STRIDE + bx;
                        let dx =
                            _mm256_sub_ps(set(m.x - ((x0 as usize + bx) as f32 + 0.5)), lane_f);
                        let sigma = _mm256_fmadd_ps(
                            half,
                            _mm256_fmadd_ps(
                                _mm256_mul_ps(ca, dx),
                                dx,
                                _mm256_mul_ps(_mm256_mul_ps(cc, dy), dy),
                            ),
                            _mm256_mul_ps(_mm256_mul_ps(cb, dx), dy),
                        );
                        let lx = _mm256_add_epi32(_mm256_set1_epi32(bx as i32), lane_i);
                        // SAFETY (every pointer below): `i + 8 <= TILE_PX`, as in the forward.
                        let p = |a: &mut [f32; TILE_PX]| unsafe { a.as_mut_ptr().add(i) };
                        let last = unsafe {
                            _mm256_loadu_si256(st.last.as_ptr().add(i) as *const __m256i)
                        };
                        let in_list = _mm256_cmpgt_epi32(last, kv);
                        let outside = _mm256_or_si256(
                            _mm256_cmpgt_epi32(_mm256_set1_epi32(lx0), lx),
                            _mm256_cmpgt_epi32(lx, _mm256_set1_epi32(lx1)),
                        );
                        let near = _mm256_and_ps(
                            _mm256_castsi256_ps(_mm256_andnot_si256(outside, in_list)),
                            _mm256_and_ps(
                                _mm256_cmp_ps::<_CMP_GE_OQ>(sigma, zero),
                                _mm256_cmp_ps::<_CMP_LE_OQ>(sigma, cut),
                            ),
                        );
                        // As in the forward: no exponential for a block no lane of which can blend.
                        if _mm256_movemask_ps(near) == 0 {
                            continue;
                        }
                        let vis = exp_neg(sigma);
                        let raw = _mm256_mul_ps(o, vis);
                        let alpha = _mm256_min_ps(max_alpha, raw);
                        let ok = _mm256_and_ps(near, _mm256_cmp_ps::<_CMP_GE_OQ>(alpha, thr));
                        if _mm256_movemask_ps(ok) == 0 {
                            continue;
                        }
                        unsafe {
                            let ra = _mm256_div_ps(one, _mm256_sub_ps(one, alpha));
                            let tr0 = _mm256_loadu_ps(p(&mut st.tr));
                            let t = _mm256_blendv_ps(tr0, _mm256_mul_ps(tr0, ra), ok);
                            _mm256_storeu_ps(p(&mut st.tr), t);
                            let fac = _mm256_mul_ps(alpha, t);
                            let vc0 = _mm256_loadu_ps(p(&mut st.v_c[0]));
                            let vc1 = _mm256_loadu_ps(p(&mut st.v_c[1]));
                            let vc2 = _mm256_loadu_ps(p(&mut st.v_c[2]));
                            let vd = _mm256_loadu_ps(p(&mut st.v_dsum));
                            let vf = _mm256_loadu_ps(p(&mut st.v_final));
                            let b0v = _mm256_loadu_ps(p(&mut st.behind[0]));
                            let b1v = _mm256_loadu_ps(p(&mut st.behind[1]));
                            let b2v = _mm256_loadu_ps(p(&mut st.behind[2]));
                            let bzv = _mm256_loadu_ps(p(&mut st.behind_z));
                            // (c·t − b·ra), the factor of each pixel gradient in ∂L/∂α.
                            let term =
                                |c: __m256, b: __m256| _mm256_fmsub_ps(c, t, _mm256_mul_ps(b, ra));
                            let v_alpha = _mm256_mul_ps(term(cx, b0v), vc0);
                            let v_alpha = _mm256_fmadd_ps(term(cy, b1v), vc1, v_alpha);
                            let v_alpha = _mm256_fmadd_ps(term(cz, b2v), vc2, v_alpha);
                            let v_alpha = _mm256_fmadd_ps(term(zz, bzv), vd, v_alpha);
                            let v_alpha = _mm256_fmadd_ps(ra, vf, v_alpha);
                            let on = |a: __m256, add: __m256, m: __m256| {
                                _mm256_blendv_ps(a, _mm256_add_ps(a, add), m)
                            };
                            // a + x·y, fused, on the lanes of m.
                            let on_fma = |a: __m256, x: __m256, y: __m256, m: __m256| {
                                _mm256_blendv_ps(a, _mm256_fmadd_ps(x, y, a), m)
                            };
                            acc[7] = on_fma(acc[7], vc0, fac, ok);
                            acc[8] = on_fma(acc[8], vc1, fac, ok);
                            acc[9] = on_fma(acc[9], vc2, fac, ok);
                            acc[11] = on_fma(acc[11], vd, fac, ok);
                            _mm256_storeu_ps(p(&mut st.behind[0]), on_fma(b0v, cx, fac, ok));
                            _mm256_storeu_ps(p(&mut st.behind[1]), on_fma(b1v, cy, fac, ok));
                            _mm256_storeu_ps(p(&mut st.behind[2]), on_fma(b2v, cz, fac, ok));
                            _mm256_storeu_ps(p(&mut st.behind_z), on_fma(bzv, zz, fac, ok));
                            let grad =
                                _mm256_and_ps(ok, _mm256_cmp_ps::<_CMP_LE_OQ>(raw, max_alpha));
                            let v_sigma = _mm256_mul_ps(_mm256_xor_ps(raw, sign), v_alpha);
                            let vmx = _mm256_mul_ps(
                                v_sigma,
                                _mm256_fmadd_ps(ca, dx, _mm256_mul_ps(cb, dy)),
                            );
                            let vmy = _mm256_mul_ps(
                                v_sigma,
                                _mm256_fmadd_ps(cb, dx, _mm256_mul_ps(cc, dy)),
                            );
                            let hv = _mm256_mul_ps(half, v_sigma);
                            acc[0] = on(acc[0], vmx, grad);
                            acc[1] = on(acc[1], vmy, grad);
                            acc[2] = on(acc[2], _mm256_andnot_ps(sign, vmx), grad);
                            acc[3] = on(acc[3], _mm256_andnot_ps(sign, vmy), grad);
                            acc[4] = on_fma(acc[4], _mm256_mul_ps(hv, dx), dx, grad);
                            acc[5] = on_fma(acc[5], _mm256_mul_ps(v_sigma, dx), dy, grad);
                            acc[6] = on_fma(acc[6], _mm256_mul_ps(hv, dy), dy, grad);
                            acc[10] = on_fma(acc[10], vis, v_alpha, grad);
                        }
                    }
                }
                reduce(&acc)
            }

            /// [`crate::blocks::reduce`] on the vectors: `_mm256_hadd_ps` adds neighbouring
            /// lanes within each half, twice, which leaves the sums of lanes 0–3 and of lanes
            /// 4–7 of four accumulators in one vector; its halves are added last.
            #[inline]
            #[target_feature(enable = $features)]
            fn reduce(acc: &[__m256; SUMS]) -> [f32; SUMS] {
                let h = |a, b| _mm256_hadd_ps(a, b);
                let mut out = [0.0f32; SUMS];
                for (q, four) in acc.chunks_exact(4).enumerate() {
                    let v = h(h(four[0], four[1]), h(four[2], four[3]));
                    let sum = _mm_add_ps(_mm256_castps256_ps128(v), _mm256_extractf128_ps::<1>(v));
                    // SAFETY: four floats from 4q, and SUMS is a multiple of four.
                    unsafe { _mm_storeu_ps(out.as_mut_ptr().add(4 * q), sum) };
                }
                out
            }
        }
    };
}

simd_kernels!(avx2, "avx2,fma,popcnt");
simd_kernels!(avx512, "avx2,fma,popcnt,avx512f,avx512vl");

/// Per-splat gradient sums, in lanes while a splat is visited and reduced once when it is
/// done: mean2d (2), |mean2d| (2), conic (3), colour (3), opacity, depth.
const SUMS: usize = 12;
// The vector reduction takes the sums four at a time.
const _: () = assert!(SUMS.is_multiple_of(4));

/// What the backward keeps per pixel of a tile, structure of arrays (see
/// `raster::backward_tile` for what each is).
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
/// contribution is masked off, so the results are the same to the bit. Same results as [`crate::raster::backward_tile`]
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

/// The lanes of `sums` added up as a tree, `((l0 + l1) + (l2 + l3)) + ((l4 + l5) + (l6 + l7))`:
/// the order in which horizontal vector adds sum them.
#[inline(always)]
fn reduce(sums: &[Lanes; SUMS]) -> [f32; SUMS] {
    std::array::from_fn(|q| {
        let l = &sums[q];
        ((l[0] + l[1]) + (l[2] + l[3])) + ((l[4] + l[5]) + (l[6] + l[7]))
    })
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

/// Splat `k` undone from the pixels of its box, back to front: the portable lanes the AVX2
/// kernel mirrors operation for operation.
#[allow(clippy::needless_range_loop)]
fn backward_splat(
    s: &Splat,
    k: u32,
    (x0, y0, w, h): (u32, u32, u32, u32),
    st: &mut BackState,
    blocks: u32,
) -> [f32; SUMS] {
    let mut acc = [[0.0f32; LANES]; SUMS];
    let Some(bounds) = local_box(s, x0, y0, w, h) else {
        return [0.0; SUMS];
    };
    let [lx0, lx1, _, _] = bounds.map(|v| v as i32);
    let (m, [ca, cb, cc], o, cut) = (s.mean(), s.conic(), s.opacity(), s.sigma_cut());
    let (col, z) = (s.color(), s.depth());
    let mut todo = blocks & box_blocks(bounds);
    while todo != 0 {
        let b = todo.trailing_zeros() as usize;
        todo &= todo - 1;
        let (ly, bx) = (b / BLOCKS_PER_ROW, b % BLOCKS_PER_ROW * LANES);
        let dy = m.y - ((y0 as usize + ly) as f32 + 0.5);
        {
            let dx0 = m.x - ((x0 as usize + bx) as f32 + 0.5);
            for l in 0..LANES {
                let i = ly * STRIDE + bx + l;
                let lx = (bx + l) as i32;
                let dx = dx0 - l as f32;
                let sigma = 0.5f32.mul_add((ca * dx).mul_add(dx, cc * dy * dy), cb * dx * dy);
                let vis = exp_neg(sigma);
                let raw = o * vis;
                let alpha = MAX_ALPHA.min(raw);
                let ok = k < st.last[i]
                    && lx0 <= lx
                    && lx <= lx1
                    && (0.0..=cut).contains(&sigma)
                    && alpha >= ALPHA_THRESHOLD;
                let ra = 1.0 / (1.0 - alpha);
                let t = if ok { st.tr[i] * ra } else { st.tr[i] };
                st.tr[i] = t;
                let fac = alpha * t;
                let term = |c: f32, b: f32| c.mul_add(t, -(b * ra));
                let v_alpha = term(col.x, st.behind[0][i]) * st.v_c[0][i];
                let v_alpha = term(col.y, st.behind[1][i]).mul_add(st.v_c[1][i], v_alpha);
                let v_alpha = term(col.z, st.behind[2][i]).mul_add(st.v_c[2][i], v_alpha);
                let v_alpha = term(z, st.behind_z[i]).mul_add(st.v_dsum[i], v_alpha);
                let v_alpha = ra.mul_add(st.v_final[i], v_alpha);
                let on = |a: f32, add: f32, on: bool| if on { a + add } else { a };
                let on_fma =
                    |a: f32, x: f32, y: f32, on: bool| if on { x.mul_add(y, a) } else { a };
                acc[7][l] = on_fma(acc[7][l], st.v_c[0][i], fac, ok);
                acc[8][l] = on_fma(acc[8][l], st.v_c[1][i], fac, ok);
                acc[9][l] = on_fma(acc[9][l], st.v_c[2][i], fac, ok);
                acc[11][l] = on_fma(acc[11][l], st.v_dsum[i], fac, ok);
                st.behind[0][i] = on_fma(st.behind[0][i], col.x, fac, ok);
                st.behind[1][i] = on_fma(st.behind[1][i], col.y, fac, ok);
                st.behind[2][i] = on_fma(st.behind[2][i], col.z, fac, ok);
                st.behind_z[i] = on_fma(st.behind_z[i], z, fac, ok);
                let grad = ok && raw <= MAX_ALPHA;
                let v_sigma = -raw * v_alpha;
                let vmx = v_sigma * ca.mul_add(dx, cb * dy);
                let vmy = v_sigma * cb.mul_add(dx, cc * dy);
                acc[0][l] = on(acc[0][l], vmx, grad);
                acc[1][l] = on(acc[1][l], vmy, grad);
                acc[2][l] = on(acc[2][l], vmx.abs(), grad);
                acc[3][l] = on(acc[3][l], vmy.abs(), grad);
                acc[4][l] = on_fma(acc[4][l], 0.5 * v_sigma * dx, dx, grad);
                acc[5][l] = on_fma(acc[5][l], v_sigma * dx, dy, grad);
                acc[6][l] = on_fma(acc[6][l], 0.5 * v_sigma * dy, dy, grad);
                acc[10][l] = on_fma(acc[10][l], vis, v_alpha, grad);
            }
        }
    }
    reduce(&acc)
}

#[cfg(test)]
mod tests {
    use super::*;

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
            .map(|i| crate::project::project_one(&g, i, &cam, 1, false, pos).unwrap_or_default())
            .collect();
        let bins = crate::tiles::bin(&projected, cam.width, cam.height);
        let splats: Vec<Splat> = projected.iter().map(Splat::new).collect();
        let mut checked = 0;
        for t in 0..bins.num_tiles() {
            let list = crate::raster::gather(&bins, &splats, t);
            let tile = crate::raster::tile_pixels(&bins, t, cam.width, cam.height);
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
            .map(|i| crate::project::project_one(&g, i, &cam, 1, false, pos).unwrap_or_default())
            .collect();
        let bins = crate::tiles::bin(&projected, cam.width, cam.height);
        let splats: Vec<Splat> = projected.iter().map(Splat::new).collect();
        let (mut compared, mut skipped) = (0, 0);
        for t in 0..bins.num_tiles() {
            let list = crate::raster::gather(&bins, &splats, t);
            let tile = crate::raster::tile_pixels(&bins, t, cam.width, cam.height);
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

    #[test]
    fn exp_neg_is_within_its_stated_error() {
        let mut worst = 0.0f64;
        for i in 0..=2_000_000u32 {
            let s = i as f32 * (87.0 / 2_000_000.0);
            let exact = (-(s as f64)).exp();
            let rel = ((exp_neg(s) as f64 - exact) / exact).abs();
            worst = worst.max(rel);
        }
        assert!(worst < EXP_REL_ERROR, "worst relative error {worst:e}");
        // Out-of-range inputs stay finite: masked lanes compute them too.
        for s in [-1.0f32, -1e30, 1e30, f32::INFINITY, f32::NEG_INFINITY] {
            assert!(exp_neg(s).is_finite(), "{s}");
        }
        assert_eq!(exp_neg(0.0), 1.0);
    }
}
