//! 3×3 convolutions (zero padding, stride 1) with hand-written backward passes, for training
//! on the CPU.
//!
//! burn's generic weight gradient for a convolution runs a convolution whose kernel is the
//! whole output gradient, after swapping and copying the maps, and for a grouped one it does
//! so once per channel: together the largest cost of a `tiny` training step (restore/README,
//! "Where a training step's time goes"). Here:
//! - depthwise: the forward, the input gradient (the same correlation with each kernel turned
//!   half a turn) and the weight gradient (nine dot products per plane) are loops over one
//!   plane at a time, planes in parallel;
//! - dense: the forward and the input gradient are [`super::dense_direct`]'s kernel (the latter
//!   with the kernels transposed and turned half a turn), the weight gradient one matrix product
//!   of the input's 3×3 neighbourhoods with the output gradient.
//!
//! Registered with burn as a backend extension, so autodiff records each as one node; they
//! stand in only on burn's CPU backend under autodiff ([`trained_applies`]), and the reference
//! path keeps burn's `Conv2d`.

use super::kernels::{flex_dims, flex_slice};
use burn::backend::autodiff::NodeId;
use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::flex::FlexTensor;
use burn::backend::ops::FloatTensorOps;
use burn::backend::{Autodiff, Backend, Dispatch, Flex, backend_extension, tensor::FloatTensor};
use burn::nn::conv::Conv2d;
use burn::tensor::{Device, Tensor, TensorData};
use rayon::prelude::*;

/// Whether [`depthwise3`] and [`dense3`] may stand in for burn's convolution: a tensor under
/// autodiff on burn's CPU backend (the extension is registered for that backend only).
pub fn trained_applies(t: &Tensor<4>) -> bool {
    t.is_autodiff() && t.device() == Device::flex().autodiff()
}

/// `conv` (a depthwise 3×3 layer: `[c, 1, 3, 3]` weights, padding 1) applied to `x`
/// `[b, c, h, w]` through the hand-written kernels; its bias, if any, added after.
pub fn depthwise3(conv: &Conv2d, x: Tensor<4>) -> Tensor<4> {
    let y = depthwise3_weights(x, conv.weight.val());
    match &conv.bias {
        Some(bias) => {
            let c = bias.dims()[0];
            y + bias.val().reshape([1, c, 1, 1])
        }
        None => y,
    }
}

/// Depthwise 3×3 weights `[c, 1, 3, 3]` (padding 1, no bias) applied to `x` `[b, c, h, w]`
/// through the hand-written kernels.
pub fn depthwise3_weights(x: Tensor<4>, weight: Tensor<4>) -> Tensor<4> {
    Tensor::<4>::from_dispatch(<Dispatch as DepthwiseOps>::depthwise3(
        x.into_dispatch(),
        weight.into_dispatch(),
    ))
}

/// `conv` (a dense 3×3 layer: `[cout, cin, 3, 3]` weights, padding 1, stride 1, one group)
/// applied to `x` `[b, cin, h, w]` through the hand-written backward; its bias, if any, added
/// after.
pub fn dense3(conv: &Conv2d, x: Tensor<4>) -> Tensor<4> {
    let y = Tensor::<4>::from_dispatch(<Dispatch as DenseOps>::dense3(
        x.into_dispatch(),
        conv.weight.val().into_dispatch(),
    ));
    match &conv.bias {
        Some(bias) => {
            let c = bias.dims()[0];
            y + bias.val().reshape([1, c, 1, 1])
        }
        None => y,
    }
}

#[backend_extension(Flex, Autodiff)]
pub trait DenseOps: Backend {
    /// `x: [b, cin, h, w]`, `weight: [cout, cin, 3, 3]` → `[b, cout, h, w]`.
    fn dense3(x: FloatTensor<Self>, weight: FloatTensor<Self>) -> FloatTensor<Self>;
    /// The input gradient from the output gradient `dy`.
    fn dense3_x_grad(weight: FloatTensor<Self>, dy: FloatTensor<Self>) -> FloatTensor<Self>;
    /// The weight gradient `[cout, cin, 3, 3]`.
    fn dense3_w_grad(x: FloatTensor<Self>, dy: FloatTensor<Self>) -> FloatTensor<Self>;
}

impl DenseOps for Flex {
    fn dense3(x: FlexTensor, weight: FlexTensor) -> FlexTensor {
        let (x, d @ [b, _, h, w]) = values(x);
        let (weight, [cout, ..]) = values(weight);
        let y = super::dense_direct::dense3(flex_slice(&x), flex_slice(&weight), cout, d);
        tensor(y, [b, cout, h, w])
    }

