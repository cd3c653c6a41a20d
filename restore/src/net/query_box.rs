//! Query enhancement `Q − AvgPool_k(Q)` straight from the planes, on the CPU.
//!
//! burn's average pool visits every output through generic index arithmetic (a quarter of a
//! `tiny` 512² forward pass went there, two pools per enhanced block, and their backward a
//! good part of a training step). Here each plane is summed along its rows, then down its
//! columns, `k` shifted slice additions each, which vectorise; the sums are direct (no
//! running sum), so no error builds up along a row.
//!
//! The zero-padded box mean is a symmetric operator, so `x − box(x)` is its own adjoint: the
//! input gradient is the same kernel applied to the output gradient. Registered with burn as
//! a backend extension ([`EnhanceOps`]), autodiff records it as one node; it stands in only
//! on burn's CPU backend, under autodiff or not.

use super::kernels::{flex_dims, flex_slice};
use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops};
use burn::backend::flex::FlexTensor;
use burn::backend::{Autodiff, Backend, Dispatch, Flex, backend_extension, tensor::FloatTensor};
use burn::tensor::{Tensor, TensorData};

/// `x`: planes of `h × w`, one after another; `k` odd → `x − AvgPool_k(x)` with stride 1 and
/// zero padding counted in the mean (divided by `k²` everywhere), as
/// [`super::layers::enhance_query`].
pub fn enhance(x: &[f32], k: usize, h: usize, w: usize) -> Vec<f32> {
    assert!(k % 2 == 1, "an odd box, not {k}");
    let plane = h * w;
    if plane == 0 {
        return vec![0.0f32; x.len()];
    }
    assert_eq!(x.len() % plane, 0, "planes of {h}x{w}");
    super::fresh::filled(x.len(), plane, |i, dst| {
        plane_task(dst, &x[i * plane..][..plane], k, h, w)
    })
}

/// One plane `src` (`h × w`) enhanced into `dst`, every value written (`k` odd).
pub(super) fn plane_task(dst: &mut [f32], src: &[f32], k: usize, h: usize, w: usize) {
    #[cfg(target_arch = "x86_64")]
    if base::isa::Isa::chosen() != base::isa::Isa::Portable {
        // SAFETY: `Isa::chosen` names a build the CPU has, and every build past the
        // portable one has AVX2.
        return unsafe { plane_avx2(dst, src, k, h, w) };
    }
    plane_body(dst, src, k, h, w)
}

/// The same code compiled for AVX2 (no multiply-add contracted: the portable build's bits).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn plane_avx2(dst: &mut [f32], src: &[f32], k: usize, h: usize, w: usize) {
    plane_body(dst, src, k, h, w)
}

#[inline(always)]
fn plane_body(dst: &mut [f32], src: &[f32], k: usize, h: usize, w: usize) {
    let r = (k / 2) as isize;
    // Row sums of the whole plane, then column sums of those, row by row.
    let mut rows = vec![0.0f32; h * w];
    for (sum, row) in rows.chunks_exact_mut(w).zip(src.chunks_exact(w)) {
        for d in -r..=r {
            // sum[x] += row[x + d] where x + d is inside the row.
            let lo = (-d).clamp(0, w as isize) as usize;
            let hi = (w as isize - d).clamp(lo as isize, w as isize) as usize;
            if hi == lo {
                continue; // the shift is wider than the row
            }
            let shifted = &row[(lo as isize + d) as usize..][..hi - lo];
            for (s, &v) in sum[lo..hi].iter_mut().zip(shifted) {
                *s += v;
            }
        }
    }
    let inv = 1.0 / (k * k) as f32;
    let mut acc = vec![0.0f32; w];
    for y in 0..h {
        acc.fill(0.0);
        let top = (y as isize - r).max(0) as usize;
        let bottom = ((y as isize + r) as usize).min(h - 1);
        for sum in rows[top * w..(bottom + 1) * w].chunks_exact(w) {
            for (a, &s) in acc.iter_mut().zip(sum) {
                *a += s;
            }
        }
        let q = &src[y * w..][..w];
        for ((o, &v), &a) in dst[y * w..][..w].iter_mut().zip(q).zip(&acc) {
            *o = v - a * inv;
        }
    }
}

/// `q − AvgPool_k(q)` through [`EnhanceOps`] (`k` odd; `q` on burn's CPU backend).
pub fn enhance_tensor(q: Tensor<4>, k: usize) -> Tensor<4> {
    Tensor::<4>::from_dispatch(<Dispatch as EnhanceOps>::enhance(q.into_dispatch(), k))
}

#[backend_extension(Flex, Autodiff)]
pub trait EnhanceOps: Backend {
    /// `x: [b, c, h, w]` → `x − AvgPool_k(x)`, the same shape.
    fn enhance(x: FloatTensor<Self>, k: usize) -> FloatTensor<Self>;
}

impl EnhanceOps for Flex {
    fn enhance(x: FlexTensor, k: usize) -> FlexTensor {
        let x = x.to_contiguous();
        let dims = flex_dims::<4>(&x);
        FlexTensor::from_data(TensorData::new(
            enhance(flex_slice(&x), k, dims[2], dims[3]),
            dims,
        ))
    }
}

#[derive(Debug)]
struct EnhanceBackward {
    k: usize,
}

impl<B: Backend + EnhanceOps> Backward<B, 1> for EnhanceBackward {
    type State = ();

    fn backward(self, ops: Ops<(), 1>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [parent] = ops.parents;
        let dy = grads.consume::<B>(&ops.node);
        if let Some(node) = parent {
            grads.register::<B>(node.id, B::enhance(dy, self.k));
        }
    }
}

impl<B: Backend + EnhanceOps, C: CheckpointStrategy> EnhanceOps for Autodiff<B, C> {
    fn enhance(x: FloatTensor<Self>, k: usize) -> FloatTensor<Self> {
        let node = x.node();
        let y = B::enhance(x.into_primitive(), k);
        EnhanceBackward { k }
            .prepare::<C>([node])
            .compute_bound()
            .stateless(y)
    }
}
