//! Windowed attention with overlapping key windows: non-overlapping `w × w` query windows,
//! each attending to the `wk × wk` window centred on it (`wk = w + w/2`, overlap 0.5).
//! Keys that fall outside the image are masked out, so the result equals full attention with
//! an explicit "key in my window" mask (the tests check exactly that).

use burn::module::{Module, Param};
use burn::nn::conv::Conv2d;
use burn::tensor::activation::softmax;
use burn::tensor::module::attention;
use burn::tensor::ops::{AttentionModuleOptions, PadMode};
use burn::tensor::{Device, Int, Tensor, TensorData};

use super::kernels::{Kernels, current, direct_applies, host};
use super::layers::{conv, enhance_query, pointwise};
use super::window_direct::{WindowSpec, attend_maps, head_dim_supported};

/// Logit added to masked keys: `exp` of it is exactly zero in f32.
const MASKED: f32 = -1e4;

/// `[b, c, h, w]` → `[b·n_windows, win², c]`, windows in row-major order.
pub fn query_windows(x: Tensor<4>, win: usize) -> Tensor<3> {
    let [b, c, h, w] = x.dims();
    let (nh, nw) = (h / win, w / win);
    x.reshape([b, c, nh, win, nw, win])
        .permute([0, 2, 4, 3, 5, 1])
        .reshape([b * nh * nw, win * win, c])
}

/// Inverse of [`query_windows`].
pub fn merge_windows(x: Tensor<3>, b: usize, h: usize, w: usize, win: usize) -> Tensor<4> {
    let c = x.dims()[2];
    let (nh, nw) = (h / win, w / win);
    x.reshape([b, nh, nw, win, win, c])
        .permute([0, 5, 1, 3, 2, 4])
        .reshape([b, c, h, w])
}

/// `[b, c, h, w]` → `[b·n_windows, kwin², c]`: the key window around every query window
/// (zero outside the image). Built from strided views of the zero-padded map (`unfold` per
/// axis), not im2col: burn's padded `unfold4d` runs as a one-hot convolution, `C·kwin²`
/// output channels, which dominated training time.
pub fn key_windows(x: Tensor<4>, win: usize, kwin: usize) -> Tensor<3> {
    let [b, c, h, w] = x.dims();
    let p = (kwin - win) / 2;
    let (nh, nw) = (h / win, w / win);
    x.pad([(p, p), (p, p)], PadMode::Constant(0.0))
        .unfold::<5, _>(2, kwin, win)
        .unfold::<6, _>(3, kwin, win)
        .permute([0, 2, 3, 4, 5, 1])
        .reshape([b * nh * nw, kwin * kwin, c])
}

/// Additive mask `[n_windows, 1, kwin²]`: 0 for keys inside the image, [`MASKED`] outside.
pub fn key_mask(h: usize, w: usize, win: usize, kwin: usize, device: &Device) -> Tensor<3> {
    let p = (kwin - win) as isize / 2;
    let mut m = Vec::with_capacity((h / win) * (w / win) * kwin * kwin);
    for wy in 0..h / win {
        for wx in 0..w / win {
            for ky in 0..kwin as isize {
                for kx in 0..kwin as isize {
                    let y = (wy * win) as isize + ky - p;
                    let x = (wx * win) as isize + kx - p;
                    let inside = (0..h as isize).contains(&y) && (0..w as isize).contains(&x);
                    m.push(if inside { 0.0f32 } else { MASKED });
                }
            }
        }
    }
    let n = m.len() / (kwin * kwin);
    Tensor::from_data(TensorData::new(m, [n, 1, kwin * kwin]), device)
}

/// Index into the relative-position table for every (query, key) pair of a window.
pub fn relative_index(win: usize, kwin: usize) -> Vec<i64> {
    let side = win + kwin - 1;
    let mut idx = Vec::with_capacity(win * win * kwin * kwin);
    for qi in 0..win {
        for qj in 0..win {
            for ki in 0..kwin {
                for kj in 0..kwin {
                    // Offsets qi − ki (in key-window coordinates) shifted to be non-negative.
                    let dy = qi + kwin - 1 - ki;
                    let dx = qj + kwin - 1 - kj;
                    idx.push((dy * side + dx) as i64);
                }
            }
        }
    }
    idx
}

/// Multi-head attention of query windows over key windows. `q: [n, win², heads·d]`,
/// `k, v: [n, kwin², heads·d]`, `bias` broadcast to `[n, heads, win², kwin²]`.
pub fn attend(
    q: Tensor<3>,
    k: Tensor<3>,
    v: Tensor<3>,
    heads: usize,
    bias: Tensor<4>,
) -> Tensor<3> {
    let [n, lq, c] = q.dims();
    let lk = k.dims()[1];
    let d = c / heads;
    let split = |t: Tensor<3>, l: usize| t.reshape([n, l, heads, d]).swap_dims(1, 2);
    let (q, k, v) = (split(q, lq), split(k, lk), split(v, lk));
    let logits = q
        .matmul(k.swap_dims(2, 3))
        .mul_scalar((d as f32).powf(-0.5))
        + bias;
    softmax(logits, 3)
        .matmul(v)
        .swap_dims(1, 2)
        .reshape([n, lq, c])
}

