//! Small building blocks: convolutions as Restormer uses them, LayerNorm over channels, the
//! gated-Dconv feed-forward network and query enhancement.

use burn::module::{Module, Param};
use burn::nn::PaddingConfig2d;
use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::tensor::module::avg_pool2d;
use burn::tensor::ops::AvgPoolOptions;
use burn::tensor::{Device, Tensor, TensorData};

use super::gate_direct::gated_depthwise;
use super::kernels::{Kernels, current, direct_applies, extension_applies, host};

/// A layer made by [`conv`] applied to `x`: a dense 3×3 one on the CPU through the plane
/// loops of [`super::conv_train`] (in training for its hand-written backward, burn's weight
/// gradient being slow; in inference because its forward beats burn's im2col and matrix
/// product too), else burn's `Conv2d`.
pub fn conv3(conv: &Conv2d, x: Tensor<4>) -> Tensor<4> {
    if is_plain(conv, 3) && extension_applies(&x) {
        return super::conv_train::dense3(conv, x);
    }
    conv.forward(x)
}

/// GELU; on burn's CPU backend with the vectorised erf of [`super::gelu`] (forward and
/// backward) when the fast kernels run.
pub fn gelu(x: Tensor<4>) -> Tensor<4> {
    if extension_applies(&x) {
        return super::gelu::gelu_tensor(x);
    }
    burn::tensor::activation::gelu(x)
}

/// Whether `conv` is a dense `k × k` convolution with same-size output, as [`conv`] makes
/// them (stride 1, no dilation, one group, `k / 2` padding): the shape the hand-written
/// kernels are written for.
fn is_plain(conv: &Conv2d, k: usize) -> bool {
    let p = k / 2;
    conv.kernel_size == [k, k]
        && conv.stride == [1, 1]
        && conv.dilation == [1, 1]
        && conv.groups == 1
        && conv.padding == PaddingConfig2d::Explicit(p, p, p, p)
}

/// `k × k` convolution with same-size output.
pub fn conv(cin: usize, cout: usize, k: usize, bias: bool, device: &Device) -> Conv2d {
    Conv2dConfig::new([cin, cout], [k, k])
        .with_padding(PaddingConfig2d::Explicit(k / 2, k / 2, k / 2, k / 2))
        .with_bias(bias)
        .init(device)
}

/// A 1×1 convolution: on burn's CPU backend with the fast kernels through the register-blocked
/// loop of [`super::pointwise`] (forward and backward); on another backend in training as a
/// matrix product over the pixels (burn's convolution weight gradient takes a generic path
/// there), else burn's `Conv2d`.
pub fn pointwise(conv: &Conv2d, x: Tensor<4>) -> Tensor<4> {
    if is_plain(conv, 1) && extension_applies(&x) {
        // The weights read before the bias, as burn's `Conv2d` reads them: burn draws a
        // parameter's initial values when it is first read, so this order is the network's
        // initialisation from a seed.
        let weight = conv.weight.val();
        let bias = conv.bias.as_ref().map(|b| b.val());
        return super::pointwise::pointwise_tensor(x, weight, bias);
    }
    let weight = conv.weight.val();
    let [cout, cin, kh, kw] = weight.dims();
    if current() == Kernels::Reference || kh != 1 || kw != 1 || !weight.is_require_grad() {
        return conv.forward(x);
    }
    let [b, _, h, w] = x.dims();
    let y = weight
        .reshape([1, cout, cin])
        .matmul(x.reshape([b, cin, h * w]));
    let y = match &conv.bias {
        Some(bias) => y + bias.val().reshape([1, cout, 1]),
        None => y,
    };
    y.reshape([b, cout, h, w])
}

/// In training on the CPU, a 1×1 convolution's output (no bias) in `N` equal parts along its
/// channels, as the channel attention splits its q/k/v map, each made from its share of the
/// weights; `None` elsewhere (the caller splits the whole map).
///
/// Splitting the whole map in training gives each part a backward that fills a zero map of all
/// its channels, and burn sums the `N`; and its views are copied when reshaped. The same
/// values; the weights read as [`pointwise`] reads them (burn draws a parameter's initial
/// values when it is first read). Not for the window attention's q/k/v: there, three narrow
/// weight gradients cost more than the split saves (RESULTS.md, issue 50).
pub fn trained_parts<const N: usize>(conv: &Conv2d, x: &Tensor<4>) -> Option<[Tensor<4>; N]> {
    if conv.bias.is_some()
        || !is_plain(conv, 1)
        || current() != Kernels::Fast
        || !super::conv_train::trained_applies(x)
    {
        return None;
    }
    let weight = conv.weight.val();
    let c = weight.dims()[0] / N;
    Some(std::array::from_fn(|i| {
        let part = weight.clone().narrow(0, i * c, c);
        super::pointwise::pointwise_tensor(x.clone(), part, None)
    }))
}

