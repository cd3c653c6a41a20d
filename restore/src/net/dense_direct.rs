//! The dense 3×3 convolution (zero padding, stride 1, no bias) on the CPU: the 1×1 loop's
//! register tiles over each block's nine shifted copies of its input rows.
//!
//! burn's CPU convolution writes the whole im2col matrix (9·cin rows by every pixel, zeroed
//! first) and packs it for a general matrix product: about 12 % of a `tiny` forward pass, for
//! the network's embedding, output, down- and up-sampling layers. Here a task is one output
//! row of one image; each block of [`BLOCK`] pixels of it copies the 9·cin input rows it reads
//! (channel by channel, then `ky`, then `kx`: the order of `[cout, cin, 3, 3]` weights, which
//! are then the 1×1 loop's `[cout, 9·cin]`) side by side, zero outside the map, and
//! [`super::pointwise`]'s tiles sum them. The same kernel with the weights transposed and
//! turned half a turn is the input gradient ([`super::conv_train`]).
//!
//! Every build adds the 9·cin products in the same order, each fused (one rounding, the
//! portable loop's `mul_add` and the vector builds' FMA: the same bits); the output is within
//! 1e-6 of its scale of an f64 sum (the tests below).

use super::pointwise::{BLOCK, Out};
use rayon::prelude::*;

/// `x: [b, cin, h, w]`, `weight: [cout, cin, 3, 3]` → `[b, cout, h, w]`:
/// `out[n][o][y][x] = Σ_{i, ky, kx} weight[o][i][ky][kx] · x[n][i][y + ky − 1][x + kx − 1]`,
/// the input zero outside the map.
pub fn dense3(x: &[f32], weight: &[f32], cout: usize, [b, cin, h, w]: [usize; 4]) -> Vec<f32> {
    let plane = h * w;
    assert_eq!(x.len(), b * cin * plane, "map of {b}x{cin}x{h}x{w}");
    assert_eq!(weight.len(), cout * cin * 9, "{cout}x{cin}x3x3 weights");
    let len = b * cout * plane;
    let mut out = Vec::<f32>::with_capacity(len);
    let dst = Out(out.as_mut_ptr());
    // One gathering buffer per rayon job, not per row (every value is written before it is
    // read, so its zeros are not needed again).
    let buffer = || vec![0.0f32; 9 * cin * BLOCK];
    (0..b * h)
        .into_par_iter()
        .for_each_init(buffer, |buf, task| {
            let (n, y) = (task / h, task % h);
            let src = &x[n * cin * plane..][..cin * plane];
            // SAFETY: `out` has capacity for `b·cout·plane` values; this task writes only row `y`
            // of item `n`'s `cout` planes, inside that capacity.
            let row = unsafe { dst.add(n * cout * plane + y * w) };
            output_row(row, buf, src, weight, Dims { cout, cin, h, w }, y);
        });
    // SAFETY: the tasks above wrote every row of every plane of every item.
    unsafe { out.set_len(len) };
    out
}

/// One image's sizes: output channels, input channels, height, width.
#[derive(Clone, Copy)]
struct Dims {
    cout: usize,
    cin: usize,
    h: usize,
    w: usize,
}

/// Row `y` of all `cout` output planes of one image.
fn output_row(dst: Out, buf: &mut [f32], x: &[f32], weight: &[f32], dims: Dims, y: usize) {
    #[cfg(target_arch = "x86_64")]
    match base::isa::Isa::chosen() {
        // SAFETY: `Isa::chosen` names a build the CPU has; the writes stay in row `y` of each
        // plane (see `dense3`).
        base::isa::Isa::Avx512 => return unsafe { row_avx512(dst, buf, x, weight, dims, y) },
        // SAFETY: as above.
        base::isa::Isa::Avx2 => return unsafe { row_avx2(dst, buf, x, weight, dims, y) },
        base::isa::Isa::Portable => {}
    }
    // SAFETY: as above.
    unsafe { row_portable(dst, buf, x, weight, dims, y) }
}

