//! Windowed attention read straight from the feature maps, for inference on the CPU.
//!
//! The tensor formulation ([`super::window::attend_fused`]) first copies every overlapping
//! key window out of the map, splits heads, repeats the MAFG query for each filter and merges
//! the windows back: with a few channels per head those copies cost more than the attention.
//! This kernel gathers each window's queries, keys and values into small buffers as it goes
//! and writes its answer into the output map, so nothing the size of the map is made but
//! the output. Training runs it too, with a hand-written backward (`net/window_train`).

use super::lanes;
use rayon::prelude::*;

/// Sizes and extra terms of one windowed attention.
pub struct WindowSpec<'a> {
    pub heads: usize,
    /// Query window side.
    pub win: usize,
    /// Key window side (centred on the query window, `kwin − win` even).
    pub kwin: usize,
    /// Query maps are shared: output map `g` takes its queries from query map `g / share`.
    pub share: usize,
    /// `[win², channels]` added to the queries by position in their window.
    pub pos_q: Option<&'a [f32]>,
    /// `[kwin², channels]` added to the keys by position in their window.
    pub pos_k: Option<&'a [f32]>,
    /// `[heads, win², kwin²]` logits added by (query, key) position.
    pub bias: Option<&'a [f32]>,
}

/// Channels per head the kernel is built for (the configs use 8 and 16).
pub fn head_dim_supported(d: usize) -> bool {
    matches!(d, 4 | 8 | 16 | 32)
}

/// `q: [g / share, c, h, w]`, `k, v: [g, c, h, w]` → `[g, c, h, w]`: every query attends, per
/// head, to the keys of the `kwin` window around its `win` window that lie inside the image
/// (keys outside are left out, which the tensor form does with a logit whose `exp` is 0).
/// `None` for a head width [`head_dim_supported`] refuses.
pub fn attend_maps(
    q: &[f32],
    k: &[f32],
    v: &[f32],
    dims: [usize; 3],
    s: &WindowSpec,
) -> Option<Vec<f32>> {
    attend(q, k, v, dims, s, false).map(|(out, _)| out)
}

/// [`attend_maps`], also keeping the softmax of every window and head for a backward pass
/// (`net/window_train`), which then need not compute it again: one `Vec` per strip of window
/// rows (the kernel's task), `[windows in the row, heads, win², padded(kwin²)]`, keys in the
/// order of the window's keys inside the image, zeros after them.
pub fn attend_maps_keeping(
    q: &[f32],
    k: &[f32],
    v: &[f32],
    dims: [usize; 3],
    s: &WindowSpec,
) -> Option<(Vec<f32>, Vec<Vec<f32>>)> {
    attend(q, k, v, dims, s, true)
}

fn attend(
    q: &[f32],
    k: &[f32],
    v: &[f32],
    [c, h, w]: [usize; 3],
    s: &WindowSpec,
    keep: bool,
) -> Option<(Vec<f32>, Vec<Vec<f32>>)> {
    let d = c / s.heads;
    let z = Sizes { c, h, w };
    Some(match d {
        4 => run::<4>(q, k, v, z, s, keep),
        8 => run::<8>(q, k, v, z, s, keep),
        16 => run::<16>(q, k, v, z, s, keep),
        32 => run::<32>(q, k, v, z, s, keep),
        _ => return None,
    })
}

#[derive(Clone, Copy)]
struct Sizes {
    c: usize,
    h: usize,
    w: usize,
}

fn run<const D: usize>(
    q: &[f32],
    k: &[f32],
    v: &[f32],
    z: Sizes,
    s: &WindowSpec,
    keep: bool,
) -> (Vec<f32>, Vec<Vec<f32>>) {
    let Sizes { c, h, w } = z;
    let plane = h * w;
    let groups = k.len() / (c * plane);
    let nh = h / s.win;
    // One strip of window rows per task: `[c, win, w]` of one output map.
    let (strips, kept): (Vec<Vec<f32>>, Vec<Vec<f32>>) = (0..groups * nh)
        .into_par_iter()
        .map(|task| strip::<D>(task, q, k, v, z, s, keep))
        .unzip();
    let mut out = vec![0.0f32; groups * c * plane];
    for (task, strip) in strips.iter().enumerate() {
        let (g, wy) = (task / nh, task % nh);
        for ch in 0..c {
            let dst = &mut out[(g * c + ch) * plane + wy * s.win * w..][..s.win * w];
            dst.copy_from_slice(&strip[ch * s.win * w..][..s.win * w]);
        }
    }
    (out, kept)
}

