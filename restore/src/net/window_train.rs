//! STAF's window attention for training on the CPU: the direct forward of
//! [`super::window_direct`] with a hand-written backward.
//!
//! The tensor formulation copies every overlapping key window out of the maps, splits heads,
//! runs burn's attention and merges the windows back, and autodiff records each step: its
//! matrix-product, softmax and copy gradients were a third of a `tiny` training step. Here
//! the forward reads the maps directly (nothing is kept but the inputs), and the backward
//! recomputes each window's softmax and forms, per window and head,
//! `dV = Pᵀ·dO`, `dS = P ⊙ (dO·Vᵀ − rowsum(P ⊙ dO·Vᵀ))`, `dQ = s·dS·K`, `dK = s·dSᵀ·Q`, and
//! the position logits' gradient `Σ dS` over windows. Query pixels belong to one window, so
//! `dQ` is written in place; key windows overlap, so each task adds its keys' gradients into
//! a band of rows of its own, and the bands are summed in task order (a fixed order: the same
//! bits on every run). Registered with burn as a backend extension ([`WindowTrainOps`]); it
//! stands in only on burn's CPU backend under autodiff.

use super::window_direct::{WindowSpec, attend_maps, exp_nonpositive, head_dim_supported};
use burn::backend::autodiff::NodeId;
use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::flex::FlexTensor;
use burn::backend::{Autodiff, Backend, Dispatch, Flex, backend_extension, tensor::FloatTensor};
use burn::tensor::{Tensor, TensorData};
use rayon::prelude::*;

/// Whether [`attend_tensor`] serves a layer of `c` channels in `heads` heads.
pub fn supported(c: usize, heads: usize) -> bool {
    c.is_multiple_of(heads) && head_dim_supported(c / heads)
}

/// Window attention of the maps `q, k, v: [b, c, h, w]` with position logits
/// `bias: [heads, win², kwin²]` (keys outside the map left out) → `[b, c, h, w]`, through
/// [`WindowTrainOps`] (on burn's CPU backend under autodiff; see [`supported`]).
pub fn attend_tensor(
    q: Tensor<4>,
    k: Tensor<4>,
    v: Tensor<4>,
    bias: Tensor<3>,
    win: usize,
    kwin: usize,
) -> Tensor<4> {
    Tensor::<4>::from_dispatch(<Dispatch as WindowTrainOps>::window_attention(
        q.into_dispatch(),
        k.into_dispatch(),
        v.into_dispatch(),
        bias.into_dispatch(),
        win,
        kwin,
    ))
}

#[backend_extension(Flex, Autodiff)]
pub trait WindowTrainOps: Backend {
    /// `q, k, v: [b, c, h, w]`, `bias: [heads, win², kwin²]` → `[b, c, h, w]`.
    fn window_attention(
        q: FloatTensor<Self>,
        k: FloatTensor<Self>,
        v: FloatTensor<Self>,
        bias: FloatTensor<Self>,
        win: usize,
        kwin: usize,
    ) -> FloatTensor<Self>;
}

fn slice(t: &FlexTensor) -> &[f32] {
    t.as_slice::<f32>()
        .expect("the restorer's maps are f32 on the CPU")
}

fn dims<const D: usize>(t: &FlexTensor) -> [usize; D] {
    let s = t.layout().shape();
    std::array::from_fn(|i| s[i])
}

impl WindowTrainOps for Flex {
    fn window_attention(
        q: FlexTensor,
        k: FlexTensor,
        v: FlexTensor,
        bias: FlexTensor,
        win: usize,
        kwin: usize,
    ) -> FlexTensor {
        let (q, k, v, bias) = (
            q.to_contiguous(),
            k.to_contiguous(),
            v.to_contiguous(),
            bias.to_contiguous(),
        );
        let [b, c, h, w] = dims::<4>(&q);
        let heads = dims::<3>(&bias)[0];
        let spec = WindowSpec {
            heads,
            win,
            kwin,
            share: 1,
            pos_q: None,
            pos_k: None,
            bias: Some(slice(&bias)),
        };
        let out = attend_maps(slice(&q), slice(&k), slice(&v), [c, h, w], &spec)
            .expect("a supported head width");
        FlexTensor::from_data(TensorData::new(out, [b, c, h, w]))
    }
}