/// The portable build of the row: [`blocks`] over [`portable_tile`].
///
/// # Safety
/// As [`blocks`].
unsafe fn row_portable(dst: Out, buf: &mut [f32], x: &[f32], weight: &[f32], dims: Dims, y: usize) {
    let tile = |rows, src, w, out, taps, stride| {
        // SAFETY: `blocks`' contract for its tiles is `portable_tile`'s.
        unsafe { portable_tile(rows, src, w, out, taps, stride) }
    };
    // SAFETY: the caller's contract.
    unsafe { blocks::<6, 16>(dst, buf, x, weight, dims, y, tile) }
}

/// The tile of the portable build: `out[j][k] = Σ_i w[j·taps + i] · src[i·BLOCK + k]` for
/// `j < rows`, `k < 16`, fused into the sum in `i`'s order from zero (the vector tiles' bits).
///
/// # Safety
/// As the vector tiles: `src` has `taps` rows of [`BLOCK`] values, `w` `rows` rows of `taps`,
/// `out` `rows` rows `stride` apart with 16 writable values each.
unsafe fn portable_tile(
    rows: usize,
    src: *const f32,
    w: *const f32,
    out: *mut f32,
    taps: usize,
    stride: usize,
) {
    for j in 0..rows {
        let mut acc = [0.0f32; 16];
        for i in 0..taps {
            // SAFETY: the contract above.
            let (wv, s) = unsafe {
                (
                    *w.add(j * taps + i),
                    std::slice::from_raw_parts(src.add(i * BLOCK), 16),
                )
            };
            for (a, &v) in acc.iter_mut().zip(s) {
                *a = wv.mul_add(v, *a);
            }
        }
        // SAFETY: the contract above.
        unsafe { std::ptr::copy_nonoverlapping(acc.as_ptr(), out.add(j * stride), 16) };
    }
}

/// A vector build of the row over [`blocks`] with `pointwise`'s tiles `$tile::<R>` for `R` up
/// to `$rows` output channels × `$cols` pixels, compiled with `$features`.
macro_rules! row_build {
    ($(#[$doc:meta])* $name:ident, $features:literal, $tile:ident, $rows:literal, $cols:literal,
     [$($r:literal),*]) => {
        $(#[$doc])*
        /// # Safety
        /// As [`blocks`]; the CPU has the build's features.
        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = $features)]
        unsafe fn $name(dst: Out, buf: &mut [f32], x: &[f32], weight: &[f32], dims: Dims, y: usize) {
            const ZEROS: [f32; $rows] = [0.0; $rows];
            let tile = |rows: usize, src: *const f32, w: *const f32, out: *mut f32, taps: usize,
                        stride: usize| {
                // SAFETY: `blocks`' contract for its tiles; the build's features are enabled.
                unsafe {
                    match rows {
                        $($r => super::pointwise::$tile::<$r>(src, w, &ZEROS, out, taps, stride),)*
                        _ => unreachable!("a tile has 1 to {} rows", $rows),
                    }
                }
            };
            // SAFETY: the caller's contract.
            unsafe { blocks::<$rows, $cols>(dst, buf, x, weight, dims, y, tile) }
        }
    };
}

row_build!(
    /// 6 output channels × 16 pixels per tile.
    row_avx2, "avx2,fma", tile8, 6, 16, [1, 2, 3, 4, 5, 6]
);
row_build!(
    /// 12 output channels × 32 pixels per tile.
    row_avx512, "avx512f,avx512vl,avx2,fma", tile16, 12, 32,
    [1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12]
);