/// One task's strip, in the build for the CPU at hand.
fn strip<const D: usize>(
    task: usize,
    q: &[f32],
    k: &[f32],
    v: &[f32],
    z: Sizes,
    s: &WindowSpec,
    keep: bool,
) -> (Vec<f32>, Vec<f32>) {
    #[cfg(target_arch = "x86_64")]
    if base::isa::Isa::chosen() != base::isa::Isa::Portable {
        // SAFETY: `Isa::chosen` names a build the CPU has, and every build past the
        // portable one has AVX2 (the project's one dispatcher, so `METASPLAT_NO_AVX2` holds
        // here too).
        return unsafe { strip_avx2::<D>(task, q, k, v, z, s, keep) };
    }
    strip_body::<D>(task, q, k, v, z, s, keep)
}

/// The same code compiled for AVX2: the loops over keys and channels become 8-wide. No
/// multiply-add is contracted, so it gives the portable build's bits.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn strip_avx2<const D: usize>(
    task: usize,
    q: &[f32],
    k: &[f32],
    v: &[f32],
    z: Sizes,
    s: &WindowSpec,
    keep: bool,
) -> (Vec<f32>, Vec<f32>) {
    strip_body::<D>(task, q, k, v, z, s, keep)
}

#[inline(always)]
fn strip_body<const D: usize>(
    task: usize,
    q: &[f32],
    k: &[f32],
    v: &[f32],
    z: Sizes,
    s: &WindowSpec,
    keep: bool,
) -> (Vec<f32>, Vec<f32>) {
    let Sizes { c, h, w } = z;
    let plane = h * w;
    let (nh, nw) = (h / s.win, w / s.win);
    let (lq, lk) = (s.win * s.win, s.kwin * s.kwin);
    let pad = (s.kwin - s.win) / 2;
    let scale = (D as f32).powf(-0.5);
    let (g, wy) = (task / nh, task % nh);
    let qmap = &q[(g / s.share) * c * plane..][..c * plane];
    let kmap = &k[g * c * plane..][..c * plane];
    let vmap = &v[g * c * plane..][..c * plane];
    let mut strip = vec![0.0f32; c * s.win * w];
    let mut qb = vec![[0.0f32; D]; lq];
    // Keys transposed, `[D, np]`, so the logits accumulate along contiguous keys, in chunks
    // of 8 over rows padded with zeros ([`super::lanes`]).
    let lkp = lanes::padded(lk);
    let mut kt = vec![0.0f32; D * lkp];
    let mut vb = vec![[0.0f32; D]; lk];
    let mut inside: Vec<(usize, usize)> = Vec::with_capacity(lk);
    let mut logits = vec![0.0f32; lq * lkp];
    let mut invs = vec![0.0f32; lq];
    let mut kept = vec![0.0f32; if keep { nw * s.heads * lq * lkp } else { 0 }];
    // The strip's rows of one head's channels, copied out of the maps before its windows
    // read them: the maps' planes lie a megabyte apart, so gathering a window's pixels
    // straight from them put every channel in the same cache sets and most loads missed.
    // Keys and queries stay a plane per channel (`[D, rows, w]`), values go pixel-major
    // (`[rows · w, D]`) so a key's values are one load.
    let y0 = wy * s.win;
    let (ylo, yhi) = (y0.saturating_sub(pad), (y0 + s.win + pad).min(h));
    let rows = yhi - ylo;
    let mut ks = vec![0.0f32; D * rows * w];
    let mut qs = vec![0.0f32; D * s.win * w];
    let mut vs = vec![[0.0f32; D]; rows * w];
    for head in 0..s.heads {
        let ch0 = head * D;
        for i in 0..D {
            let ch = ch0 + i;
            // Rows `from..from + n` of channel `ch`'s plane.
            let span = |from: usize, n: usize| ch * plane + from * w..ch * plane + (from + n) * w;
            ks[i * rows * w..][..rows * w].copy_from_slice(&kmap[span(ylo, rows)]);
            qs[i * s.win * w..][..s.win * w].copy_from_slice(&qmap[span(y0, s.win)]);
            for (dst, &x) in vs.iter_mut().zip(&vmap[span(ylo, rows)]) {
                dst[i] = x;
            }
        }
        for wx in 0..nw {
            let x0 = wx * s.win;
            inside.clear();
            for ky in 0..s.kwin {
                for kx in 0..s.kwin {
                    let y = (y0 + ky) as isize - pad as isize;
                    let x = (x0 + kx) as isize - pad as isize;
                    if (0..h as isize).contains(&y) && (0..w as isize).contains(&x) {
                        inside.push((ky * s.kwin + kx, (y as usize - ylo) * w + x as usize));
                    }
                }
            }
            let n = inside.len();
            let np = lanes::padded(n);
            for i in 0..D {
                let ch = ch0 + i;
                let qp = &qs[i * s.win * w..][..s.win * w];
                for qy in 0..s.win {
                    for qx in 0..s.win {
                        let qi = qy * s.win + qx;
                        let pos = s.pos_q.map_or(0.0, |p| p[qi * c + ch]);
                        qb[qi][i] = (qp[qy * w + x0 + qx] + pos) * scale;
                    }
                }
                let kp = &ks[i * rows * w..][..rows * w];
                let krow = &mut kt[i * np..][..np];
                for (j, &(kj, px)) in inside.iter().enumerate() {
                    krow[j] = kp[px] + s.pos_k.map_or(0.0, |p| p[kj * c + ch]);
                }
                krow[n..].fill(0.0);
            }
            for (dst, &(_, px)) in vb.iter_mut().zip(&inside) {
                *dst = vs[px];
            }
            let logits = &mut logits[..lq * np];
            let bias = s.bias.map(|b| &b[head * lq * lk..][..lq * lk]);
            let slots = inside.iter().map(|&(kj, _)| kj);
            logit_rows(logits, slots, n, bias, &qb, &kt[..D * np]);
            for (qi, inv) in invs.iter_mut().enumerate() {
                let row = &mut logits[qi * np..][..np];
                *inv = lanes::exp_row(row, n, exp_nonpositive);
                if keep {
                    // As `lanes::softmax` normalises: the same bits.
                    let dst = &mut kept[((wx * s.heads + head) * lq + qi) * lkp..][..np];
                    for (d, &e) in dst.iter_mut().zip(row.iter()) {
                        *d = e * *inv;
                    }
                }
            }
            // `P·V`, four queries at a time: each query's sum still runs over its keys in
            // order (the bits of one at a time), but four independent chains of adds overlap
            // where one would wait on each add.
            let mut qi = 0;
            while qi < lq {
                let r = (lq - qi).min(QUERIES);
                let acc = weighted_values::<D>(&logits[qi * np..][..r * np], np, &vb[..n]);
                for (a, q) in acc[..r].iter().zip(qi..) {
                    let (qy, qx) = (q / s.win, q % s.win);
                    for (i, a) in a.iter().enumerate() {
                        strip[((ch0 + i) * s.win + qy) * w + x0 + qx] = a * invs[q];
                    }
                }
                qi += r;
            }
        }
    }
    (strip, kept)
}

