//! LayerNorm over the channels of every pixel for CPU inference, in two passes.
//!
//! As tensors ([`super::layers::ChannelNorm`]) it is nine passes over the map, each making a
//! new tensor (mean, centred, square, mean, add, root, divide, scale, shift): four times per
//! STAF block. Here one pass over strips of pixels finds each pixel's mean and inverse
//! deviation (the strip's channels stay in cache for the second, centred sum), and one pass
//! over the output planes writes `(x − mean) · rstd · γ + β`. The variance is the centred
//! one, as in the tensor form. It has no gradient: training takes the tensor formulation.

use rayon::prelude::*;

/// Pixels per task of the moments pass: with 64 channels its strip is 64 KiB.
const STRIP: usize = 256;

/// `x: [b, c, h, w]`, `weight`, `bias`: `[c]` → the normalised map, `[b, c, h, w]`.
pub fn channel_norm(
    x: &[f32],
    weight: &[f32],
    bias: &[f32],
    eps: f32,
    [b, c, h, w]: [usize; 4],
) -> Vec<f32> {
    let plane = h * w;
    assert_eq!(x.len(), b * c * plane, "map of {b}x{c}x{h}x{w}");
    assert!(weight.len() == c && bias.len() == c, "{c} channels");
    if b * c * plane == 0 {
        return Vec::new();
    }
    // Per pixel: (mean, 1/sqrt(var + eps)), batch item by batch item, strip by strip.
    let mut mean = vec![0.0f32; b * plane];
    let mut rstd = vec![0.0f32; b * plane];
    mean.par_chunks_mut(plane)
        .zip(rstd.par_chunks_mut(plane))
        .enumerate()
        .for_each(|(n, (m, r))| {
            let item = &x[n * c * plane..][..c * plane];
            m.par_chunks_mut(STRIP)
                .zip(r.par_chunks_mut(STRIP))
                .enumerate()
                .for_each(|(s, (m, r))| moments(m, r, item, c, plane, s * STRIP, eps));
        });
    let mut out = vec![0.0f32; b * c * plane];
    out.par_chunks_mut(plane)
        .enumerate()
        .for_each(|(task, dst)| {
            let (n, ch) = (task / c, task % c);
            let src = &x[(n * c + ch) * plane..][..plane];
            let stats = (&mean[n * plane..][..plane], &rstd[n * plane..][..plane]);
            apply(dst, src, stats, weight[ch], bias[ch]);
        });
    out
}

fn moments(
    m: &mut [f32],
    r: &mut [f32],
    item: &[f32],
    c: usize,
    plane: usize,
    p0: usize,
    eps: f32,
) {
    #[cfg(target_arch = "x86_64")]
    if base::isa::Isa::chosen() != base::isa::Isa::Portable {
        // SAFETY: `Isa::chosen` names a build the CPU has, and every build past the
        // portable one has AVX2.
        return unsafe { moments_avx2(m, r, item, c, plane, p0, eps) };
    }
    moments_body(m, r, item, c, plane, p0, eps)
}

fn apply(dst: &mut [f32], src: &[f32], stats: (&[f32], &[f32]), g: f32, b: f32) {
    #[cfg(target_arch = "x86_64")]
    if base::isa::Isa::chosen() != base::isa::Isa::Portable {
        // SAFETY: as in `moments`.
        return unsafe { apply_avx2(dst, src, stats, g, b) };
    }
    apply_body(dst, src, stats, g, b)
}

/// The same code compiled for AVX2 (no multiply-add contracted: the portable build's bits).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn moments_avx2(
    m: &mut [f32],
    r: &mut [f32],
    item: &[f32],
    c: usize,
    plane: usize,
    p0: usize,
    eps: f32,
) {
    moments_body(m, r, item, c, plane, p0, eps)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn apply_avx2(dst: &mut [f32], src: &[f32], stats: (&[f32], &[f32]), g: f32, b: f32) {
    apply_body(dst, src, stats, g, b)
}

#[inline(always)]
fn moments_body(
    m: &mut [f32],
    r: &mut [f32],
    item: &[f32],
    c: usize,
    plane: usize,
    p0: usize,
    eps: f32,
) {
    let n = m.len();
    let strip = |ch: usize| &item[ch * plane + p0..][..n];
    m.fill(0.0);
    for ch in 0..c {
        for (s, &v) in m.iter_mut().zip(strip(ch)) {
            *s += v;
        }
    }
    let inv_c = 1.0 / c as f32;
    m.iter_mut().for_each(|s| *s *= inv_c);
    r.fill(0.0);
    for ch in 0..c {
        for ((s, &v), &mu) in r.iter_mut().zip(strip(ch)).zip(m.iter()) {
            let d = v - mu;
            *s += d * d;
        }
    }
    r.iter_mut()
        .for_each(|s| *s = 1.0 / (*s * inv_c + eps).sqrt());
}

#[inline(always)]
fn apply_body(dst: &mut [f32], src: &[f32], (mean, rstd): (&[f32], &[f32]), g: f32, b: f32) {
    for (((o, &v), &mu), &rs) in dst.iter_mut().zip(src).zip(mean).zip(rstd) {
        *o = (v - mu) * rs * g + b;
    }
}
