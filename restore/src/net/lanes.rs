//! Row operations of the window attention kernels over rows padded to a multiple of 8.
//!
//! A key window holds 36 keys in `tiny` (25 or 30 at a map's edge). Over rows of such
//! lengths the compiler's vectorised loops (32 wide when unrolled) leave most of the work to
//! their scalar remainder, and a sum written as one running total (`iter().sum()`, a dot
//! product beside another update) is not vectorised at all: floating-point addition is not
//! associative, so the compiler keeps its order. Here every row is padded with zeros to a
//! multiple of 8 and worked in chunks of 8, and sums run in 8 lanes added together in a fixed
//! order at the end: each lane's order is written in the code, not chosen by the compiler, so
//! the portable and the AVX2 builds give the same bits.

/// Lanes per chunk: one AVX2 register of f32.
pub const LANES: usize = 8;

/// `n` rounded up to whole chunks.
#[inline(always)]
pub fn padded(n: usize) -> usize {
    n.next_multiple_of(LANES)
}

/// The 8 lanes added in a fixed order: pairwise, `((0+4)+(2+6)) + ((1+5)+(3+7))`.
#[inline(always)]
fn reduce(acc: [f32; LANES]) -> f32 {
    let a = [
        acc[0] + acc[4],
        acc[1] + acc[5],
        acc[2] + acc[6],
        acc[3] + acc[7],
    ];
    (a[0] + a[2]) + (a[1] + a[3])
}

/// `y += a·x` (rows of whole chunks).
#[inline(always)]
pub fn axpy(y: &mut [f32], a: f32, x: &[f32]) {
    for (yc, xc) in y
        .as_chunks_mut::<LANES>()
        .0
        .iter_mut()
        .zip(x.as_chunks::<LANES>().0)
    {
        let (mut t, xv) = (*yc, *xc);
        for l in 0..LANES {
            t[l] += a * xv[l];
        }
        *yc = t;
    }
}

/// `Σ x·y` in lanes.
#[inline(always)]
pub fn dot(x: &[f32], y: &[f32]) -> f32 {
    let mut acc = [0.0f32; LANES];
    for (xc, yc) in x
        .as_chunks::<LANES>()
        .0
        .iter()
        .zip(y.as_chunks::<LANES>().0)
    {
        let (xv, yv) = (*xc, *yc);
        for l in 0..LANES {
            acc[l] += xv[l] * yv[l];
        }
    }
    reduce(acc)
}

/// `y += a·x` and `Σ x·z` in one pass over `x`: the first attention backward's `dK += q·dS`
/// beside `dQ = dS·K`, kept for the reference that `net/window_train`'s tests compare the
/// kernel with ([`weighted_rows`] and [`dots`] took its place).
#[cfg(test)]
#[inline(always)]
pub(crate) fn axpy_dot(y: &mut [f32], a: f32, x: &[f32], z: &[f32]) -> f32 {
    let mut acc = [0.0f32; LANES];
    for ((yc, xc), zc) in y
        .as_chunks_mut::<LANES>()
        .0
        .iter_mut()
        .zip(x.as_chunks::<LANES>().0)
        .zip(z.as_chunks::<LANES>().0)
    {
        let (mut t, xv, zv) = (*yc, *xc, *zc);
        for l in 0..LANES {
            t[l] += a * xv[l];
            acc[l] += xv[l] * zv[l];
        }
        *yc = t;
    }
    reduce(acc)
}

/// Rows `out[r] = Σ_k a(r, k)·x[k]` over the rows `x[k]` (rows of `np`, whole chunks), each
/// summed from zero in `k` order: what [`axpy`] into a zeroed row gives, bit for bit, with the
/// row's chunks held in registers (up to four at a time) instead of loaded and stored once per
/// `k` (the attention backward's `dP = dO·Vᵀ`, `dV = Pᵀ·dO` and `dK = dSᵀ·Q`).
#[inline(always)]
pub fn weighted_rows(out: &mut [f32], np: usize, x: &[f32], a: impl Fn(usize, usize) -> f32) {
    let m = x.len() / np;
    let chunks = np / LANES;
    for (r, row) in out.chunks_exact_mut(np).enumerate() {
        let mut c0 = 0;
        while c0 < chunks {
            let t = (chunks - c0).min(4);
            let a = |k| a(r, k);
            match t {
                1 => row_tile::<1>(row, x, np, m, c0, a),
                2 => row_tile::<2>(row, x, np, m, c0, a),
                3 => row_tile::<3>(row, x, np, m, c0, a),
                _ => row_tile::<4>(row, x, np, m, c0, a),
            }
            c0 += t;
        }
    }
}