/// Row `y` in blocks of [`BLOCK`] pixels: each block's 9·cin shifted input rows gathered side
/// by side into `buf` ([`gather`]), then `tile(rows, src, w, out, 9·cin, stride)` over `ROWS`
/// output channels × `COLS` pixels at a time. A tile that would run past the row's end writes
/// into a scratch tile, of which the row's pixels are copied.
///
/// # Safety
/// `dst` points at pixel 0 of row `y` of the first of `cout` planes `h·w` apart, and the caller
/// owns that row of each; `buf` holds at least `9·cin·BLOCK` values; `tile` may be called with
/// `src` at `taps` rows of `BLOCK` values (reading `COLS` from each), `w` at `rows ≤ ROWS` rows
/// of `taps` weights and `out` at `rows` rows `stride` apart with `COLS` writable values each;
/// `COLS` divides [`BLOCK`].
#[inline(always)]
unsafe fn blocks<const ROWS: usize, const COLS: usize>(
    dst: Out,
    buf: &mut [f32],
    x: &[f32],
    weight: &[f32],
    Dims { cout, cin, h, w }: Dims,
    y: usize,
    tile: impl Fn(usize, *const f32, *const f32, *mut f32, usize, usize),
) {
    let (plane, taps) = (h * w, 9 * cin);
    let buf = &mut buf[..taps * BLOCK];
    let mut scratch = [[0.0f32; COLS]; ROWS];
    for x0 in (0..w).step_by(BLOCK) {
        let len = BLOCK.min(w - x0);
        gather(buf, x, cin, (h, w), y, x0..x0 + len);
        for o0 in (0..cout).step_by(ROWS) {
            let rows = ROWS.min(cout - o0);
            let wt = weight[o0 * taps..].as_ptr();
            for t in (0..len).step_by(COLS) {
                let src = buf[t..].as_ptr();
                if t + COLS <= len {
                    // SAFETY: planes `o0..o0 + rows` exist, and pixels `x0 + t ..` of row `y`
                    // up to `x0 + t + COLS ≤ w` are the caller's.
                    tile(
                        rows,
                        src,
                        wt,
                        unsafe { dst.0.add(o0 * plane + x0 + t) },
                        taps,
                        plane,
                    );
                } else {
                    tile(rows, src, wt, scratch.as_mut_ptr().cast(), taps, COLS);
                    for (j, s) in scratch[..rows].iter().enumerate() {
                        // SAFETY: as above, the row's last `len − t` pixels.
                        unsafe {
                            std::ptr::copy_nonoverlapping(
                                s.as_ptr(),
                                dst.0.add((o0 + j) * plane + x0 + t),
                                len - t,
                            )
                        };
                    }
                }
            }
        }
    }
}

