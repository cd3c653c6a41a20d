//! The portable builds of the blending kernels: lane loops the intrinsics builds
//! ([`super::intrinsics`]) mirror operation for operation.

use super::{BLOCKS_PER_ROW, BackState, Lanes, STRIDE, SUMS, TileState, block_bit, box_blocks};
use crate::conventions::{ALPHA_THRESHOLD, MAX_ALPHA, TRANSMITTANCE_MIN};
use crate::cpu::exp::exp_neg;
use crate::cpu::lanes::LANES;
use crate::cpu::stages::{Splat, local_box};

/// The portable kernel: lane loops the AVX2 kernel mirrors operation for operation.
// The lane index addresses several arrays in lockstep, as the vector code does.
#[allow(clippy::needless_range_loop)]
pub(super) fn forward_tile_lanes(
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

/// The lanes of `sums` added up as a tree, `((l0 + l1) + (l2 + l3)) + ((l4 + l5) + (l6 + l7))`:
/// the order in which horizontal vector adds sum them.
#[inline(always)]
pub(super) fn reduce(sums: &[Lanes; SUMS]) -> [f32; SUMS] {
    std::array::from_fn(|q| {
        let l = &sums[q];
        ((l[0] + l[1]) + (l[2] + l[3])) + ((l[4] + l[5]) + (l[6] + l[7]))
    })
}

/// Splat `k` undone from the pixels of its box, back to front: the portable lanes the AVX2
/// kernel mirrors operation for operation.
#[allow(clippy::needless_range_loop)]
pub(super) fn backward_splat(
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