    fn dense3_x_grad(weight: FlexTensor, dy: FlexTensor) -> FlexTensor {
        let (weight, [cout, cin, _, _]) = values(weight);
        let turned = transposed_half_turn(flex_slice(&weight), cout, cin);
        let (dy, d @ [b, _, h, w]) = values(dy);
        let dx = super::dense_direct::dense3(flex_slice(&dy), &turned, cin, d);
        tensor(dx, [b, cin, h, w])
    }

    fn dense3_w_grad(x: FlexTensor, dy: FlexTensor) -> FlexTensor {
        let (x, [b, cin, h, w]) = values(x);
        let (dy, [_, cout, _, _]) = values(dy);
        let n = b * h * w;
        // [cin·9, n] · [n, cout] = [cin·9, cout], then reordered to [cout, cin, 3, 3].
        let cols = tensor(
            neighbourhoods(flex_slice(&x), [b, cin, h, w]),
            [1, 1, cin * 9, n],
        );
        let dyt = tensor(
            pixels_by_channel(flex_slice(&dy), [b, cout, h, w]),
            [1, 1, n, cout],
        );
        let (g, _) = values(<Flex as FloatTensorOps<Flex>>::float_matmul(cols, dyt));
        let g = flex_slice(&g);
        let mut out = vec![0.0f32; cout * cin * 9];
        for (ck, row) in g.chunks_exact(cout).enumerate() {
            for (co, &v) in row.iter().enumerate() {
                out[co * cin * 9 + ck] = v;
            }
        }
        tensor(out, [cout, cin, 3, 3])
    }
}

/// `[cout, cin, 3, 3]` → `[cin, cout, 3, 3]` with each kernel turned half a turn: the
/// kernels whose forward convolution of the output gradient is the input gradient.
fn transposed_half_turn(weight: &[f32], cout: usize, cin: usize) -> Vec<f32> {
    let mut out = vec![0.0f32; cout * cin * 9];
    for co in 0..cout {
        for ci in 0..cin {
            let src = &weight[(co * cin + ci) * 9..][..9];
            let dst = &mut out[(ci * cout + co) * 9..][..9];
            for (d, s) in dst.iter_mut().zip(src.iter().rev()) {
                *d = *s;
            }
        }
    }
    out
}

/// im2col: row `ci·9 + ky·3 + kx` holds, for every pixel of every image (`b·h·w` columns),
/// the input at `(y + ky − 1, x + kx − 1)` of channel `ci`, zero outside.
fn neighbourhoods(x: &[f32], [b, c, h, w]: [usize; 4]) -> Vec<f32> {
    let (plane, n) = (h * w, b * h * w);
    let mut out = vec![0.0f32; c * 9 * n];
    if n == 0 {
        return out;
    }
    out.par_chunks_mut(n).enumerate().for_each(|(row, dst)| {
        let (ci, k) = (row / 9, row % 9);
        let (dy, dx) = (k / 3, k % 3);
        for n_img in 0..b {
            let src = &x[(n_img * c + ci) * plane..][..plane];
            let dst = &mut dst[n_img * plane..][..plane];
            for y in 0..h {
                let Some(sy) = (y + dy).checked_sub(1).filter(|&sy| sy < h) else {
                    continue;
                };
                let s = &src[sy * w..][..w];
                let d = &mut dst[y * w..][..w];
                // Output column x reads input column x + dx − 1.
                match dx {
                    0 => d[1..].copy_from_slice(&s[..w - 1]),
                    1 => d.copy_from_slice(s),
                    _ => d[..w - 1].copy_from_slice(&s[1..]),
                }
            }
        }
    });
    out
}

/// `[b, c, h, w]` → `[b·h·w, c]`: each pixel's channels side by side.
fn pixels_by_channel(x: &[f32], [b, c, h, w]: [usize; 4]) -> Vec<f32> {
    let plane = h * w;
    assert_eq!(x.len(), b * c * plane);
    // A permutation: every value is written once (`fresh`).
    super::fresh::written(b * plane * c, |out| {
        for n_img in 0..b {
            for ch in 0..c {
                let src = &x[(n_img * c + ch) * plane..][..plane];
                for (p, &v) in src.iter().enumerate() {
                    out[(n_img * plane + p) * c + ch] = v;
                }
            }
        }
    })
}

#[derive(Debug)]
struct DenseBackward;

