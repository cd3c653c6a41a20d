//! The GDFN's middle, `GELU(DW(x₁)) ⊙ DW(x₂)`, for training on the CPU: one autodiff node
//! with a hand-written backward.
//!
//! As tensors under autodiff it is five nodes over the widest maps of the network (the
//! depthwise convolution, the two halves of its output, the GELU, the product): the halves
//! are copied to be dense for the GELU, the product's backward makes two maps and the split's
//! backward copies them into a zeroed map of twice the width. Here the forward keeps the
//! depthwise output `d` and makes the gated map in one pass over it; the backward makes
//! `∂d` in one pass (`∂d₁ = ∂y · d₂ · GELU′(d₁)`, `∂d₂ = ∂y · GELU(d₁)`) and hands it to the
//! depthwise kernels of [`super::conv_train`]. The forward's values are those of
//! [`super::gate_direct`] (the same row kernel and GELU), bit for bit. Registered with burn
//! as a backend extension ([`GateTrainOps`]) for burn's CPU backend under autodiff.

use super::conv_train::{DepthwiseOps, forward as depthwise_forward, tensor, values};
use super::gate_direct::gated_depthwise;
use super::gelu::{gelu, gelu_slope};
use super::kernels::flex_slice;
use burn::backend::autodiff::NodeId;
use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::flex::FlexTensor;
use burn::backend::{Autodiff, Backend, Dispatch, Flex, backend_extension, tensor::FloatTensor};
use burn::nn::conv::Conv2d;
use burn::tensor::Tensor;
use rayon::prelude::*;
use std::sync::Arc;

/// `GELU(DW(h₁)) ⊙ DW(h₂)` for the GDFN's projected map `h: [b, 2·hid, h, w]` and its
/// depthwise layer `conv` (no bias) → `[b, hid, h, w]`, through [`GateTrainOps`] (a tensor
/// under autodiff on burn's CPU backend: `conv_train::trained_applies`).
pub fn gated_tensor(conv: &Conv2d, h: Tensor<4>) -> Tensor<4> {
    debug_assert!(
        conv.bias.is_none(),
        "the GDFN's depthwise layer has no bias"
    );
    Tensor::<4>::from_dispatch(<Dispatch as GateTrainOps>::gated_depthwise3(
        h.into_dispatch(),
        conv.weight.val().into_dispatch(),
    ))
}

#[backend_extension(Flex, Autodiff)]
pub trait GateTrainOps: Backend {
    /// `x: [b, 2·hid, h, w]`, `weight: [2·hid, 1, 3, 3]` → `[b, hid, h, w]`.
    fn gated_depthwise3(x: FloatTensor<Self>, weight: FloatTensor<Self>) -> FloatTensor<Self>;
}

impl GateTrainOps for Flex {
    fn gated_depthwise3(x: FlexTensor, weight: FlexTensor) -> FlexTensor {
        let (x, [b, c2, h, w]) = values(x);
        let (weight, _) = values(weight);
        let y = gated_depthwise(flex_slice(&x), flex_slice(&weight), [b, c2, h, w]);
        tensor(y, [b, c2 / 2, h, w])
    }
}

/// Plane `i` of the gated map from the depthwise output `d: [b, 2·hid, h, w]`, or with `dy`
/// the two planes of `∂d` it feeds. Per output plane: `(b, i)`.
fn pair_planes<'a>(
    d: &'a [f32],
    [b, c2, h, w]: [usize; 4],
) -> impl Fn(usize) -> (&'a [f32], &'a [f32]) {
    let (hid, plane) = (c2 / 2, h * w);
    debug_assert_eq!(d.len(), b * c2 * plane);
    move |task| {
        let (n, i) = (task / hid, task % hid);
        (
            &d[(n * c2 + i) * plane..][..plane],
            &d[(n * c2 + hid + i) * plane..][..plane],
        )
    }
}

/// `GELU(d₁) · d₂`, plane by plane.
fn gate(d: &[f32], dims: [usize; 4]) -> Vec<f32> {
    let [b, c2, h, w] = dims;
    let plane = h * w;
    if plane == 0 {
        return vec![0.0; b * c2 / 2 * plane];
    }
    let planes = pair_planes(d, dims);
    // Every value of every plane is written: no zeros first (`fresh`).
    super::fresh::filled(b * c2 / 2 * plane, plane, |task, dst| {
        let (u, v) = planes(task);
        #[cfg(target_arch = "x86_64")]
        if base::isa::Isa::chosen() != base::isa::Isa::Portable {
            // SAFETY: `Isa::chosen` names a build the CPU has, and every build past the
            // portable one has AVX2.
            return unsafe { gate_plane_avx2(dst, u, v) };
        }
        gate_plane(dst, u, v)
    })
}

