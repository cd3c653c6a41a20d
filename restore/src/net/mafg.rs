//! MAFG: guidance from the 13 Wiener images. Each filter output is embedded per pixel; the
//! median image's embedding queries every filter's embedding in overlapping windows; each
//! filter's answer is projected back to RGB, and the 13 RGB answers (39 channels) are
//! embedded by a 3×3 conv into the body's width.

use burn::module::{Module, Param};
use burn::nn::conv::Conv2d;
use burn::tensor::{Device, Tensor, TensorData};

use super::kernels::{Kernels, current, direct_applies, host};
use super::layers::{ChannelNorm, conv, pointwise};
use super::window::{attend, attend_fused, key_mask, key_windows, merge_windows, query_windows};
use super::window_direct::{WindowSpec, attend_maps, head_dim_supported};
use aberration::wiener::{BANK_MEDIAN, BANK_SIZE};

#[derive(Module, Debug)]
pub struct CrossAttentionGuide {
    pub embed: Conv2d,
    pub norm: ChannelNorm,
    pub q: Conv2d,
    pub k: Conv2d,
    pub v: Conv2d,
    /// Learned position embeddings of the query and key window positions.
    pub pos_q: Param<Tensor<2>>,
    pub pos_k: Param<Tensor<2>>,
    pub out: Conv2d,
    pub heads: usize,
    pub win: usize,
    pub kwin: usize,
    /// Add each filter's image to its answer (the guide learns a correction to the bank).
    pub residual: bool,
}

impl CrossAttentionGuide {
    pub fn new(
        embed: usize,
        heads: usize,
        head_dim: usize,
        win: usize,
        kwin: usize,
        residual: bool,
        device: &Device,
    ) -> Self {
        let hd = heads * head_dim;
        let normal = burn::tensor::Distribution::Normal(0.0, 0.02);
        Self {
            embed: conv(3, embed, 1, true, device),
            norm: ChannelNorm::new(embed, device),
            q: conv(embed, hd, 1, true, device),
            k: conv(embed, hd, 1, true, device),
            v: conv(embed, hd, 1, true, device),
            pos_q: Param::from_tensor(Tensor::random([win * win, hd], normal, device)),
            pos_k: Param::from_tensor(Tensor::random([kwin * kwin, hd], normal, device)),
            out: conv(hd, 3, 1, true, device),
            heads,
            win,
            kwin,
            residual,
        }
    }

    /// `bank: [b, 39, h, w]` (filter-major) → `[b, 39, h, w]`.
    pub fn forward(&self, bank: Tensor<4>) -> Tensor<4> {
        let [b, _, h, w] = bank.dims();
        let input = self.residual.then(|| bank.clone());
        let m = BANK_SIZE;
        let feats = self
            .norm
            .forward(pointwise(&self.embed, bank.reshape([b * m, 3, h, w])));
        let e = feats.dims()[1];
        let median = feats
            .clone()
            .reshape([b, m, e, h, w])
            .narrow(1, BANK_MEDIAN, 1)
            .reshape([b, e, h, w]);
        let q = pointwise(&self.q, median);
        let k = pointwise(&self.k, feats.clone());
        let v = pointwise(&self.v, feats);
        let rgb = pointwise(&self.out, self.answers(q, k, v));
        let rgb = rgb.reshape([b, 3 * m, h, w]);
        match input {
            Some(bank) => rgb + bank,
            None => rgb,
        }
    }

    /// Every filter's answer map `[b·m, hd, h, w]` from the median's query map `[b, hd, h, w]`
    /// and the filters' key and value maps `[b·m, hd, h, w]`, by the kernels [`current`]
    /// names (the direct one where it applies, in training with its hand-written backward).
    fn answers(&self, q: Tensor<4>, k: Tensor<4>, v: Tensor<4>) -> Tensor<4> {
        let [b, hd, h, w] = q.dims();
        let m = BANK_SIZE;
        let device = q.device();
        if current() == Kernels::Fast && direct_applies(&q) && head_dim_supported(hd / self.heads) {
            let (pos_q, pos_k) = (host(self.pos_q.val()), host(self.pos_k.val()));
            let spec = WindowSpec {
                heads: self.heads,
                win: self.win,
                kwin: self.kwin,
                share: m,
                pos_q: Some(&pos_q),
                pos_k: Some(&pos_k),
                bias: None,
            };
            let out = attend_maps(&host(q), &host(k), &host(v), [hd, h, w], &spec)
                .expect("a supported head width");
            return Tensor::from_data(TensorData::new(out, [b * m, hd, h, w]), &device);
        }
        if current() == Kernels::Fast
            && super::conv_train::trained_applies(&q)
            && super::window_train::supported(hd, self.heads)
        {
            let (pos_q, pos_k) = (self.pos_q.val(), self.pos_k.val());
            return super::window_train::cross_tensor(
                q, k, v, pos_q, pos_k, self.heads, self.win, self.kwin,
            );
        }
        let q = query_windows(q, self.win) + self.pos_q.val().unsqueeze_dim::<3>(0);
        let k = key_windows(k, self.win, self.kwin) + self.pos_k.val().unsqueeze_dim::<3>(0);
        let v = key_windows(v, self.win, self.kwin);
        // Every filter is asked the same question: repeat the median's query windows.
        let [nq, lq, hd] = q.dims();
        let q =
            q.reshape([b, 1, nq / b, lq, hd])
                .repeat_dim(1, m)
                .reshape([b * m * (nq / b), lq, hd]);
        let out = match current() {
            Kernels::Reference => {
                let mask = key_mask(h, w, self.win, self.kwin, &device)
                    .unsqueeze_dim::<4>(1)
                    .repeat_dim(0, b * m);
                attend(q, k, v, self.heads, mask)
            }
            Kernels::Fast => {
                let mask = key_mask(h, w, self.win, self.kwin, &device);
                let [n, _, lk] = mask.dims();
                let bias =
                    Tensor::zeros([n, self.heads, lq, lk], &device) + mask.unsqueeze_dim::<4>(1);
                attend_fused(q, k, v, self.heads, bias)
            }
        };
        merge_windows(out, b * m, h, w, self.win)
    }
}
