//! The STAF block: spatial window attention and channel attention side by side, each with
//! its own feed-forward network, fused by a learned gate.

use burn::module::Module;
use burn::nn::conv::Conv2d;
use burn::tensor::activation::sigmoid;
use burn::tensor::{Device, Tensor, TensorData};

use super::channel::ChannelAttention;
use super::kernels::{Kernels, current, direct_applies, host};
use super::layers::{ChannelNorm, Gdfn, conv, gelu, pointwise};
use super::window::WindowAttention;

/// Where the fusion gate varies.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Gate {
    /// One weight per channel from the spatial mean (encoder and latent levels).
    PerChannel,
    /// One weight per pixel from the channel mean (decoder and refinement).
    PerPixel,
}

/// Sizes of one block.
#[derive(Clone, Copy, Debug)]
pub struct BlockSpec {
    pub channels: usize,
    pub channel_heads: usize,
    pub window_heads: usize,
    pub win: usize,
    pub kwin: usize,
    pub hidden: usize,
    /// Query-enhancement kernel (0: none).
    pub qe: usize,
    pub gate: Gate,
}

#[derive(Module, Debug)]
pub struct StafBlock {
    pub norm_sa: ChannelNorm,
    pub spatial: WindowAttention,
    pub norm_sa_ffn: ChannelNorm,
    pub ffn_sa: Gdfn,
    pub norm_ca: ChannelNorm,
    pub channel: ChannelAttention,
    pub norm_ca_ffn: ChannelNorm,
    pub ffn_ca: Gdfn,
    pub fuse_in: Conv2d,
    pub fuse_out: Conv2d,
    pub per_pixel: bool,
}

impl StafBlock {
    pub fn new(s: BlockSpec, device: &Device) -> Self {
        let c = s.channels;
        Self {
            norm_sa: ChannelNorm::new(c, device),
            spatial: WindowAttention::new(c, s.window_heads, s.win, s.kwin, s.qe, device),
            norm_sa_ffn: ChannelNorm::new(c, device),
            ffn_sa: Gdfn::new(c, s.hidden, device),
            norm_ca: ChannelNorm::new(c, device),
            channel: ChannelAttention::new(c, s.channel_heads, s.qe, device),
            norm_ca_ffn: ChannelNorm::new(c, device),
            ffn_ca: Gdfn::new(c, s.hidden, device),
            fuse_in: conv(2 * c, c, 1, true, device),
            fuse_out: conv(c, c, 1, true, device),
            per_pixel: s.gate == Gate::PerPixel,
        }
    }

    pub fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        let sa = x.clone() + self.spatial.forward(self.norm_sa.forward(x.clone()));
        let sa = sa.clone() + self.ffn_sa.forward(self.norm_sa_ffn.forward(sa));
        let ca = x.clone() + self.channel.forward(self.norm_ca.forward(x));
        let ca = ca.clone() + self.ffn_ca.forward(self.norm_ca_ffn.forward(ca));
        if current() == Kernels::Fast {
            return self.fuse_fast(sa, ca);
        }
        let f = pointwise(
            &self.fuse_out,
            gelu(pointwise(
                &self.fuse_in,
                Tensor::cat(vec![sa.clone(), ca.clone()], 1),
            )),
        );
        let w = if self.per_pixel {
            sigmoid(f.mean_dim(1))
        } else {
            sigmoid(f.mean_dim(2).mean_dim(3))
        };
        sa * w.clone() + ca * (w.neg().add_scalar(1.0))
    }

    /// The fusion gate without `fuse_out`'s map: the gate reads only a mean of it, and a
    /// mean of a 1×1 convolution is the convolution of the mean. Per pixel, the channel mean
    /// of `W·g + b` is `mean_rows(W)·g + mean(b)` (one row instead of `C`); per channel, the
    /// spatial mean is `W·mean(g) + b` (one pixel instead of all). Then `ca + (sa − ca)·w`,
    /// on the CPU without gradients in one pass ([`super::fuse_direct`]).
    fn fuse_fast(&self, sa: Tensor<4>, ca: Tensor<4>) -> Tensor<4> {
        let [b, c, h, w] = sa.dims();
        let g = gelu(pointwise(
            &self.fuse_in,
            Tensor::cat(vec![sa.clone(), ca.clone()], 1),
        ));
        let weight = self.fuse_out.weight.val().reshape([c, c]);
        let bias = self
            .fuse_out
            .bias
            .as_ref()
            .map(|bias| bias.val())
            .expect("the fusion's 1x1 convolutions have a bias");
        let gate = if self.per_pixel {
            let row = weight.mean_dim(0).reshape([1, 1, c]);
            let f = row.matmul(g.reshape([b, c, h * w])) + bias.mean().reshape([1, 1, 1]);
            sigmoid(f).reshape([b, 1, h, w])
        } else {
            let pooled = g.mean_dim(2).mean_dim(3).reshape([b, c, 1]);
            let f = weight.reshape([1, c, c]).matmul(pooled) + bias.reshape([1, c, 1]);
            sigmoid(f).reshape([b, c, 1, 1])
        };
        if direct_applies(&sa) {
            let device = sa.device();
            let gate_dims = gate.dims();
            let out = super::fuse_direct::blend(
                &host(sa),
                &host(ca),
                &host(gate),
                [b, c, h, w],
                gate_dims,
            );
            return Tensor::from_data(TensorData::new(out, [b, c, h, w]), &device);
        }
        ca.clone() + (sa - ca) * gate
    }
}
