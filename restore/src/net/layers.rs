//! Small building blocks: convolutions as Restormer uses them, LayerNorm over channels, the
//! gated-Dconv feed-forward network and query enhancement.

use burn::module::{Module, Param};
use burn::nn::PaddingConfig2d;
use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::tensor::activation::gelu;
use burn::tensor::module::avg_pool2d;
use burn::tensor::ops::AvgPoolOptions;
use burn::tensor::{Device, Tensor};

/// `k × k` convolution with same-size output.
pub fn conv(cin: usize, cout: usize, k: usize, bias: bool, device: &Device) -> Conv2d {
    Conv2dConfig::new([cin, cout], [k, k])
        .with_padding(PaddingConfig2d::Explicit(k / 2, k / 2, k / 2, k / 2))
        .with_bias(bias)
        .init(device)
}

/// Depthwise 3×3 convolution without bias.
pub fn depthwise3(c: usize, device: &Device) -> Conv2d {
    Conv2dConfig::new([c, c], [3, 3])
        .with_padding(PaddingConfig2d::Explicit(1, 1, 1, 1))
        .with_groups(c)
        .with_bias(false)
        .init(device)
}

/// LayerNorm over the channels of every pixel, with bias (Restormer's "WithBias").
#[derive(Module, Debug)]
pub struct ChannelNorm {
    pub weight: Param<Tensor<1>>,
    pub bias: Param<Tensor<1>>,
}

impl ChannelNorm {
    pub fn new(c: usize, device: &Device) -> Self {
        Self {
            weight: Param::from_tensor(Tensor::ones([c], device)),
            bias: Param::from_tensor(Tensor::zeros([c], device)),
        }
    }

    pub fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        let c = x.dims()[1];
        let mean = x.clone().mean_dim(1);
        let centred = x - mean;
        let var = centred.clone().powf_scalar(2.0).mean_dim(1);
        let normed = centred / var.add_scalar(1e-5).sqrt();
        normed * self.weight.val().reshape([1, c, 1, 1]) + self.bias.val().reshape([1, c, 1, 1])
    }
}

/// Gated-Dconv feed-forward network: `W_out(GELU(DW(W_1 x)) ⊙ DW(W_2 x))`.
#[derive(Module, Debug)]
pub struct Gdfn {
    pub project_in: Conv2d,
    pub depthwise: Conv2d,
    pub project_out: Conv2d,
}

impl Gdfn {
    pub fn new(c: usize, hidden: usize, device: &Device) -> Self {
        Self {
            project_in: conv(c, 2 * hidden, 1, false, device),
            depthwise: depthwise3(2 * hidden, device),
            project_out: conv(hidden, c, 1, false, device),
        }
    }

    pub fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        let h = self.depthwise.forward(self.project_in.forward(x));
        let mut parts = h.chunk(2, 1);
        let x2 = parts.pop().expect("two halves");
        let x1 = parts.pop().expect("two halves");
        self.project_out.forward(gelu(x1) * x2)
    }
}

/// Query enhancement: `Q − AvgPool_k(Q)`, stride 1, zero padding (counted in the mean), so
/// the query stresses what differs from its neighbourhood. `k = 0` or `1` leaves `Q` alone.
pub fn enhance_query(q: Tensor<4>, k: usize) -> Tensor<4> {
    if k <= 1 {
        return q;
    }
    let pooled = avg_pool2d(
        q.clone(),
        AvgPoolOptions::new([k, k])
            .with_stride([1, 1])
            .with_padding([k / 2, k / 2]),
    );
    q - pooled
}
