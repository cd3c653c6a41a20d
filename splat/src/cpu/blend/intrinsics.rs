//! The intrinsics builds of the blending kernels, one module per instruction set.

/// A build of the intrinsics kernels for one instruction set: [`forward_tile_lanes`] and
/// [`backward_splat`] with the same operations in the same order on eight lanes at once (fused
/// multiply-adds exactly where the portable loop calls `mul_add`, so the bits equal the
/// portable loop's). The AVX-512 build is the same source: AVX-512VL gives the compiler 32
/// vector registers instead of 16, so the backward's twelve lane sums stay out of memory.
macro_rules! simd_kernels {
    ($module:ident, $features:literal) => {
        #[cfg(target_arch = "x86_64")]
        pub(super) mod $module {
            use std::arch::x86_64::*;

            use std::mem::MaybeUninit;

            use crate::conventions::{ALPHA_THRESHOLD, MAX_ALPHA, TRANSMITTANCE_MIN};
            use crate::cpu::blend::{
                BLOCKS_PER_ROW, BackList, BackState, STRIDE, SUMS, TILE_PX, TileState, block_bit,
                box_blocks,
            };
            use crate::cpu::lanes::LANES;
            use crate::cpu::stages::{IsectGrad, Splat, local_box};

            /// [`crate::cpu::exp::exp_neg`] on eight lanes.
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

            /// [`crate::cpu::blend::backward_list`] around this build's kernel, so that the
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
                crate::cpu::blend::backward_list(list, tile, st, out, |s, k, t, st, b| {
                    // SAFETY: the caller's promise.
                    unsafe { backward_splat(s, k, t, st, b) }
                })
            }

            /// [`crate::cpu::blend::backward_splat`] on eight lanes.
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

            /// [`crate::cpu::blend::reduce`] on the vectors: `_mm256_hadd_ps` adds neighbouring
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