/// [`attend`] as burn's fused attention, which keeps one window's logits at a time instead of
/// a tensor of all of them. `q: [g·n, win², heads·d]`, `k, v: [g·n, kwin², heads·d]` for `g`
/// maps of `n` windows each; `bias: [n, heads, win², kwin²]` (position logits and the key
/// mask) is shared by the `g` maps, which burn broadcasts without copying.
pub fn attend_fused(
    q: Tensor<3>,
    k: Tensor<3>,
    v: Tensor<3>,
    heads: usize,
    bias: Tensor<4>,
) -> Tensor<3> {
    let [total, lq, c] = q.dims();
    let lk = k.dims()[1];
    let d = c / heads;
    let n = bias.dims()[0];
    let g = total / n;
    // Each (window, head) is one attention problem: the windows go where burn puts heads.
    let split = |t: Tensor<3>, l: usize| {
        t.reshape([g, n, l, heads, d])
            .swap_dims(2, 3)
            .reshape([g, n * heads, l, d])
    };
    let options = AttentionModuleOptions {
        scale: Some(f64::from((d as f32).powf(-0.5))),
        ..Default::default()
    };
    let bias = bias.reshape([1, n * heads, lq, lk]);
    attention(
        split(q, lq),
        split(k, lk),
        split(v, lk),
        None,
        Some(bias),
        options,
    )
    .reshape([g, n, heads, lq, d])
    .swap_dims(2, 3)
    .reshape([total, lq, c])
}

/// STAF's spatial branch: window self-attention with relative position logits.
#[derive(Module, Debug)]
pub struct WindowAttention {
    pub qkv: Conv2d,
    pub proj: Conv2d,
    /// `[(win + kwin − 1)², heads]` logits by relative offset.
    pub relative: Param<Tensor<2>>,
    pub heads: usize,
    pub win: usize,
    pub kwin: usize,
    /// Query-enhancement kernel (0: none).
    pub qe: usize,
}

impl WindowAttention {
    pub fn new(
        c: usize,
        heads: usize,
        win: usize,
        kwin: usize,
        qe: usize,
        device: &Device,
    ) -> Self {
        let side = win + kwin - 1;
        Self {
            qkv: conv(c, 3 * c, 1, true, device),
            proj: conv(c, c, 1, true, device),
            relative: Param::from_tensor(Tensor::random(
                [side * side, heads],
                burn::tensor::Distribution::Normal(0.0, 0.02),
                device,
            )),
            heads,
            win,
            kwin,
            qe,
        }
    }

    /// `[heads, win², kwin²]` relative-position logits.
    fn position_bias(&self) -> Tensor<3> {
        let device = self.relative.val().device();
        let idx = relative_index(self.win, self.kwin);
        let n = idx.len();
        let idx = Tensor::<1, Int>::from_data(TensorData::new(idx, [n]), &device);
        self.relative
            .val()
            .select(0, idx)
            .reshape([self.win * self.win, self.kwin * self.kwin, self.heads])
            .permute([2, 0, 1])
    }

    pub fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        let qkv = pointwise(&self.qkv, x);
        let c = qkv.dims()[1] / 3;
        if current() == Kernels::Fast
            && super::conv_train::trained_applies(&qkv)
            && super::window_train::supported(c, self.heads)
            && (self.qe <= 1 || self.qe % 2 == 1)
        {
            // In training on the CPU, one node from the q/k/v map to the answers (no slices).
            let bias = self.position_bias();
            let answers =
                super::window_train::attend_qkv_tensor(qkv, bias, self.qe, self.win, self.kwin);
            return pointwise(&self.proj, answers);
        }
        let mut parts = qkv.chunk(3, 1);
        let v = parts.pop().expect("qkv");
        let k = parts.pop().expect("qkv");
        let q = enhance_query(parts.pop().expect("qkv"), self.qe);
        pointwise(&self.proj, self.answers(q, k, v))
    }

    /// The attention's answer map `[b, c, h, w]` from the query, key and value maps, by the
    /// kernels [`current`] names (the direct one where it applies, in training with its
    /// hand-written backward).
    fn answers(&self, q: Tensor<4>, k: Tensor<4>, v: Tensor<4>) -> Tensor<4> {
        let [b, c, h, w] = q.dims();
        let device = q.device();
        if current() == Kernels::Fast && direct_applies(&q) && head_dim_supported(c / self.heads) {
            let bias = host(self.position_bias());
            let spec = WindowSpec {
                heads: self.heads,
                win: self.win,
                kwin: self.kwin,
                share: 1,
                pos_q: None,
                pos_k: None,
                bias: Some(&bias),
            };
            let out = attend_maps(&host(q), &host(k), &host(v), [c, h, w], &spec)
                .expect("a supported head width");
            return Tensor::from_data(TensorData::new(out, [b, c, h, w]), &device);
        }
        if current() == Kernels::Fast
            && super::conv_train::trained_applies(&q)
            && super::window_train::supported(c, self.heads)
        {
            let bias = self.position_bias();
            return super::window_train::attend_tensor(q, k, v, bias, self.win, self.kwin);
        }
        let q = query_windows(q, self.win);
        let k = key_windows(k, self.win, self.kwin);
        let v = key_windows(v, self.win, self.kwin);
        let nwin = (h / self.win) * (w / self.win);
        let out = match current() {
            Kernels::Reference => {
                let mask = key_mask(h, w, self.win, self.kwin, &device)
                    .unsqueeze_dim::<4>(1)
                    .repeat_dim(0, b);
                let bias = self.position_bias().unsqueeze_dim::<4>(0) + mask;
                debug_assert_eq!(bias.dims()[0], b * nwin);
                attend(q, k, v, self.heads, bias)
            }
            Kernels::Fast => {
                let mask = key_mask(h, w, self.win, self.kwin, &device).unsqueeze_dim::<4>(1);
                let bias = self.position_bias().unsqueeze_dim::<4>(0) + mask;
                attend_fused(q, k, v, self.heads, bias)
            }
        };
        merge_windows(out, b, h, w, self.win)
    }
}