/// `∂d` from `∂y`: `∂d₁ = ∂y · d₂ · GELU′(d₁)`, `∂d₂ = ∂y · GELU(d₁)`.
fn gate_grad(d: &[f32], dy: &[f32], dims: [usize; 4]) -> Vec<f32> {
    let [b, c2, h, w] = dims;
    let (hid, plane) = (c2 / 2, h * w);
    if plane == 0 {
        return vec![0.0; b * c2 * plane];
    }
    let planes = pair_planes(d, dims);
    // Each task writes the two planes of one output plane: image n's channels i and hid + i;
    // together they write every value (`fresh`).
    super::fresh::written(b * c2 * plane, |out| {
        let mut halves: Vec<(&mut [f32], &mut [f32])> = Vec::with_capacity(b * hid);
        for image in out.chunks_exact_mut(c2 * plane) {
            let (first, second) = image.split_at_mut(hid * plane);
            halves.extend(
                first
                    .chunks_exact_mut(plane)
                    .zip(second.chunks_exact_mut(plane)),
            );
        }
        halves
            .into_par_iter()
            .enumerate()
            .for_each(|(task, (du, dv))| {
                let (u, v) = planes(task);
                let g = &dy[task * plane..][..plane];
                #[cfg(target_arch = "x86_64")]
                if base::isa::Isa::chosen() != base::isa::Isa::Portable {
                    // SAFETY: as in `gate`.
                    return unsafe { gate_grad_plane_avx2(du, dv, [u, v, g]) };
                }
                gate_grad_plane(du, dv, [u, v, g])
            });
    })
}

#[inline(always)]
fn gate_plane(dst: &mut [f32], u: &[f32], v: &[f32]) {
    for ((o, &u), &v) in dst.iter_mut().zip(u).zip(v) {
        *o = gelu(u) * v;
    }
}

/// The same code compiled for AVX2 (no multiply-add contracted: the portable build's bits).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn gate_plane_avx2(dst: &mut [f32], u: &[f32], v: &[f32]) {
    gate_plane(dst, u, v)
}

/// `[d₁, d₂, ∂y]` planes → `∂d₁`, `∂d₂`.
#[inline(always)]
fn gate_grad_plane(du: &mut [f32], dv: &mut [f32], [u, v, g]: [&[f32]; 3]) {
    for ((((du, dv), &u), &v), &g) in du.iter_mut().zip(dv.iter_mut()).zip(u).zip(v).zip(g) {
        *du = g * v * gelu_slope(u);
        *dv = g * gelu(u);
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn gate_grad_plane_avx2(du: &mut [f32], dv: &mut [f32], planes: [&[f32]; 3]) {
    gate_grad_plane(du, dv, planes)
}

/// What the backward needs besides the inputs: the depthwise output the forward made.
#[derive(Clone)]
struct Kept(Arc<Vec<f32>>);

impl std::fmt::Debug for Kept {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Kept({} values)", self.0.len())
    }
}

#[derive(Debug)]
struct GateBackward;

impl Backward<Flex, 2> for GateBackward {
    type State = (NodeId, NodeId, Kept);

    fn backward(
        self,
        ops: Ops<Self::State, 2>,
        grads: &mut Gradients,
        checkpointer: &mut Checkpointer,
    ) {
        let [node_x, node_w] = ops.parents;
        let (id_x, id_w, Kept(d)) = ops.state;
        let dy = grads.consume::<Flex>(&ops.node).to_contiguous();
        let (x, dims) = values(checkpointer.retrieve_node_output::<FlexTensor>(id_x));
        let (weight, _) = values(checkpointer.retrieve_node_output::<FlexTensor>(id_w));
        // From `∂d` on, the depthwise convolution's own gradients.
        let dd = tensor(gate_grad(&d, flex_slice(&dy), dims), dims);
        if let Some(node) = node_x {
            grads.register::<Flex>(node.id, Flex::depthwise3_x_grad(weight, dd.clone()));
        }
        if let Some(node) = node_w {
            grads.register::<Flex>(node.id, Flex::depthwise3_w_grad(x, dd));
        }
    }
}

impl<C: CheckpointStrategy> GateTrainOps for Autodiff<Flex, C> {
    fn gated_depthwise3(x: FloatTensor<Self>, weight: FloatTensor<Self>) -> FloatTensor<Self> {
        match GateBackward
            .prepare::<C>([x.node(), weight.node()])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(mut prep) => {
                let (id_x, id_w) = (prep.checkpoint(&x), prep.checkpoint(&weight));
                let (xs, dims) = values(x.into_primitive());
                let (ws, _) = values(weight.into_primitive());
                let d = depthwise_forward(flex_slice(&xs), flex_slice(&ws), dims);
                let y = gate(&d, dims);
                let [b, c2, h, w] = dims;
                let y = tensor(y, [b, c2 / 2, h, w]);
                prep.finish((id_x, id_w, Kept(Arc::new(d))), y)
            }
            OpsKind::UnTracked(prep) => prep.finish(Flex::gated_depthwise3(
                x.into_primitive(),
                weight.into_primitive(),
            )),
        }
    }
}