impl<B: Backend + DenseOps> Backward<B, 2> for DenseBackward {
    type State = (NodeId, NodeId);

    fn backward(
        self,
        ops: Ops<Self::State, 2>,
        grads: &mut Gradients,
        checkpointer: &mut Checkpointer,
    ) {
        let [node_x, node_w] = ops.parents;
        let dy = grads.consume::<B>(&ops.node);
        let x: FloatTensor<B> = checkpointer.retrieve_node_output(ops.state.0);
        let weight: FloatTensor<B> = checkpointer.retrieve_node_output(ops.state.1);
        if let Some(node) = node_x {
            grads.register::<B>(node.id, B::dense3_x_grad(weight, dy.clone()));
        }
        if let Some(node) = node_w {
            grads.register::<B>(node.id, B::dense3_w_grad(x, dy));
        }
    }
}

impl<B: Backend + DenseOps, C: CheckpointStrategy> DenseOps for Autodiff<B, C> {
    fn dense3(x: FloatTensor<Self>, weight: FloatTensor<Self>) -> FloatTensor<Self> {
        match DenseBackward
            .prepare::<C>([x.node(), weight.node()])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(mut prep) => {
                let state = (prep.checkpoint(&x), prep.checkpoint(&weight));
                let y = B::dense3(x.into_primitive(), weight.into_primitive());
                prep.finish(state, y)
            }
            OpsKind::UnTracked(prep) => {
                prep.finish(B::dense3(x.into_primitive(), weight.into_primitive()))
            }
        }
    }

    fn dense3_x_grad(_: FloatTensor<Self>, _: FloatTensor<Self>) -> FloatTensor<Self> {
        unreachable!("the convolution's gradient is not differentiated")
    }

    fn dense3_w_grad(_: FloatTensor<Self>, _: FloatTensor<Self>) -> FloatTensor<Self> {
        unreachable!("the convolution's gradient is not differentiated")
    }
}

#[backend_extension(Flex, Autodiff)]
pub trait DepthwiseOps: Backend {
    /// `x: [b, c, h, w]`, `weight: [c, 1, 3, 3]` → `[b, c, h, w]`.
    fn depthwise3(x: FloatTensor<Self>, weight: FloatTensor<Self>) -> FloatTensor<Self>;
    /// The input gradient from the output gradient `dy`.
    fn depthwise3_x_grad(weight: FloatTensor<Self>, dy: FloatTensor<Self>) -> FloatTensor<Self>;
    /// The weight gradient `[c, 1, 3, 3]`.
    fn depthwise3_w_grad(x: FloatTensor<Self>, dy: FloatTensor<Self>) -> FloatTensor<Self>;
}

/// A dense copy's values (no copy when the tensor is dense already).
pub(super) fn values(t: FlexTensor) -> (FlexTensor, [usize; 4]) {
    let t = t.to_contiguous();
    let d = flex_dims::<4>(&t);
    (t, d)
}

pub(super) fn tensor(v: Vec<f32>, shape: [usize; 4]) -> FlexTensor {
    FlexTensor::from_data(TensorData::new(v, shape))
}

impl DepthwiseOps for Flex {
    fn depthwise3(x: FlexTensor, weight: FlexTensor) -> FlexTensor {
        let (x, d) = values(x);
        let (weight, _) = values(weight);
        tensor(forward(flex_slice(&x), flex_slice(&weight), d), d)
    }

    fn depthwise3_x_grad(weight: FlexTensor, dy: FlexTensor) -> FlexTensor {
        let (dy, d) = values(dy);
        let (weight, _) = values(weight);
        tensor(
            forward(flex_slice(&dy), &half_turn(flex_slice(&weight)), d),
            d,
        )
    }

    fn depthwise3_w_grad(x: FlexTensor, dy: FlexTensor) -> FlexTensor {
        let (x, d) = values(x);
        let (dy, _) = values(dy);
        tensor(
            weight_grad(flex_slice(&x), flex_slice(&dy), d),
            [d[1], 1, 3, 3],
        )
    }
}

#[derive(Debug)]
struct DepthwiseBackward;

impl<B: Backend + DepthwiseOps> Backward<B, 2> for DepthwiseBackward {
    type State = (NodeId, NodeId);