/// The gradients of [`attend_maps`] (one query map per output map, position logits, no
/// position embeddings) from the output gradient `dout`: `(dq, dk, dv, dbias)`.
pub fn attend_backward(
    q: &[f32],
    k: &[f32],
    v: &[f32],
    dout: &[f32],
    bias: &[f32],
    [b, c, h, w]: [usize; 4],
    [heads, win, kwin]: [usize; 3],
) -> (Vec<f32>, Vec<f32>, Vec<f32>, Vec<f32>) {
    let z = Sizes {
        c,
        h,
        w,
        heads,
        win,
        kwin,
    };
    match c / heads {
        4 => run::<4>(q, k, v, dout, bias, b, z),
        8 => run::<8>(q, k, v, dout, bias, b, z),
        16 => run::<16>(q, k, v, dout, bias, b, z),
        32 => run::<32>(q, k, v, dout, bias, b, z),
        d => panic!("window attention with {d} channels per head"),
    }
}

#[derive(Clone, Copy)]
struct Sizes {
    c: usize,
    h: usize,
    w: usize,
    heads: usize,
    win: usize,
    kwin: usize,
}

/// One task's share: `dq` for its strip of window rows (`[c, win, w]`), `dk` and `dv` for
/// the band of map rows its key windows cover (`[c, kwin, w]`, rows from `wy·win − pad`),
/// and its windows' share of the position logits' gradient.
struct StripGrads {
    dq: Vec<f32>,
    dk: Vec<f32>,
    dv: Vec<f32>,
    dbias: Vec<f32>,
}

fn run<const D: usize>(
    q: &[f32],
    k: &[f32],
    v: &[f32],
    dout: &[f32],
    bias: &[f32],
    b: usize,
    z: Sizes,
) -> (Vec<f32>, Vec<f32>, Vec<f32>, Vec<f32>) {
    let Sizes {
        c,
        h,
        w,
        heads,
        win,
        kwin,
    } = z;
    let plane = h * w;
    let nh = h / win;
    let pad = (kwin - win) / 2;
    let parts: Vec<StripGrads> = (0..b * nh)
        .into_par_iter()
        .map(|task| strip::<D>(task, q, k, v, dout, bias, z))
        .collect();
    let mut dq = vec![0.0f32; b * c * plane];
    let mut dk = vec![0.0f32; b * c * plane];
    let mut dv = vec![0.0f32; b * c * plane];
    let mut dbias = vec![0.0f32; heads * win * win * kwin * kwin];
    for (task, part) in parts.iter().enumerate() {
        let (g, wy) = (task / nh, task % nh);
        for ch in 0..c {
            let map = (g * c + ch) * plane;
            dq[map + wy * win * w..][..win * w]
                .copy_from_slice(&part.dq[ch * win * w..][..win * w]);
            for ky in 0..kwin {
                let Some(y) = (wy * win + ky).checked_sub(pad).filter(|&y| y < h) else {
                    continue;
                };
                let band = (ch * kwin + ky) * w;
                for (d, s) in [(&mut dk, &part.dk), (&mut dv, &part.dv)] {
                    for (o, &g) in d[map + y * w..][..w].iter_mut().zip(&s[band..][..w]) {
                        *o += g;
                    }
                }
            }
        }
        for (o, &g) in dbias.iter_mut().zip(&part.dbias) {
            *o += g;
        }
    }
    (dq, dk, dv, dbias)
}

fn strip<const D: usize>(
    task: usize,
    q: &[f32],
    k: &[f32],
    v: &[f32],
    dout: &[f32],
    bias: &[f32],
    z: Sizes,
) -> StripGrads {
    #[cfg(target_arch = "x86_64")]
    if base::isa::Isa::chosen() != base::isa::Isa::Portable {
        // SAFETY: `Isa::chosen` names a build the CPU has, and every build past the
        // portable one has AVX2.
        return unsafe { strip_avx2::<D>(task, q, k, v, dout, bias, z) };
    }
    strip_body::<D>(task, q, k, v, dout, bias, z)
}

/// The same code compiled for AVX2 (no multiply-add contracted: the portable build's bits).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn strip_avx2<const D: usize>(
    task: usize,
    q: &[f32],
    k: &[f32],
    v: &[f32],
    dout: &[f32],
    bias: &[f32],
    z: Sizes,
) -> StripGrads {
    strip_body::<D>(task, q, k, v, dout, bias, z)
}