/// `T` chunks of one row of [`weighted_rows`] from chunk `c0`.
#[inline(always)]
fn row_tile<const T: usize>(
    row: &mut [f32],
    x: &[f32],
    np: usize,
    m: usize,
    c0: usize,
    a: impl Fn(usize) -> f32,
) {
    let mut acc = [[0.0f32; LANES]; T];
    for k in 0..m {
        let ak = a(k);
        let xs = x[k * np + c0 * LANES..][..T * LANES].as_chunks::<LANES>().0;
        for t in 0..T {
            let xv = xs[t];
            for l in 0..LANES {
                acc[t][l] += ak * xv[l];
            }
        }
    }
    for (o, v) in row[c0 * LANES..][..T * LANES]
        .as_chunks_mut::<LANES>()
        .0
        .iter_mut()
        .zip(acc)
    {
        *o = v;
    }
}

/// `[dot(x, rows[i]) for i in 0..D]` over the `D` rows of `rows` (each as long as `x`; `D` a
/// multiple of 4, as every head width the kernels serve): the same bits as [`dot`] row by row,
/// with `x` read once for eight rows (four when `D` is 4).
#[inline(always)]
pub fn dots<const D: usize>(x: &[f32], rows: &[f32]) -> [f32; D] {
    assert!(D.is_multiple_of(4), "rows in fours");
    let mut out = [0.0f32; D];
    if D.is_multiple_of(LANES) {
        for b in (0..D).step_by(LANES) {
            out[b..b + LANES].copy_from_slice(&dots_block::<LANES>(x, rows, b));
        }
    } else {
        for b in (0..D).step_by(4) {
            out[b..b + 4].copy_from_slice(&dots_block::<4>(x, rows, b));
        }
    }
    out
}

/// [`dots`] of rows `i0..i0 + B`.
#[inline(always)]
fn dots_block<const B: usize>(x: &[f32], rows: &[f32], i0: usize) -> [f32; B] {
    let chunks = x.len() / LANES;
    let rows = &rows.as_chunks::<LANES>().0[i0 * chunks..][..B * chunks];
    let mut acc = [[0.0f32; LANES]; B];
    for (c, xv) in x.as_chunks::<LANES>().0.iter().enumerate() {
        for (i, acc) in acc.iter_mut().enumerate() {
            let r = rows[i * chunks + c];
            for l in 0..LANES {
                acc[l] += xv[l] * r[l];
            }
        }
    }
    let mut out = [0.0f32; B];
    for (o, a) in out.iter_mut().zip(acc) {
        *o = reduce(a);
    }
    out
}

/// A softmax row in place: the first `n` entries are logits, the rest padding; afterwards
/// the padding is zero and the first `n` sum to 1. `exp` is the caller's (for `x ≤ 0`).
#[inline(always)]
pub fn softmax(row: &mut [f32], n: usize, exp: impl Fn(f32) -> f32) {
    let inv = exp_row(row, n, exp);
    for c in row.as_chunks_mut::<LANES>().0.iter_mut() {
        let mut v = *c;
        for e in v.iter_mut() {
            *e *= inv;
        }
        *c = v;
    }
}

