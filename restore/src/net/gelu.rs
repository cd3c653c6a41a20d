//! GELU (the exact, erf form) on the CPU with an erf that vectorises, forward and backward.
//!
//! burn's CPU GELU and its gradient call a scalar `erf` per element (7 % of a `tiny`
//! training step went to the gradient alone). Here erf is Abramowitz and Stegun 7.1.26
//! (absolute error below 1.5e-7) over [`exp_nonpositive`], so the loops run 8 wide.
//! Registered with burn as a backend extension ([`GeluOps`]); it stands in only on burn's CPU
//! backend, under autodiff or not.

use super::kernels::flex_slice;
use super::window_direct::exp_nonpositive;
use burn::backend::autodiff::NodeId;
use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::flex::FlexTensor;
use burn::backend::{Autodiff, Backend, Dispatch, Flex, backend_extension, tensor::FloatTensor};
use burn::tensor::{Tensor, TensorData};

/// `erf(x)`, absolute error below 1.5e-7.
#[inline(always)]
pub fn erf(x: f32) -> f32 {
    let z = x.abs();
    let t = 1.0 / (1.0 + 0.327_591_1 * z);
    let poly = ((((1.061_405_4 * t - 1.453_152_1) * t + 1.421_413_8) * t - 0.284_496_74) * t
        + 0.254_829_6)
        * t;
    let erf_abs = 1.0 - poly * exp_nonpositive(-z * z);
    if x < 0.0 { -erf_abs } else { erf_abs }
}

/// `x/2 · (1 + erf(x/√2))`.
#[inline(always)]
pub fn gelu(x: f32) -> f32 {
    0.5 * x * (1.0 + erf(x * std::f32::consts::FRAC_1_SQRT_2))
}

/// `d gelu / dx = Φ(x) + x·φ(x)`.
#[inline(always)]
pub fn gelu_slope(x: f32) -> f32 {
    // 1/√(2π)
    const INV_SQRT_2PI: f32 = 0.398_942_3;
    let cdf = 0.5 * (1.0 + erf(x * std::f32::consts::FRAC_1_SQRT_2));
    cdf + x * INV_SQRT_2PI * exp_nonpositive(-0.5 * x * x)
}

/// Elements per task: large enough that a task outweighs its hand-off.
const CHUNK: usize = 1 << 14;

fn map_into(out: &mut [f32], x: &[f32], dy: Option<&[f32]>) {
    #[cfg(target_arch = "x86_64")]
    if base::isa::Isa::chosen() != base::isa::Isa::Portable {
        // SAFETY: `Isa::chosen` names a build the CPU has, and every build past the
        // portable one has AVX2.
        return unsafe { map_avx2(out, x, dy) };
    }
    map_body(out, x, dy)
}

/// The same code compiled for AVX2 (no multiply-add contracted: the portable build's bits).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn map_avx2(out: &mut [f32], x: &[f32], dy: Option<&[f32]>) {
    map_body(out, x, dy)
}

#[inline(always)]
fn map_body(out: &mut [f32], x: &[f32], dy: Option<&[f32]>) {
    match dy {
        None => out.iter_mut().zip(x).for_each(|(o, &v)| *o = gelu(v)),
        Some(dy) => {
            for ((o, &v), &g) in out.iter_mut().zip(x).zip(dy) {
                *o = g * gelu_slope(v);
            }
        }
    }
}

/// GELU of every value, or with `dy` the input gradient `dy · gelu'(x)`.
pub fn gelu_values(x: &[f32], dy: Option<&[f32]>) -> Vec<f32> {
    if let Some(dy) = dy {
        assert_eq!(dy.len(), x.len());
    }
    super::fresh::filled(x.len(), CHUNK, |i, o| {
        let x = &x[i * CHUNK..][..o.len()];
        map_into(o, x, dy.map(|d| &d[i * CHUNK..][..o.len()]));
    })
}

/// GELU of `x` (on burn's CPU backend) through [`GeluOps`].
pub fn gelu_tensor<const D: usize>(x: Tensor<D>) -> Tensor<D> {
    Tensor::<D>::from_dispatch(<Dispatch as GeluOps>::gelu_fast(x.into_dispatch()))
}

#[backend_extension(Flex, Autodiff)]
pub trait GeluOps: Backend {
    /// GELU of every element.
    fn gelu_fast(x: FloatTensor<Self>) -> FloatTensor<Self>;
    /// `dy · gelu'(x)`.
    fn gelu_fast_grad(x: FloatTensor<Self>, dy: FloatTensor<Self>) -> FloatTensor<Self>;
}

impl GeluOps for Flex {
    fn gelu_fast(x: FlexTensor) -> FlexTensor {
        let x = x.to_contiguous();
        let shape = x.layout().shape().to_vec();
        FlexTensor::from_data(TensorData::new(gelu_values(flex_slice(&x), None), shape))
    }

    fn gelu_fast_grad(x: FlexTensor, dy: FlexTensor) -> FlexTensor {
        let (x, dy) = (x.to_contiguous(), dy.to_contiguous());
        let shape = x.layout().shape().to_vec();
        let g = gelu_values(flex_slice(&x), Some(flex_slice(&dy)));
        FlexTensor::from_data(TensorData::new(g, shape))
    }
}

#[derive(Debug)]
struct GeluBackward;

impl<B: Backend + GeluOps> Backward<B, 1> for GeluBackward {
    type State = NodeId;

    fn backward(
        self,
        ops: Ops<Self::State, 1>,
        grads: &mut Gradients,
        checkpointer: &mut Checkpointer,
    ) {
        let [parent] = ops.parents;
        let dy = grads.consume::<B>(&ops.node);
        let x: FloatTensor<B> = checkpointer.retrieve_node_output(ops.state);
        if let Some(node) = parent {
            grads.register::<B>(node.id, B::gelu_fast_grad(x, dy));
        }
    }
}

impl<B: Backend + GeluOps, C: CheckpointStrategy> GeluOps for Autodiff<B, C> {
    fn gelu_fast(x: FloatTensor<Self>) -> FloatTensor<Self> {
        match GeluBackward
            .prepare::<C>([x.node()])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(mut prep) => {
                let state = prep.checkpoint(&x);
                prep.finish(state, B::gelu_fast(x.into_primitive()))
            }
            OpsKind::UnTracked(prep) => prep.finish(B::gelu_fast(x.into_primitive())),
        }
    }

    fn gelu_fast_grad(_: FloatTensor<Self>, _: FloatTensor<Self>) -> FloatTensor<Self> {
        unreachable!("GELU's gradient is not differentiated")
    }
}