/// A depthwise 3×3 layer applied to `x`: in training on the CPU through the hand-written
/// kernels of [`super::depthwise`] (burn's grouped-convolution weight gradient is slow), else
/// burn's `Conv2d`.
pub fn depthwise(conv: &Conv2d, x: Tensor<4>) -> Tensor<4> {
    if current() == Kernels::Fast && super::conv_train::trained_applies(&x) {
        return super::conv_train::depthwise3(conv, x);
    }
    conv.forward(x)
}

/// Depthwise 3×3 convolution without bias.
pub fn depthwise3(c: usize, device: &Device) -> Conv2d {
    Conv2dConfig::new([c, c], [3, 3])
        .with_padding(PaddingConfig2d::Explicit(1, 1, 1, 1))
        .with_groups(c)
        .with_bias(false)
        .init(device)
}

/// The LayerNorm's ε (Restormer's).
const NORM_EPS: f32 = 1e-5;

/// LayerNorm over the channels of every pixel, with bias (Restormer's "WithBias"); on the CPU
/// in two passes, with a hand-written backward ([`super::norm_direct`]).
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
        if extension_applies(&x) {
            let (weight, bias) = (self.weight.val(), self.bias.val());
            return super::norm_direct::norm_tensor(x, weight, bias, NORM_EPS);
        }
        let c = x.dims()[1];
        let mean = x.clone().mean_dim(1);
        let centred = x - mean;
        let var = centred.clone().powf_scalar(2.0).mean_dim(1);
        let normed = centred / var.add_scalar(NORM_EPS as f64).sqrt();
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
        let h = pointwise(&self.project_in, x);
        if current() == Kernels::Fast && direct_applies(&h) {
            let dims = h.dims();
            let [b, c2, hh, w] = dims;
            let device = h.device();
            let weight = host(self.depthwise.weight.val());
            let gated = gated_depthwise(&host(h), &weight, dims);
            let gated = Tensor::from_data(TensorData::new(gated, [b, c2 / 2, hh, w]), &device);
            return pointwise(&self.project_out, gated);
        }
        if current() == Kernels::Fast && super::conv_train::trained_applies(&h) {
            let gated = super::gate_train::gated_tensor(&self.depthwise, h);
            return pointwise(&self.project_out, gated);
        }
        let h = depthwise(&self.depthwise, h);
        let mut parts = h.chunk(2, 1);
        let x2 = parts.pop().expect("two halves");
        let x1 = parts.pop().expect("two halves");
        pointwise(&self.project_out, gelu(x1) * x2)
    }
}

/// Query enhancement: `Q − AvgPool_k(Q)`, stride 1, zero padding (counted in the mean), so
/// the query stresses what differs from its neighbourhood. `k = 0` or `1` leaves `Q` alone.
///
/// The box is separable: a `k × 1` pass then a `1 × k` pass add the same terms as one
/// `k × k` pool (zero padding counted in both), with `2k` reads per pixel instead of `k²`;
/// on the CPU straight from the planes ([`super::query_box`]).
pub fn enhance_query(q: Tensor<4>, k: usize) -> Tensor<4> {
    if k <= 1 {
        return q;
    }
    if k % 2 == 1 && extension_applies(&q) {
        return super::query_box::enhance_tensor(q, k);
    }
    let pool = |x: Tensor<4>, kernel: [usize; 2]| {
        avg_pool2d(
            x,
            AvgPoolOptions::new(kernel)
                .with_stride([1, 1])
                .with_padding([kernel[0] / 2, kernel[1] / 2]),
        )
    };
    let pooled = match current() {
        Kernels::Reference => pool(q.clone(), [k, k]),
        Kernels::Fast => pool(pool(q.clone(), [k, 1]), [1, k]),
    };
    q - pooled
}