/// Queries whose `P·V` sums run side by side.
const QUERIES: usize = 4;

/// `Σⱼ pⱼ vⱼ` for up to [`QUERIES`] rows of `p` (`rows`: `r` rows of stride `np`) over the
/// keys' values `vb`, each row's sum in key order.
#[inline(always)]
fn weighted_values<const D: usize>(
    rows: &[f32],
    np: usize,
    vb: &[[f32; D]],
) -> [[f32; D]; QUERIES] {
    let r = rows.len().div_ceil(np);
    let mut acc = [[0.0f32; D]; QUERIES];
    let n = vb.len();
    if r == QUERIES {
        // Four named rows and sums, so they stay in registers.
        let (p0, p1, p2, p3) = (
            &rows[..n],
            &rows[np..][..n],
            &rows[2 * np..][..n],
            &rows[3 * np..][..n],
        );
        let (mut a0, mut a1, mut a2, mut a3) = ([0.0f32; D], [0.0f32; D], [0.0f32; D], [0.0f32; D]);
        for j in 0..n {
            let v = vb[j];
            let (x0, x1, x2, x3) = (p0[j], p1[j], p2[j], p3[j]);
            for i in 0..D {
                a0[i] += x0 * v[i];
                a1[i] += x1 * v[i];
                a2[i] += x2 * v[i];
                a3[i] += x3 * v[i];
            }
        }
        acc = [a0, a1, a2, a3];
    } else {
        for (q, a) in acc[..r].iter_mut().enumerate() {
            for (p, v) in rows[q * np..][..n].iter().zip(vb) {
                for (a, v) in a.iter_mut().zip(v) {
                    *a += p * v;
                }
            }
        }
    }
    acc
}