#[inline(always)]
fn strip_body<const D: usize>(
    task: usize,
    q: &[f32],
    k: &[f32],
    v: &[f32],
    dout: &[f32],
    bias: &[f32],
    z: Sizes,
) -> StripGrads {
    let Sizes {
        c,
        h,
        w,
        heads,
        win,
        kwin,
    } = z;
    let plane = h * w;
    let (nh, nw) = (h / win, w / win);
    let (lq, lk) = (win * win, kwin * kwin);
    let pad = (kwin - win) / 2;
    let scale = (D as f32).powf(-0.5);
    let (g, wy) = (task / nh, task % nh);
    let at = g * c * plane..(g + 1) * c * plane;
    let (qmap, kmap, vmap, omap) = (&q[at.clone()], &k[at.clone()], &v[at.clone()], &dout[at]);
    let mut out = StripGrads {
        dq: vec![0.0f32; c * win * w],
        dk: vec![0.0f32; c * kwin * w],
        dv: vec![0.0f32; c * kwin * w],
        dbias: vec![0.0f32; heads * lq * lk],
    };
    // Per window and head: queries (scaled) and output gradients by query, keys and values by
    // key, each `[n, D]`; the softmax `p` and its gradient `ds`, `[lq, n]`.
    let mut qb = vec![[0.0f32; D]; lq];
    let mut ob = vec![[0.0f32; D]; lq];
    let mut kb = vec![[0.0f32; D]; lk];
    let mut vb = vec![[0.0f32; D]; lk];
    let mut dkb = vec![[0.0f32; D]; lk];
    let mut dvb = vec![[0.0f32; D]; lk];
    let mut p = vec![0.0f32; lq * lk];
    let mut ds = vec![0.0f32; lq * lk];
    // (slot in the key window, pixel in the map, pixel in the band)
    let mut inside: Vec<(usize, usize, usize)> = Vec::with_capacity(lk);
    for wx in 0..nw {
        let (y0, x0) = (wy * win, wx * win);
        inside.clear();
        for ky in 0..kwin {
            for kx in 0..kwin {
                let y = (y0 + ky) as isize - pad as isize;
                let x = (x0 + kx) as isize - pad as isize;
                if (0..h as isize).contains(&y) && (0..w as isize).contains(&x) {
                    let px = y as usize * w + x as usize;
                    inside.push((ky * kwin + kx, px, ky * w + x as usize));
                }
            }
        }
        let n = inside.len();
        for head in 0..heads {
            let ch0 = head * D;
            for i in 0..D {
                let ch = (ch0 + i) * plane;
                for qi in 0..lq {
                    let px = (y0 + qi / win) * w + x0 + qi % win;
                    qb[qi][i] = qmap[ch + px] * scale;
                    ob[qi][i] = omap[ch + px];
                }
                for (j, &(_, px, _)) in inside.iter().enumerate() {
                    kb[j][i] = kmap[ch + px];
                    vb[j][i] = vmap[ch + px];
                }
            }
            let hb = &bias[head * lq * lk..][..lq * lk];
            // Softmax rows, as the forward computes them.
            for qi in 0..lq {
                let row = &mut p[qi * n..][..n];
                for (l, (kj, &(slot, _, _))) in row.iter_mut().zip(kb.iter().zip(&inside)) {
                    let dot: f32 = qb[qi].iter().zip(kj).map(|(a, b)| a * b).sum();
                    *l = dot + hb[qi * lk + slot];
                }
                let max = row.iter().fold(f32::NEG_INFINITY, |m, &l| m.max(l));
                for l in row.iter_mut() {
                    *l = exp_nonpositive(*l - max);
                }
                let inv = 1.0 / row.iter().sum::<f32>();
                row.iter_mut().for_each(|l| *l *= inv);
            }
            // dV = Pᵀ dO; dP = dO Vᵀ; dS = P (dP − rowsum(P dP)).
            dvb[..n].iter_mut().for_each(|r| *r = [0.0; D]);
            for qi in 0..lq {
                let prow = &p[qi * n..][..n];
                let dsrow = &mut ds[qi * n..][..n];
                let mut total = 0.0f32;
                for (j, (d, &pj)) in dsrow.iter_mut().zip(prow).enumerate() {
                    let dp: f32 = ob[qi].iter().zip(&vb[j]).map(|(a, b)| a * b).sum();
                    *d = dp;
                    total += pj * dp;
                    for (a, &o) in dvb[j].iter_mut().zip(&ob[qi]) {
                        *a += pj * o;
                    }
                }
                for (d, &pj) in dsrow.iter_mut().zip(prow) {
                    *d = pj * (*d - total);
                }
            }
            // dQ = s·dS·K (into the strip), dK = dSᵀ·(s·Q), dbias += dS.
            dkb[..n].iter_mut().for_each(|r| *r = [0.0; D]);
            let db = &mut out.dbias[head * lq * lk..][..lq * lk];
            for qi in 0..lq {
                let dsrow = &ds[qi * n..][..n];
                let mut dq = [0.0f32; D];
                for (j, &d) in dsrow.iter().enumerate() {
                    for ((a, &kv), (bk, &qv)) in dq
                        .iter_mut()
                        .zip(&kb[j])
                        .zip(dkb[j].iter_mut().zip(&qb[qi]))
                    {
                        *a += d * kv;
                        *bk += d * qv;
                    }
                    db[qi * lk + inside[j].0] += d;
                }
                let (qy, qx) = (qi / win, qi % win);
                for (i, a) in dq.iter().enumerate() {
                    out.dq[((ch0 + i) * win + qy) * w + x0 + qx] = a * scale;
                }
            }
            for (j, &(_, _, band)) in inside.iter().enumerate() {
                for i in 0..D {
                    let at = (ch0 + i) * kwin * w + band;
                    out.dk[at] += dkb[j][i];
                    out.dv[at] += dvb[j][i];
                }
            }
        }
    }
    out
}

