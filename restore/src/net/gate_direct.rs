//! The GDFN's middle for CPU inference, `GELU(DW(x₁)) ⊙ DW(x₂)`, in one pass.
//!
//! As tensors it is four passes over the widest maps of the network (the depthwise
//! convolution's output, its two halves, the GELU and the product, each a new tensor of
//! the hidden width); here each output plane is made from its two input planes while they
//! are in cache. It has no gradient: training takes the tensor formulation.

use super::conv_train::depthwise_row;
use super::fresh;
use super::gelu::gelu;

/// `x: [b, 2·hid, h, w]` (the GDFN's first projection), `weight: [2·hid, 1, 3, 3]` (its
/// depthwise 3×3 kernels, zero padding) → `[b, hid, h, w]`: channel `i` is
/// `GELU(dw_i(x_i)) · dw_{hid+i}(x_{hid+i})`.
pub fn gated_depthwise(x: &[f32], weight: &[f32], [b, c2, h, w]: [usize; 4]) -> Vec<f32> {
    let hid = c2 / 2;
    let plane = h * w;
    fresh::filled(b * hid * plane, plane, |task, dst| {
        let (n, i) = (task / hid, task % hid);
        let src = |ch: usize| &x[(n * c2 + ch) * plane..][..plane];
        let kernel = |ch: usize| -> &[f32; 9] { weight[ch * 9..][..9].try_into().unwrap() };
        plane_task(
            dst,
            (src(i), kernel(i)),
            (src(hid + i), kernel(hid + i)),
            h,
            w,
        );
    })
}

type Plane<'a> = (&'a [f32], &'a [f32; 9]);

fn plane_task(dst: &mut [f32], a: Plane, g: Plane, h: usize, w: usize) {
    #[cfg(target_arch = "x86_64")]
    if base::isa::Isa::chosen() != base::isa::Isa::Portable {
        // SAFETY: `Isa::chosen` names a build the CPU has, and every build past the
        // portable one has AVX2 (the project's one dispatcher, so `METASPLAT_NO_AVX2` holds
        // here too).
        return unsafe { plane_avx2(dst, a, g, h, w) };
    }
    plane_body(dst, a, g, h, w)
}

/// The same code compiled for AVX2 (no multiply-add contracted: the portable build's bits).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn plane_avx2(dst: &mut [f32], a: Plane, g: Plane, h: usize, w: usize) {
    plane_body(dst, a, g, h, w)
}

#[inline(always)]
fn plane_body(dst: &mut [f32], a: Plane, g: Plane, h: usize, w: usize) {
    let mut ra = vec![0.0f32; w];
    let mut rg = vec![0.0f32; w];
    for y in 0..h {
        depthwise_row(&mut ra, a.0, a.1, y, h, w);
        depthwise_row(&mut rg, g.0, g.1, y, h, w);
        for ((o, &u), &v) in dst[y * w..][..w].iter_mut().zip(&ra).zip(&rg) {
            *o = gelu(u) * v;
        }
    }
}