/// One window's and head's logits, `[lq, np]` rows for its `n` keys padded to `np`: the
/// position logits of the keys' slots (`bias`: this head's `[lq, kwin²]`) or zeros, plus
/// `q·k` (`qb`: scaled queries; `kt`: keys transposed, `[D, np]`, zero padding). The
/// backward (`net/window_train`) computes them through this too, so both get the same bits.
#[inline(always)]
pub(super) fn logit_rows<const D: usize>(
    rows: &mut [f32],
    slots: impl Iterator<Item = usize> + Clone,
    n: usize,
    bias: Option<&[f32]>,
    qb: &[[f32; D]],
    kt: &[f32],
) {
    let np = rows.len() / qb.len();
    match bias {
        Some(b) => {
            let lk = b.len() / qb.len();
            for (qi, row) in rows.chunks_exact_mut(np).enumerate() {
                if n == lk {
                    // A window inside the map: its keys are every slot in order, so the
                    // row is copied, not gathered (a tenth of the kernel's time when it was).
                    row[..n].copy_from_slice(&b[qi * lk..][..lk]);
                } else {
                    for (l, slot) in row.iter_mut().zip(slots.clone()) {
                        *l = b[qi * lk + slot];
                    }
                }
                row[n..].fill(0.0);
            }
        }
        None => rows.fill(0.0),
    }
    for (i, krow) in kt.chunks_exact(np).enumerate() {
        for (row, q) in rows.chunks_exact_mut(np).zip(qb) {
            lanes::axpy(row, q[i], krow);
        }
    }
}

/// `eᵡ` for `x ≤ 0` without a library call, so the softmax loop vectorises: `x = n·ln 2 + r`
/// with `|r| ≤ ln 2 / 2`, Cephes' degree-6 polynomial for `eʳ`, `2ⁿ` from the exponent bits.
/// Below −87 it returns `e⁻⁸⁷` (≈ 1.6e-38), which next to the row's maximum (whose term
/// is 1) is below f32 resolution, as is every such term in the exact softmax.
#[inline(always)]
pub fn exp_nonpositive(x: f32) -> f32 {
    const LOG2E: f32 = std::f32::consts::LOG2_E;
    // ln 2 split so that `n · LN2_HI` is exact.
    const LN2_HI: f32 = 0.693_359_4;
    const LN2_LO: f32 = -2.121_944_4e-4;
    let x = x.max(-87.0);
    let n = (x * LOG2E + 0.5).floor();
    let r = x - n * LN2_HI - n * LN2_LO;
    let p = ((((1.987_569_1e-4 * r + 1.398_199_9e-3) * r + 8.333_452e-3) * r + 4.166_579_6e-2) * r
        + 1.666_666_5e-1)
        * r
        + 0.5;
    let e = p * r * r + r + 1.0;
    pow2(n) * e
}

/// `2ⁿ` for a whole number `n` in [−126, 127] (here −125 to 0, for `x` in [−87, 0]): added
/// to 2²³, `n + 127` lands in the low mantissa bits and is read back as an integer, with no
/// float-to-integer conversion (whose saturating form the compiler does not vectorise: with
/// one, the softmax's exponentials went a lane at a time).
#[inline(always)]
fn pow2(n: f32) -> f32 {
    const MAGIC: f32 = 8_388_608.0;
    let biased = (n + 127.0 + MAGIC).to_bits().wrapping_sub(MAGIC.to_bits());
    f32::from_bits(biased << 23)
}

#[cfg(test)]
mod tests {
    use super::{exp_nonpositive, pow2};

    #[test]
    fn pow2_is_exact_over_the_normal_exponents() {
        for n in -126..=127 {
            assert_eq!(pow2(n as f32), 2f32.powi(n), "2^{n}");
        }
    }

    #[test]
    fn exp_nonpositive_is_within_a_few_ulp_of_f64_exp() {
        let mut worst = 0.0f64;
        for i in 0..=200_000 {
            let x = -87.0 * i as f64 / 200_000.0;
            let got = f64::from(exp_nonpositive(x as f32));
            let want = (x as f32 as f64).exp();
            worst = worst.max((got - want).abs() / want);
        }
        assert!(worst < 5e-7, "worst relative error {worst:.2e}");
        assert_eq!(exp_nonpositive(0.0), 1.0);
        // Far below: a positive number too small to matter beside 1, never NaN or negative.
        let tiny = exp_nonpositive(-1e4);
        assert!((0.0..1e-37).contains(&tiny));
        assert!(exp_nonpositive(f32::NEG_INFINITY) < 1e-37);
    }
}