    fn backward(
        self,
        ops: Ops<Self::State, 2>,
        grads: &mut Gradients,
        checkpointer: &mut Checkpointer,
    ) {
        let [node_x, node_w] = ops.parents;
        let dy = grads.consume::<B>(&ops.node);
        let x: FloatTensor<B> = checkpointer.retrieve_node_output(ops.state.0);
        let weight: FloatTensor<B> = checkpointer.retrieve_node_output(ops.state.1);
        if let Some(node) = node_x {
            grads.register::<B>(node.id, B::depthwise3_x_grad(weight, dy.clone()));
        }
        if let Some(node) = node_w {
            grads.register::<B>(node.id, B::depthwise3_w_grad(x, dy));
        }
    }
}

impl<B: Backend + DepthwiseOps, C: CheckpointStrategy> DepthwiseOps for Autodiff<B, C> {
    fn depthwise3(x: FloatTensor<Self>, weight: FloatTensor<Self>) -> FloatTensor<Self> {
        match DepthwiseBackward
            .prepare::<C>([x.node(), weight.node()])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(mut prep) => {
                let state = (prep.checkpoint(&x), prep.checkpoint(&weight));
                let y = B::depthwise3(x.into_primitive(), weight.into_primitive());
                prep.finish(state, y)
            }
            OpsKind::UnTracked(prep) => {
                prep.finish(B::depthwise3(x.into_primitive(), weight.into_primitive()))
            }
        }
    }

    // The gradients are computed on the inner backend inside `backward`; a gradient of a
    // gradient is never asked for.
    fn depthwise3_x_grad(_: FloatTensor<Self>, _: FloatTensor<Self>) -> FloatTensor<Self> {
        unreachable!("the depthwise gradient is not differentiated")
    }

    fn depthwise3_w_grad(_: FloatTensor<Self>, _: FloatTensor<Self>) -> FloatTensor<Self> {
        unreachable!("the depthwise gradient is not differentiated")
    }
}

/// Each channel's 3×3 kernel turned by 180°: the input gradient of a cross-correlation is
/// the cross-correlation of the output gradient with it.
fn half_turn(weight: &[f32]) -> Vec<f32> {
    weight
        .chunks_exact(9)
        .flat_map(|k| k.iter().rev().copied())
        .collect()
}

/// `x: [b, c, h, w]` cross-correlated with each channel's 3×3 kernel (`weight: [c·9]`).
pub fn forward(x: &[f32], weight: &[f32], [b, c, h, w]: [usize; 4]) -> Vec<f32> {
    let plane = h * w;
    // Every row of every plane is written by `depthwise_row`: no zeros first (an empty map
    // makes an empty output without calling it).
    super::fresh::filled(b * c * plane, plane, |i, dst| {
        let k: &[f32; 9] = weight[(i % c) * 9..][..9].try_into().unwrap();
        let src = &x[i * plane..][..plane];
        #[cfg(target_arch = "x86_64")]
        if base::isa::Isa::chosen() != base::isa::Isa::Portable {
            // SAFETY: `Isa::chosen` names a build the CPU has, and every build past the
            // portable one has AVX2.
            return unsafe { plane_forward_avx2(dst, src, k, h, w) };
        }
        plane_forward(dst, src, k, h, w)
    })
}

/// The same code compiled for AVX2 (no multiply-add contracted: the portable build's bits).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn plane_forward_avx2(dst: &mut [f32], src: &[f32], k: &[f32; 9], h: usize, w: usize) {
    plane_forward(dst, src, k, h, w)
}

#[inline(always)]
fn plane_forward(dst: &mut [f32], src: &[f32], k: &[f32; 9], h: usize, w: usize) {
    for (y, row) in dst.chunks_exact_mut(w).enumerate() {
        depthwise_row(row, src, k, y, h, w);
    }
}