/// [`softmax`] before its last step: the row holds `exp(logit − max)` (padding zero) and the
/// return value is the factor that normalises it, for callers that apply it later.
#[inline(always)]
pub fn exp_row(row: &mut [f32], n: usize, exp: impl Fn(f32) -> f32) -> f32 {
    row[n..].fill(f32::NEG_INFINITY);
    let mut top = [f32::NEG_INFINITY; LANES];
    for c in row.as_chunks::<LANES>().0 {
        let v = *c;
        for l in 0..LANES {
            // A plain comparison, one `vmaxps`, where `f32::max` cost a compare and a blend
            // more; the same result, as both keep `top` when `v` is NaN.
            top[l] = if v[l] > top[l] { v[l] } else { top[l] };
        }
    }
    let max = top.iter().fold(f32::NEG_INFINITY, |m, &t| m.max(t));
    for c in row.as_chunks_mut::<LANES>().0.iter_mut() {
        let mut v = *c;
        for e in v.iter_mut() {
            *e = exp(*e - max);
        }
        *c = v;
    }
    // The padding's `exp(−∞)` may be the caller's smallest value rather than 0.
    row[n..].fill(0.0);
    let mut acc = [0.0f32; LANES];
    for c in row.as_chunks::<LANES>().0 {
        let v = *c;
        for l in 0..LANES {
            acc[l] += v[l];
        }
    }
    1.0 / reduce(acc)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(n: usize, seed: u32) -> Vec<f32> {
        (0..n)
            .map(|i| (((i as u32).wrapping_mul(2_654_435_761) ^ seed) % 1000) as f32 / 100.0 - 5.0)
            .collect()
    }

    #[test]
    fn lane_sums_match_f64_sums() {
        for n in [8, 16, 40, 144] {
            let (x, y) = (row(n, 1), row(n, 7));
            let want: f64 = x.iter().zip(&y).map(|(&a, &b)| a as f64 * b as f64).sum();
            assert!((dot(&x, &y) as f64 - want).abs() < 1e-4 * want.abs().max(1.0));
            let mut acc = row(n, 3);
            let want_acc: Vec<f64> = acc
                .iter()
                .zip(&x)
                .map(|(&a, &b)| a as f64 + 0.5 * b as f64)
                .collect();
            let d = axpy_dot(&mut acc, 0.5, &x, &y);
            assert!((d as f64 - want).abs() < 1e-4 * want.abs().max(1.0));
            for (a, w) in acc.iter().zip(&want_acc) {
                assert!((*a as f64 - w).abs() < 1e-5);
            }
        }
    }

    /// The register-held rows and dots give the bits of the row-at-a-time loops they stand
    /// for, over rows of one to six chunks (every tile width and a remainder).
    #[test]
    fn weighted_rows_and_dots_are_the_plain_loops_bit_for_bit() {
        let bits = |x: &[f32]| x.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        for chunks in 1..=6 {
            let np = chunks * LANES;
            let (m, rows) = (5, 3);
            let x = row(m * np, 11);
            let a = row(rows * m, 13);
            let mut want = vec![0.0f32; rows * np];
            for (r, out) in want.chunks_exact_mut(np).enumerate() {
                for k in 0..m {
                    axpy(out, a[r * m + k], &x[k * np..][..np]);
                }
            }
            let mut got = vec![f32::NAN; rows * np];
            weighted_rows(&mut got, np, &x, |r, k| a[r * m + k]);
            assert_eq!(bits(&got), bits(&want), "{chunks} chunks");
            let y = row(np, 17);
            let rows8 = row(8 * np, 19);
            let want: Vec<f32> = rows8.chunks_exact(np).map(|r| dot(&y, r)).collect();
            assert_eq!(bits(&dots::<8>(&y, &rows8)), bits(&want));
            assert_eq!(bits(&dots::<4>(&y, &rows8[..4 * np])), bits(&want[..4]));
            let rows16 = [rows8.clone(), rows8].concat();
            let want16 = [want.clone(), want].concat();
            assert_eq!(bits(&dots::<16>(&y, &rows16)), bits(&want16));
        }
    }

    #[test]
    fn softmax_leaves_the_padding_out() {
        for n in [1, 5, 25, 30, 36] {
            let mut r = row(padded(n), 5);
            // Logits far below the padding's value: a padding that took part would show.
            r[..n].iter_mut().for_each(|v| *v -= 1000.0);
            let logits: Vec<f64> = r[..n].iter().map(|&v| v as f64).collect();
            softmax(&mut r, n, |x| x.exp());
            let max = logits.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
            let total: f64 = logits.iter().map(|l| (l - max).exp()).sum();
            for (p, l) in r.iter().zip(&logits) {
                assert!((*p as f64 - (l - max).exp() / total).abs() < 1e-6);
            }
            assert!(r[n..].iter().all(|&p| p == 0.0));
        }
    }
}