/// `buf` row `i·9 + ky·3 + kx` (of [`BLOCK`] values) ← input channel `i` at row `y + ky − 1`,
/// columns `cols` shifted by `kx − 1`, zero outside the map and past the block's end.
fn gather(
    buf: &mut [f32],
    x: &[f32],
    cin: usize,
    (h, w): (usize, usize),
    y: usize,
    cols: std::ops::Range<usize>,
) {
    let (x0, len) = (cols.start, cols.len());
    for (i, channel) in buf.chunks_exact_mut(9 * BLOCK).take(cin).enumerate() {
        for (ky, rows) in channel.chunks_exact_mut(3 * BLOCK).enumerate() {
            let Some(sy) = (y + ky).checked_sub(1).filter(|&sy| sy < h) else {
                rows.fill(0.0);
                continue;
            };
            let src = &x[(i * h + sy) * w..][..w];
            for (kx, d) in rows.chunks_exact_mut(BLOCK).enumerate() {
                // d[t] reads column x0 + t + kx − 1: inside the map for t in lo..hi.
                let lo = usize::from(x0 + kx == 0);
                let hi = len.min((w + 1).saturating_sub(x0 + kx));
                d[..lo].fill(0.0);
                d[lo..hi].copy_from_slice(&src[x0 + lo + kx - 1..][..hi - lo]);
                d[hi..].fill(0.0);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::test_values::{rel_err, values};
    use super::*;

    /// The convolution summed in f64, the obvious way.
    fn reference(x: &[f32], weight: &[f32], cout: usize, [b, cin, h, w]: [usize; 4]) -> Vec<f64> {
        let mut out = vec![0.0f64; b * cout * h * w];
        for n in 0..b {
            for o in 0..cout {
                for y in 0..h {
                    for xx in 0..w {
                        let mut s = 0.0f64;
                        for i in 0..cin {
                            for ky in 0..3 {
                                for kx in 0..3 {
                                    let (sy, sx) = (y + ky, xx + kx);
                                    if sy < 1 || sx < 1 || sy > h || sx > w {
                                        continue;
                                    }
                                    let v = x[((n * cin + i) * h + sy - 1) * w + sx - 1];
                                    s += weight[(o * cin + i) * 9 + ky * 3 + kx] as f64 * v as f64;
                                }
                            }
                        }
                        out[((n * cout + o) * h + y) * w + xx] = s;
                    }
                }
            }
        }
        out
    }

    // Sizes that reach every path: rows of one pixel, narrower than a tile, a whole block and
    // a block and a half; output channels under, at and past a tile's rows (3 as the network's
    // output layer); one row, one column.
    const CASES: [(usize, [usize; 4]); 7] = [
        (16, [1, 3, 8, 64]),
        (7, [2, 5, 9, 13]),
        (3, [1, 32, 6, 100]),
        (13, [1, 4, 5, 1]),
        (8, [2, 16, 1, 40]),
        (25, [1, 2, 3, 161]),
        (2, [1, 1, 1, 1]),
    ];

    #[test]
    fn the_convolution_matches_an_f64_sum() {
        for (k, &(cout, d)) in CASES.iter().enumerate() {
            let [b, cin, h, w] = d;
            let x = values(b * cin * h * w, 1 + k as u64);
            let weight = values(cout * cin * 9, 10 + k as u64);
            let err = rel_err(
                &dense3(&x, &weight, cout, d),
                &reference(&x, &weight, cout, d),
            );
            assert!(err < 1e-6, "{cout}x{d:?}: {err:.2e} of the scale");
        }
    }

    #[test]
    fn every_build_gives_the_portable_loops_bits() {
        for (k, &(cout, [b, cin, h, w])) in CASES.iter().enumerate() {
            let plane = h * w;
            let x = values(cin * plane, 60 + k as u64);
            let weight = values(cout * cin * 9, 70 + k as u64);
            let dims = Dims { cout, cin, h, w };
            let run = |isa: base::isa::Isa| -> Vec<u32> {
                let mut out = vec![f32::NAN; cout * plane];
                let buf = &mut vec![f32::NAN; 9 * cin * BLOCK];
                for y in 0..h {
                    let dst = Out(out[y * w..].as_mut_ptr());
                    // SAFETY: `out` holds the item's `cout` planes and each call owns its row
                    // of them; each build runs only where `Isa::available` lists it.
                    unsafe {
                        match isa {
                            #[cfg(target_arch = "x86_64")]
                            base::isa::Isa::Avx512 => row_avx512(dst, buf, &x, &weight, dims, y),
                            #[cfg(target_arch = "x86_64")]
                            base::isa::Isa::Avx2 => row_avx2(dst, buf, &x, &weight, dims, y),
                            _ => row_portable(dst, buf, &x, &weight, dims, y),
                        }
                    }
                }
                out.iter().map(|v| v.to_bits()).collect()
            };
            let portable = run(base::isa::Isa::Portable);
            assert!(
                portable.iter().all(|&v| f32::from_bits(v).is_finite()),
                "every value written"
            );
            for isa in base::isa::Isa::available() {
                assert_eq!(
                    run(isa),
                    portable,
                    "{isa:?}, {cout}x{cin}x{h}x{w} (item of {b})"
                );
            }
        }
    }

    #[test]
    fn empty_maps_give_empty_outputs() {
        for d in [[0, 3, 4, 4], [1, 3, 0, 4], [1, 3, 4, 0], [2, 0, 3, 3]] {
            let [b, cin, h, w] = d;
            let out = dense3(&vec![0.5; b * cin * h * w], &vec![0.25; 4 * cin * 9], 4, d);
            assert_eq!(out.len(), b * 4 * h * w, "{d:?}");
            assert!(
                out.iter().all(|&v| v == 0.0),
                "{d:?}: no input channel sums to zero"
            );
        }
    }
}