/// `dL/dweight[c, ky, kx] = Σ_{b,y,x} dy[b,c,y,x] · x[b,c,y+ky−1,x+kx−1]` (zero outside):
/// nine dot products per plane, planes in parallel, each plane's sums in f64 before the
/// batch is added up.
pub fn weight_grad(x: &[f32], dy: &[f32], [b, c, h, w]: [usize; 4]) -> Vec<f32> {
    let plane = h * w;
    let mut out = vec![0.0f64; c * 9];
    if plane == 0 {
        return vec![0.0; c * 9];
    }
    let per_plane: Vec<[f64; 9]> = (0..b * c)
        .into_par_iter()
        .map(|i| {
            let (x, dy) = (&x[i * plane..][..plane], &dy[i * plane..][..plane]);
            #[cfg(target_arch = "x86_64")]
            if base::isa::Isa::chosen() != base::isa::Isa::Portable {
                // SAFETY: as in `forward`.
                return unsafe { plane_weight_grad_avx2(x, dy, h, w) };
            }
            plane_weight_grad(x, dy, h, w)
        })
        .collect();
    for (i, sums) in per_plane.iter().enumerate() {
        for (o, s) in out[(i % c) * 9..][..9].iter_mut().zip(sums) {
            *o += s;
        }
    }
    out.into_iter().map(|v| v as f32).collect()
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn plane_weight_grad_avx2(x: &[f32], dy: &[f32], h: usize, w: usize) -> [f64; 9] {
    plane_weight_grad(x, dy, h, w)
}

#[inline(always)]
fn plane_weight_grad(x: &[f32], dy: &[f32], h: usize, w: usize) -> [f64; 9] {
    let mut sums = [0.0f64; 9];
    for y in 0..h {
        let g = &dy[y * w..][..w];
        for ky in 0..3 {
            let Some(sy) = (y + ky).checked_sub(1).filter(|&sy| sy < h) else {
                continue;
            };
            let s = &x[sy * w..][..w];
            // Column offset kx − 1: output column x reads input column x + kx − 1.
            sums[ky * 3] += dot(&g[1..], &s[..w - 1]) as f64;
            sums[ky * 3 + 1] += dot(g, s) as f64;
            sums[ky * 3 + 2] += dot(&g[..w - 1], &s[1..]) as f64;
        }
    }
    sums
}

/// A dot product in eight lanes, so the loop vectorises without reassociation by the
/// compiler.
#[inline(always)]
fn dot(a: &[f32], b: &[f32]) -> f32 {
    let mut lanes = [0.0f32; 8];
    let mut ca = a.chunks_exact(8);
    let mut cb = b.chunks_exact(8);
    for (u, v) in (&mut ca).zip(&mut cb) {
        for l in 0..8 {
            lanes[l] += u[l] * v[l];
        }
    }
    let tail: f32 = ca
        .remainder()
        .iter()
        .zip(cb.remainder())
        .map(|(u, v)| u * v)
        .sum();
    lanes.iter().sum::<f32>() + tail
}

/// Row `y` of a 3×3 cross-correlation with zero padding (what burn's `conv2d` computes), in
/// one pass over the row: each value is `0 + t₀ + t₁ + t₂` over the kernel rows that fall
/// inside the map, `t = k₀·s[x−1] + k₁·s[x] + k₂·s[x+1]` (the sums of a pass per kernel row,
/// which this replaced: the same bits, tested below).
#[inline(always)]
pub fn depthwise_row(row: &mut [f32], src: &[f32], k: &[f32; 9], y: usize, h: usize, w: usize) {
    let tap = |ky: usize| {
        let sy = (y + ky).checked_sub(1).filter(|&sy| sy < h)?;
        Some((
            &src[sy * w..][..w],
            [k[ky * 3], k[ky * 3 + 1], k[ky * 3 + 2]],
        ))
    };
    match (tap(0), tap(1), tap(2)) {
        (Some(a), Some(b), Some(c)) => rows_sum([a.0, b.0, c.0], [a.1, b.1, c.1], row),
        (None, Some(b), Some(c)) => rows_sum([b.0, c.0], [b.1, c.1], row),
        (Some(a), Some(b), None) => rows_sum([a.0, b.0], [a.1, b.1], row),
        (None, Some(b), None) => rows_sum([b.0], [b.1], row),
        _ => unreachable!("row {y} of {h} reads its own input row"),
    }
}

/// `row[x] = Σ_r (k[r][0]·s[r][x−1] + k[r][1]·s[r][x] + k[r][2]·s[r][x+1])`, zero past the
/// ends, the rows `r` added in order from zero.
#[inline(always)]
fn rows_sum<const N: usize>(s: [&[f32]; N], k: [[f32; 3]; N], row: &mut [f32]) {
    let w = row.len();
    if w < 2 {
        let mut a = 0.0f32;
        for r in 0..N {
            a += k[r][1] * s[r][0];
        }
        row[0] = a;
        return;
    }
    // Interior columns from slices of one length, so the loop vectorises without checks.
    let n = w - 2;
    let (lo, mid, hi) = (
        s.map(|s| &s[..n]),
        s.map(|s| &s[1..][..n]),
        s.map(|s| &s[2..][..n]),
    );
    for (i, out) in row[1..][..n].iter_mut().enumerate() {
        let mut a = 0.0f32;
        for r in 0..N {
            a += k[r][0] * lo[r][i] + k[r][1] * mid[r][i] + k[r][2] * hi[r][i];
        }
        *out = a;
    }
    let (mut first, mut last) = (0.0f32, 0.0f32);
    for r in 0..N {
        first += k[r][1] * s[r][0] + k[r][2] * s[r][1];
        last += k[r][0] * s[r][w - 2] + k[r][1] * s[r][w - 1];
    }
    row[0] = first;
    row[w - 1] = last;
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The row as it was computed before [`depthwise_row`]'s one pass: a pass per kernel row
    /// added into the zeroed row.
    fn row_by_passes(row: &mut [f32], src: &[f32], k: &[f32; 9], y: usize, h: usize, w: usize) {
        row.fill(0.0);
        for ky in 0..3 {
            let Some(sy) = (y + ky).checked_sub(1).filter(|&sy| sy < h) else {
                continue;
            };
            let s = &src[sy * w..][..w];
            let (k0, k1, k2) = (k[ky * 3], k[ky * 3 + 1], k[ky * 3 + 2]);
            if w >= 2 {
                for (x, r) in row[1..w - 1].iter_mut().enumerate() {
                    *r += k0 * s[x] + k1 * s[x + 1] + k2 * s[x + 2];
                }
                row[0] += k1 * s[0] + k2 * s[1];
                row[w - 1] += k0 * s[w - 2] + k1 * s[w - 1];
            } else {
                row[0] += k1 * s[0];
            }
        }
    }

    /// The shared test stream with every eleventh value from the fourth +0 and from the eighth
    /// −0 (the sums must keep their signs' bits).
    fn values(n: usize, seed: u64) -> Vec<f32> {
        let mut v = super::super::test_values::values(n, seed);
        for (i, x) in v.iter_mut().enumerate() {
            match i % 11 {
                3 => *x = 0.0,
                7 => *x = -0.0,
                _ => {}
            }
        }
        v
    }

    #[test]
    fn the_depthwise_weight_gradient_matches_an_f64_sum() {
        for (b, c, h, w) in [
            (1, 1, 1, 1),
            (2, 3, 1, 2),
            (1, 2, 2, 1),
            (2, 2, 5, 17),
            (1, 3, 6, 64),
            (3, 1, 4, 9),
        ] {
            let n = b * c * h * w;
            let (x, dy) = (values(n, 5 + n as u64), values(n, 9 + w as u64));
            let fast = weight_grad(&x, &dy, [b, c, h, w]);
            let mut exact = vec![0.0f64; c * 9];
            for i in 0..b * c {
                for y in 0..h {
                    for xx in 0..w {
                        for k in 0..9 {
                            let (sy, sx) = (y + k / 3, xx + k % 3);
                            if (1..=h).contains(&sy) && (1..=w).contains(&sx) {
                                let at = (i * h + sy - 1) * w + sx - 1;
                                exact[(i % c) * 9 + k] +=
                                    dy[(i * h + y) * w + xx] as f64 * x[at] as f64;
                            }
                        }
                    }
                }
            }
            let scale = exact.iter().fold(1e-9f64, |m, v| m.max(v.abs()));
            let err = fast
                .iter()
                .zip(&exact)
                .map(|(&f, &e)| (f as f64 - e).abs())
                .fold(0.0, f64::max);
            assert!(
                err / scale < 1e-6,
                "{b}x{c}x{h}x{w}: {:.2e} of the scale",
                err / scale
            );
        }
    }

    #[test]
    fn empty_maps_give_empty_depthwise_outputs() {
        for d in [[0, 2, 3, 3], [1, 2, 0, 3], [1, 2, 3, 0], [1, 0, 3, 3]] {
            assert!(forward(&[], &[0.5; 18], d).is_empty(), "{d:?}");
        }
    }

    #[test]
    fn the_one_pass_row_has_the_bits_of_a_pass_per_kernel_row() {
        for (h, w) in [
            (1, 1),
            (1, 2),
            (2, 1),
            (2, 2),
            (3, 3),
            (5, 17),
            (4, 64),
            (7, 33),
        ] {
            let src = values(h * w, (h * 100 + w) as u64);
            let k: [f32; 9] = values(9, w as u64).try_into().unwrap();
            for y in 0..h {
                let (mut fast, mut slow) = (vec![f32::NAN; w], vec![f32::NAN; w]);
                depthwise_row(&mut fast, &src, &k, y, h, w);
                row_by_passes(&mut slow, &src, &k, y, h, w);
                let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(&fast), bits(&slow), "{h}x{w}, row {y}");
            }
        }
    }
}
