//! LayerNorm over the channels of every pixel on the CPU, in two passes, with a hand-written
//! backward for training.
//!
//! As tensors ([`super::layers::ChannelNorm`]) it is nine passes over the map, each making a
//! new tensor (mean, centred, square, mean, add, root, divide, scale, shift), and about as many
//! autodiff nodes: four times per STAF block, and on the 13 filters' maps in MAFG. Here one
//! pass over strips of pixels finds each pixel's mean and inverse deviation (the strip's
//! channels stay in cache for the second, centred sum), and one pass over the output planes
//! writes `(x − mean) · rstd · γ + β`. The variance is the centred one, as in the tensor
//! form. The backward recomputes the moments and forms, per pixel,
//! `dx = rstd · (γ·dy − mean(γ·dy) − x̂ · mean(γ·dy·x̂))`, and per channel `dγ = Σ dy·x̂`,
//! `dβ = Σ dy` (summed plane by plane in a fixed order). Registered with burn as a backend
//! extension ([`NormOps`]); it stands in only on burn's CPU backend.

use super::kernels::{flex_dims, flex_slice};
use burn::backend::autodiff::NodeId;
use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::flex::FlexTensor;
use burn::backend::{Autodiff, Backend, Dispatch, Flex, backend_extension, tensor::FloatTensor};
use burn::tensor::{Tensor, TensorData};
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
    let (mean, rstd) = stats(x, eps, [b, c, h, w]);
    super::fresh::filled(b * c * plane, plane, |task, dst| {
        let (n, ch) = (task / c, task % c);
        let src = &x[(n * c + ch) * plane..][..plane];
        let stats = (&mean[n * plane..][..plane], &rstd[n * plane..][..plane]);
        apply(dst, src, stats, weight[ch], bias[ch]);
    })
}

/// Per pixel `(mean, 1/sqrt(var + eps))` over the channels, batch item by batch item, strip
/// by strip: `[b, h·w]` each.
fn stats(x: &[f32], eps: f32, [b, c, h, w]: [usize; 4]) -> (Vec<f32>, Vec<f32>) {
    let plane = h * w;
    let mut mean = vec![0.0f32; b * plane];
    let mut rstd = vec![0.0f32; b * plane];
    per_strip(&mut mean, &mut rstd, plane, |n, p0, m, r| {
        moments(m, r, &x[n * c * plane..][..c * plane], c, plane, p0, eps)
    });
    (mean, rstd)
}

/// The gradients of [`channel_norm`] from the output gradient `dy`: `(dx, dγ, dβ)`.
pub fn channel_norm_backward(
    x: &[f32],
    dy: &[f32],
    weight: &[f32],
    eps: f32,
    [b, c, h, w]: [usize; 4],
) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
    let plane = h * w;
    assert!(x.len() == b * c * plane && dy.len() == x.len() && weight.len() == c);
    if x.is_empty() {
        return (Vec::new(), vec![0.0; c], vec![0.0; c]);
    }
    let (mean, rstd) = stats(x, eps, [b, c, h, w]);
    // Per pixel: mean(γ·dy) and mean(γ·dy·x̂) over the channels.
    let mut a = vec![0.0f32; b * plane];
    let mut bx = vec![0.0f32; b * plane];
    let inv_c = 1.0 / c as f32;
    per_strip(&mut a, &mut bx, plane, |n, p0, a, bx| {
        let len = a.len();
        let (m, r) = (
            &mean[n * plane + p0..][..len],
            &rstd[n * plane + p0..][..len],
        );
        for (ch, &g) in weight.iter().enumerate() {
            let at = (n * c + ch) * plane + p0;
            let (xs, ds) = (&x[at..][..len], &dy[at..][..len]);
            for i in 0..len {
                let gd = g * ds[i];
                a[i] += gd;
                bx[i] += gd * (xs[i] - m[i]) * r[i];
            }
        }
        a.iter_mut().for_each(|v| *v *= inv_c);
        bx.iter_mut().for_each(|v| *v *= inv_c);
    });
    // Per plane: dx, and that plane's share of dγ and dβ.
    // Every value of dx is written, plane by plane (`fresh`).
    let mut partial: Vec<(f32, f32)> = Vec::new();
    let dx = super::fresh::written(b * c * plane, |dx| {
        partial = dx
            .par_chunks_mut(plane)
            .enumerate()
            .map(|(task, out)| {
                let (n, ch) = (task / c, task % c);
                let xs = &x[task * plane..][..plane];
                let ds = &dy[task * plane..][..plane];
                let (m, r) = (&mean[n * plane..][..plane], &rstd[n * plane..][..plane]);
                let (a, bx) = (&a[n * plane..][..plane], &bx[n * plane..][..plane]);
                let g = weight[ch];
                let (mut dg, mut db) = (0.0f32, 0.0f32);
                for i in 0..plane {
                    let xhat = (xs[i] - m[i]) * r[i];
                    out[i] = r[i] * (g * ds[i] - a[i] - xhat * bx[i]);
                    dg += ds[i] * xhat;
                    db += ds[i];
                }
                (dg, db)
            })
            .collect();
    });
    let (mut dgamma, mut dbeta) = (vec![0.0f32; c], vec![0.0f32; c]);
    for (task, (dg, db)) in partial.into_iter().enumerate() {
        dgamma[task % c] += dg;
        dbeta[task % c] += db;
    }
    (dx, dgamma, dbeta)
}