#[derive(Debug)]
struct WindowBackward {
    win: usize,
    kwin: usize,
}

impl Backward<Flex, 4> for WindowBackward {
    type State = [NodeId; 4];

    fn backward(
        self,
        ops: Ops<Self::State, 4>,
        grads: &mut Gradients,
        checkpointer: &mut Checkpointer,
    ) {
        let dout = grads.consume::<Flex>(&ops.node).to_contiguous();
        let [q, k, v, bias]: [FlexTensor; 4] = ops
            .state
            .map(|id| checkpointer.retrieve_node_output::<FlexTensor>(id));
        let (q, k, v, bias) = (
            q.to_contiguous(),
            k.to_contiguous(),
            v.to_contiguous(),
            bias.to_contiguous(),
        );
        let d = dims::<4>(&q);
        let bias_dims = dims::<3>(&bias);
        let (dq, dk, dv, dbias) = attend_backward(
            slice(&q),
            slice(&k),
            slice(&v),
            slice(&dout),
            slice(&bias),
            d,
            [bias_dims[0], self.win, self.kwin],
        );
        let tensors = [
            FlexTensor::from_data(TensorData::new(dq, d)),
            FlexTensor::from_data(TensorData::new(dk, d)),
            FlexTensor::from_data(TensorData::new(dv, d)),
            FlexTensor::from_data(TensorData::new(dbias, bias_dims)),
        ];
        for (parent, grad) in ops.parents.into_iter().zip(tensors) {
            if let Some(node) = parent {
                grads.register::<Flex>(node.id, grad);
            }
        }
    }
}

impl<C: CheckpointStrategy> WindowTrainOps for Autodiff<Flex, C> {
    fn window_attention(
        q: FloatTensor<Self>,
        k: FloatTensor<Self>,
        v: FloatTensor<Self>,
        bias: FloatTensor<Self>,
        win: usize,
        kwin: usize,
    ) -> FloatTensor<Self> {
        let backward = WindowBackward { win, kwin };
        match backward
            .prepare::<C>([q.node(), k.node(), v.node(), bias.node()])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(mut prep) => {
                let state = [
                    prep.checkpoint(&q),
                    prep.checkpoint(&k),
                    prep.checkpoint(&v),
                    prep.checkpoint(&bias),
                ];
                let y = Flex::window_attention(
                    q.into_primitive(),
                    k.into_primitive(),
                    v.into_primitive(),
                    bias.into_primitive(),
                    win,
                    kwin,
                );
                prep.finish(state, y)
            }
            OpsKind::UnTracked(prep) => prep.finish(Flex::window_attention(
                q.into_primitive(),
                k.into_primitive(),
                v.into_primitive(),
                bias.into_primitive(),
                win,
                kwin,
            )),
        }
    }
}
