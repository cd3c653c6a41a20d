//! Restormer's transposed (channel) attention: attention maps of size `C/heads × C/heads`
//! over the whole image, so its cost is linear in the pixel count.

use burn::module::{Module, Param};
use burn::nn::conv::Conv2d;
use burn::tensor::activation::softmax;
use burn::tensor::{Device, Tensor};

use super::conv_train::depthwise3_weights;
use super::kernels::{Kernels, current};
use super::layers::{conv, depthwise, depthwise3, enhance_query, pointwise, trained_parts};

/// `x / max(‖x‖₂, ε)` along the last dimension.
pub fn l2_normalise(x: Tensor<4>) -> Tensor<4> {
    let norm = l2_norm(x.clone());
    x / norm
}

/// `max(‖x‖₂, ε)` along the last dimension (kept, size 1).
pub fn l2_norm(x: Tensor<4>) -> Tensor<4> {
    x.powf_scalar(2.0).sum_dim(3).sqrt().clamp_min(1e-12)
}

#[derive(Module, Debug)]
pub struct ChannelAttention {
    pub qkv: Conv2d,
    pub qkv_depthwise: Conv2d,
    pub proj: Conv2d,
    /// Learned softmax temperature per head.
    pub temperature: Param<Tensor<1>>,
    pub heads: usize,
    pub qe: usize,
}

impl ChannelAttention {
    pub fn new(c: usize, heads: usize, qe: usize, device: &Device) -> Self {
        Self {
            qkv: conv(c, 3 * c, 1, false, device),
            qkv_depthwise: depthwise3(3 * c, device),
            proj: conv(c, c, 1, false, device),
            temperature: Param::from_tensor(Tensor::ones([heads], device)),
            heads,
            qe,
        }
    }

    pub fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        let [b, c, h, w] = x.dims();
        let [q, k, v] = self.qkv(x);
        let q = enhance_query(q, self.qe);
        let d = c / self.heads;
        let split = |t: Tensor<4>| t.reshape([b, self.heads, d, h * w]);
        let t = self.temperature.val().reshape([1, self.heads, 1, 1]);
        let (q, k, v) = (split(q), split(k), split(v));
        let logits = match current() {
            Kernels::Reference => l2_normalise(q).matmul(l2_normalise(k).swap_dims(2, 3)),
            // The same logits with the norms applied to the small `d × d` product instead of
            // to the two maps: `q̂·k̂ᵀ = (q·kᵀ) / (‖q‖ ‖k‖ᵀ)`.
            Kernels::Fast => {
                let (nq, nk) = (l2_norm(q.clone()), l2_norm(k.clone()));
                q.matmul(k.swap_dims(2, 3)) / nq.matmul(nk.swap_dims(2, 3))
            }
        };
        let attn = softmax(logits * t, 3);
        pointwise(&self.proj, attn.matmul(v).reshape([b, c, h, w]))
    }

    /// The queries, keys and values: the 1×1 convolution to `3c` channels, its depthwise 3×3,
    /// split in three; in training on the CPU from the weights' thirds ([`trained_parts`]).
    fn qkv(&self, x: Tensor<4>) -> [Tensor<4>; 3] {
        if self.qkv_depthwise.bias.is_none()
            && let Some(parts) = trained_parts::<3>(&self.qkv, &x)
        {
            let dw = self.qkv_depthwise.weight.val();
            let c = dw.dims()[0] / 3;
            let mut parts = parts.into_iter().enumerate();
            return std::array::from_fn(|_| {
                let (i, part) = parts.next().expect("three parts");
                depthwise3_weights(part, dw.clone().narrow(0, i * c, c))
            });
        }
        let mut parts = depthwise(&self.qkv_depthwise, pointwise(&self.qkv, x)).chunk(3, 1);
        let v = parts.pop().expect("qkv");
        let k = parts.pop().expect("qkv");
        [parts.pop().expect("qkv"), k, v]
    }
}