/// Runs `f(n, p0, a, b)` on every strip of [`STRIP`] pixels (from pixel `p0`) of batch item
/// `n`'s part of two per-pixel arrays `a`, `b` (`[batch, plane]` each), strips in parallel.
fn per_strip(
    a: &mut [f32],
    b: &mut [f32],
    plane: usize,
    f: impl Fn(usize, usize, &mut [f32], &mut [f32]) + Sync,
) {
    a.par_chunks_mut(plane)
        .zip(b.par_chunks_mut(plane))
        .enumerate()
        .for_each(|(n, (a, b))| {
            a.par_chunks_mut(STRIP)
                .zip(b.par_chunks_mut(STRIP))
                .enumerate()
                .for_each(|(s, (a, b))| f(n, s * STRIP, a, b));
        });
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

/// [`channel_norm`] of `x: [b, c, h, w]` with `weight`, `bias: [c]` (on burn's CPU backend)
/// through [`NormOps`].
pub fn norm_tensor(x: Tensor<4>, weight: Tensor<1>, bias: Tensor<1>, eps: f32) -> Tensor<4> {
    Tensor::<4>::from_dispatch(<Dispatch as NormOps>::channel_norm(
        x.into_dispatch(),
        weight.into_dispatch(),
        bias.into_dispatch(),
        eps,
    ))
}

#[backend_extension(Flex, Autodiff)]
pub trait NormOps: Backend {
    /// `x: [b, c, h, w]`, `weight`, `bias`: `[c]` → `[b, c, h, w]`.
    fn channel_norm(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        bias: FloatTensor<Self>,
        eps: f32,
    ) -> FloatTensor<Self>;
}

impl NormOps for Flex {
    fn channel_norm(x: FlexTensor, weight: FlexTensor, bias: FlexTensor, eps: f32) -> FlexTensor {
        let (x, weight, bias) = (
            x.to_contiguous(),
            weight.to_contiguous(),
            bias.to_contiguous(),
        );
        let d = flex_dims::<4>(&x);
        let y = channel_norm(
            flex_slice(&x),
            flex_slice(&weight),
            flex_slice(&bias),
            eps,
            d,
        );
        FlexTensor::from_data(TensorData::new(y, d))
    }
}

#[derive(Debug)]
struct NormBackward {
    eps: f32,
}

impl Backward<Flex, 3> for NormBackward {
    type State = [NodeId; 2];

    fn backward(
        self,
        ops: Ops<Self::State, 3>,
        grads: &mut Gradients,
        checkpointer: &mut Checkpointer,
    ) {
        let dy = grads.consume::<Flex>(&ops.node).to_contiguous();
        let [x, weight] = ops.state.map(|id| {
            checkpointer
                .retrieve_node_output::<FlexTensor>(id)
                .to_contiguous()
        });
        let d = flex_dims::<4>(&x);
        let (dx, dgamma, dbeta) = channel_norm_backward(
            flex_slice(&x),
            flex_slice(&dy),
            flex_slice(&weight),
            self.eps,
            d,
        );
        let c = d[1];
        let tensors = [
            FlexTensor::from_data(TensorData::new(dx, d)),
            FlexTensor::from_data(TensorData::new(dgamma, [c])),
            FlexTensor::from_data(TensorData::new(dbeta, [c])),
        ];
        for (parent, grad) in ops.parents.into_iter().zip(tensors) {
            if let Some(node) = parent {
                grads.register::<Flex>(node.id, grad);
            }
        }
    }
}

impl<C: CheckpointStrategy> NormOps for Autodiff<Flex, C> {
    fn channel_norm(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        bias: FloatTensor<Self>,
        eps: f32,
    ) -> FloatTensor<Self> {
        let backward = NormBackward { eps };
        match backward
            .prepare::<C>([x.node(), weight.node(), bias.node()])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(mut prep) => {
                let state = [prep.checkpoint(&x), prep.checkpoint(&weight)];
                let y = Flex::channel_norm(
                    x.into_primitive(),
                    weight.into_primitive(),
                    bias.into_primitive(),
                    eps,
                );
                prep.finish(state, y)
            }
            OpsKind::UnTracked(prep) => prep.finish(Flex::channel_norm(
                x.into_primitive(),
                weight.into_primitive(),
                bias.into_primitive(),
                eps,
            )),
        }
    }
}
