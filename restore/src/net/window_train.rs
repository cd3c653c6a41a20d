//! STAF's window attention for training on the CPU: the direct forward of
//! [`super::window_direct`] with a hand-written backward.
//!
//! The tensor formulation copies every overlapping key window out of the maps, splits heads,
//! runs burn's attention and merges the windows back, and autodiff records each step: its
//! matrix-product, softmax and copy gradients were a third of a `tiny` training step. Here
//! the forward reads the maps directly (keeping the inputs and each window's softmax rows),
//! and the backward forms, per window and head,
//! `dV = Pᵀ·dO`, `dS = P ⊙ (dO·Vᵀ − rowsum(P ⊙ dO·Vᵀ))`, `dQ = s·dS·K`, `dK = s·dSᵀ·Q`, and
//! the position logits' gradient `Σ dS` over windows. Query pixels belong to one window, so
//! `dQ` is written in place; key windows overlap, so each task adds its keys' gradients into
//! a band of rows of its own, and the bands are summed in task order (a fixed order: the same
//! bits on every run). Registered with burn as a backend extension ([`WindowTrainOps`]); it
//! stands in only on burn's CPU backend under autodiff.

use super::kernels::{flex_dims, flex_slice};
use super::lanes;
use super::window_direct::{
    WindowSpec, attend_maps, attend_maps_keeping, exp_nonpositive, head_dim_supported, logit_rows,
};
use burn::backend::autodiff::NodeId;
use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::flex::FlexTensor;
use burn::backend::{Autodiff, Backend, Dispatch, Flex, backend_extension, tensor::FloatTensor};
use burn::tensor::{Tensor, TensorData};
use rayon::prelude::*;
use std::sync::Arc;

/// Whether [`attend_tensor`] and [`cross_tensor`] serve a layer of `c` channels in `heads`
/// heads.
pub fn supported(c: usize, heads: usize) -> bool {
    c.is_multiple_of(heads) && head_dim_supported(c / heads)
}

/// STAF's window attention of the maps `q, k, v: [b, c, h, w]` with position logits
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

/// STAF's window attention straight from the `[b, 3c, h, w]` map of its q/k/v convolution
/// (q, k and v its channel thirds), the query enhanced first (`Q − AvgPool_qe(Q)`, `qe` odd,
/// or ≤ 1 for none) → `[b, c, h, w]`: one node where there were three channel slices, the
/// enhancement and the attention. burn's backward of each slice fills a zero map of all 3c
/// channels and the three are summed; here the map's gradient is written once, third by
/// third. The same values as the three nodes, bit for bit (the enhancement is its own
/// adjoint, [`super::query_box`]).
pub fn attend_qkv_tensor(
    qkv: Tensor<4>,
    bias: Tensor<3>,
    qe: usize,
    win: usize,
    kwin: usize,
) -> Tensor<4> {
    Tensor::<4>::from_dispatch(<Dispatch as WindowTrainOps>::window_attention_qkv(
        qkv.into_dispatch(),
        bias.into_dispatch(),
        qe,
        win,
        kwin,
    ))
}

/// MAFG's cross-attention: query maps `q: [b, c, h, w]`, each asked of `share` key and value
/// maps `k, v: [b·share, c, h, w]`, with position embeddings `pos_q: [win², c]` and
/// `pos_k: [kwin², c]` added to queries and keys, `heads` heads → `[b·share, c, h, w]`.
#[allow(clippy::too_many_arguments)]
pub fn cross_tensor(
    q: Tensor<4>,
    k: Tensor<4>,
    v: Tensor<4>,
    pos_q: Tensor<2>,
    pos_k: Tensor<2>,
    heads: usize,
    win: usize,
    kwin: usize,
) -> Tensor<4> {
    Tensor::<4>::from_dispatch(<Dispatch as WindowTrainOps>::cross_attention(
        q.into_dispatch(),
        k.into_dispatch(),
        v.into_dispatch(),
        pos_q.into_dispatch(),
        pos_k.into_dispatch(),
        heads,
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
    /// `qkv: [b, 3c, h, w]`, `bias: [heads, win², kwin²]` → `[b, c, h, w]`, the query
    /// third enhanced with a `qe` box first.
    fn window_attention_qkv(
        qkv: FloatTensor<Self>,
        bias: FloatTensor<Self>,
        qe: usize,
        win: usize,
        kwin: usize,
    ) -> FloatTensor<Self>;
    /// `q: [b, c, h, w]`, `k, v: [b·share, c, h, w]`, `pos_q: [win², c]`,
    /// `pos_k: [kwin², c]` → `[b·share, c, h, w]`.
    #[allow(clippy::too_many_arguments)]
    fn cross_attention(
        q: FloatTensor<Self>,
        k: FloatTensor<Self>,
        v: FloatTensor<Self>,
        pos_q: FloatTensor<Self>,
        pos_k: FloatTensor<Self>,
        heads: usize,
        win: usize,
        kwin: usize,
    ) -> FloatTensor<Self>;
}

/// Which attention a node is, with its sizes; the position terms are the node's fourth
/// (bias) or fourth and fifth (embeddings) inputs.
#[derive(Clone, Copy, Debug)]
enum Kind {
    Window,
    Cross { heads: usize },
}

/// The spec of `kind` over the position terms `pos` (host copies, dense).
fn spec<'a>(
    kind: Kind,
    pos: &'a [FlexTensor],
    win: usize,
    kwin: usize,
    share: usize,
) -> WindowSpec<'a> {
    match kind {
        Kind::Window => WindowSpec {
            heads: flex_dims::<3>(&pos[0])[0],
            win,
            kwin,
            share: 1,
            pos_q: None,
            pos_k: None,
            bias: Some(flex_slice(&pos[0])),
        },
        Kind::Cross { heads } => WindowSpec {
            heads,
            win,
            kwin,
            share,
            pos_q: Some(flex_slice(&pos[0])),
            pos_k: Some(flex_slice(&pos[1])),
            bias: None,
        },
    }
}

/// The attention's output, and with `keep` the softmax of every window ([`Probs`]).
fn forward(
    maps: [FlexTensor; 3],
    pos: Vec<FlexTensor>,
    kind: Kind,
    win: usize,
    kwin: usize,
    keep: bool,
) -> (FlexTensor, Option<Probs>) {
    let [q, k, v] = maps.map(|t| t.to_contiguous());
    let pos: Vec<FlexTensor> = pos.into_iter().map(|t| t.to_contiguous()).collect();
    let [bq, c, h, w] = flex_dims::<4>(&q);
    let g = flex_dims::<4>(&k)[0];
    let spec = spec(kind, &pos, win, kwin, g / bq.max(1));
    let (qs, ks, vs) = (flex_slice(&q), flex_slice(&k), flex_slice(&v));
    let (out, probs) = if keep {
        let (out, kept) =
            attend_maps_keeping(qs, ks, vs, [c, h, w], &spec).expect("a supported head width");
        (out, Some(Probs(Arc::new(kept))))
    } else {
        let out = attend_maps(qs, ks, vs, [c, h, w], &spec).expect("a supported head width");
        (out, None)
    };
    (
        FlexTensor::from_data(TensorData::new(out, [g, c, h, w])),
        probs,
    )
}

/// The softmax rows a forward pass kept for its backward ([`attend_maps_keeping`]'s layout):
/// the backward reads them instead of computing the logits and their softmax again, which
/// was a fifth of its arithmetic.
#[derive(Clone)]
struct Probs(Arc<Vec<Vec<f32>>>);

impl std::fmt::Debug for Probs {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let n: usize = self.0.iter().map(Vec::len).sum();
        write!(f, "Probs({n} values)")
    }
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
        forward([q, k, v], vec![bias], Kind::Window, win, kwin, false).0
    }

    fn window_attention_qkv(
        qkv: FlexTensor,
        bias: FlexTensor,
        qe: usize,
        win: usize,
        kwin: usize,
    ) -> FlexTensor {
        qkv_forward(qkv, bias, qe, win, kwin, false).0
    }

    fn cross_attention(
        q: FlexTensor,
        k: FlexTensor,
        v: FlexTensor,
        pos_q: FlexTensor,
        pos_k: FlexTensor,
        heads: usize,
        win: usize,
        kwin: usize,
    ) -> FlexTensor {
        forward(
            [q, k, v],
            vec![pos_q, pos_k],
            Kind::Cross { heads },
            win,
            kwin,
            false,
        )
        .0
    }
}

/// The enhanced query and the key and value maps (`[b, c, h, w]` each) of a `[b, 3c, h, w]`
/// q/k/v map, as the three channel slices and [`super::query_box::enhance`] give them.
fn split_qkv(qkv: &[f32], [b, c, h, w]: [usize; 4], qe: usize) -> [Vec<f32>; 3] {
    let plane = h * w;
    let third = |part: usize, enhance: bool| {
        super::fresh::filled(b * c * plane, plane, |i, dst| {
            let src = &qkv[((i / c) * 3 * c + part * c + i % c) * plane..][..plane];
            if enhance {
                super::query_box::plane_task(dst, src, qe, h, w);
            } else {
                dst.copy_from_slice(src);
            }
        })
    };
    [third(0, qe > 1), third(1, false), third(2, false)]
}

/// The `[b, 3c, h, w]` gradient of [`split_qkv`]'s input from those of its three maps: the
/// query's through the enhancement (its own adjoint), each written into its third.
fn join_qkv(dq: &[f32], dk: &[f32], dv: &[f32], [b, c, h, w]: [usize; 4], qe: usize) -> Vec<f32> {
    let plane = h * w;
    super::fresh::filled(b * 3 * c * plane, plane, |i, dst| {
        let (item, part, ch) = (i / (3 * c), (i / c) % 3, i % c);
        let src = [dq, dk, dv][part];
        let src = &src[(item * c + ch) * plane..][..plane];
        if part == 0 && qe > 1 {
            super::query_box::plane_task(dst, src, qe, h, w);
        } else {
            dst.copy_from_slice(src);
        }
    })
}

/// What a tracked [`WindowTrainOps::window_attention_qkv`] keeps for its backward: the three
/// maps it attended over and the softmax of every window.
#[derive(Clone)]
struct KeptQkv {
    maps: Arc<[Vec<f32>; 3]>,
    probs: Probs,
}

impl std::fmt::Debug for KeptQkv {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "KeptQkv(3 maps of {}, {:?})",
            self.maps[0].len(),
            self.probs
        )
    }
}

/// The output of [`WindowTrainOps::window_attention_qkv`], and with `keep` what its backward
/// reads.
fn qkv_forward(
    qkv: FlexTensor,
    bias: FlexTensor,
    qe: usize,
    win: usize,
    kwin: usize,
    keep: bool,
) -> (FlexTensor, Option<KeptQkv>) {
    let (qkv, bias) = (qkv.to_contiguous(), bias.to_contiguous());
    let [b, c3, h, w] = flex_dims::<4>(&qkv);
    let c = c3 / 3;
    let [q, k, v] = split_qkv(flex_slice(&qkv), [b, c, h, w], qe);
    let spec = spec(Kind::Window, std::slice::from_ref(&bias), win, kwin, 1);
    let (out, kept) = if keep {
        let (out, probs) =
            attend_maps_keeping(&q, &k, &v, [c, h, w], &spec).expect("a supported head width");
        let kept = KeptQkv {
            maps: Arc::new([q, k, v]),
            probs: Probs(Arc::new(probs)),
        };
        (out, Some(kept))
    } else {
        let out = attend_maps(&q, &k, &v, [c, h, w], &spec).expect("a supported head width");
        (out, None)
    };
    (
        FlexTensor::from_data(TensorData::new(out, [b, c, h, w])),
        kept,
    )
}

#[derive(Debug)]
struct QkvBackward {
    qe: usize,
    win: usize,
    kwin: usize,
}

impl Backward<Flex, 2> for QkvBackward {
    /// The position logits' node and what the forward kept.
    type State = (NodeId, KeptQkv);

    fn backward(
        self,
        ops: Ops<Self::State, 2>,
        grads: &mut Gradients,
        checkpointer: &mut Checkpointer,
    ) {
        let dout = grads.consume::<Flex>(&ops.node).to_contiguous();
        let (bias_id, kept) = ops.state;
        let bias = checkpointer
            .retrieve_node_output::<FlexTensor>(bias_id)
            .to_contiguous();
        let [b, c, h, w] = flex_dims::<4>(&dout);
        let spec = spec(
            Kind::Window,
            std::slice::from_ref(&bias),
            self.win,
            self.kwin,
            1,
        );
        let [q, k, v] = &*kept.maps;
        let g = attend_backward(
            q,
            k,
            v,
            flex_slice(&dout),
            [c, h, w],
            &spec,
            Some(kept.probs.0.as_slice()),
        );
        let [qkv_parent, bias_parent] = ops.parents;
        if let Some(node) = qkv_parent {
            let dqkv = join_qkv(&g.dq, &g.dk, &g.dv, [b, c, h, w], self.qe);
            let dqkv = FlexTensor::from_data(TensorData::new(dqkv, [b, 3 * c, h, w]));
            grads.register::<Flex>(node.id, dqkv);
        }
        if let Some(node) = bias_parent {
            let shape = bias.layout().shape().to_vec();
            grads.register::<Flex>(
                node.id,
                FlexTensor::from_data(TensorData::new(g.dbias, shape)),
            );
        }
    }
}

/// The gradients of [`attend_maps`] from the output gradient `dout` (`[g, c, h, w]`, `g`
/// output maps, `g / spec.share` query maps).
pub struct AttendGrads {
    /// `[g / share, c, h, w]`: each query map's gradient, summed over the maps sharing it.
    pub dq: Vec<f32>,
    pub dk: Vec<f32>,
    pub dv: Vec<f32>,
    /// `[heads, win², kwin²]`, with `spec.bias`; else empty.
    pub dbias: Vec<f32>,
    /// `[win², c]` and `[kwin², c]`, with `spec.pos_q` / `spec.pos_k`; else empty.
    pub dpos_q: Vec<f32>,
    pub dpos_k: Vec<f32>,
}

/// The gradients of [`attend_maps`] for `q: [g / share, c, h, w]`, `k, v, dout: [g, c, h, w]`;
/// `probs`, the softmax [`attend_maps_keeping`] kept for these inputs, or `None` to compute it
/// again (the same bits either way).
pub fn attend_backward(
    q: &[f32],
    k: &[f32],
    v: &[f32],
    dout: &[f32],
    [c, h, w]: [usize; 3],
    spec: &WindowSpec,
    probs: Option<&[Vec<f32>]>,
) -> AttendGrads {
    let z = Sizes { c, h, w };
    match c / spec.heads {
        4 => run::<4>(q, k, v, dout, z, spec, probs),
        8 => run::<8>(q, k, v, dout, z, spec, probs),
        16 => run::<16>(q, k, v, dout, z, spec, probs),
        32 => run::<32>(q, k, v, dout, z, spec, probs),
        d => panic!("window attention with {d} channels per head"),
    }
}

#[derive(Clone, Copy)]
struct Sizes {
    c: usize,
    h: usize,
    w: usize,
}

/// One task's share: `dq` for its strip of window rows (`[c, win, w]`), `dk` and `dv` for
/// the band of map rows its key windows cover (`[c, kwin, w]`, rows from `wy·win − pad`),
/// and its windows' share of the position terms' gradients.
struct StripGrads {
    dq: Vec<f32>,
    dk: Vec<f32>,
    dv: Vec<f32>,
    dbias: Vec<f32>,
    dpos_q: Vec<f32>,
    dpos_k: Vec<f32>,
}

fn add(dst: &mut [f32], src: &[f32]) {
    for (o, &g) in dst.iter_mut().zip(src) {
        *o += g;
    }
}

fn run<const D: usize>(
    q: &[f32],
    k: &[f32],
    v: &[f32],
    dout: &[f32],
    z: Sizes,
    s: &WindowSpec,
    probs: Option<&[Vec<f32>]>,
) -> AttendGrads {
    let Sizes { c, h, w } = z;
    let (win, kwin) = (s.win, s.kwin);
    let plane = h * w;
    let groups = k.len() / (c * plane).max(1);
    let nh = h / win;
    let pad = (kwin - win) / 2;
    let parts: Vec<StripGrads> = (0..groups * nh)
        .into_par_iter()
        .map(|task| {
            strip::<D>(
                task,
                [q, k, v, dout],
                z,
                s,
                probs.map(|p| p[task].as_slice()),
            )
        })
        .collect();
    let size = |on: bool, n: usize| if on { n } else { 0 };
    let mut g = AttendGrads {
        dq: vec![0.0f32; groups / s.share * c * plane],
        dk: vec![0.0f32; groups * c * plane],
        dv: vec![0.0f32; groups * c * plane],
        dbias: vec![0.0f32; size(s.bias.is_some(), s.heads * win * win * kwin * kwin)],
        dpos_q: vec![0.0f32; size(s.pos_q.is_some(), win * win * c)],
        dpos_k: vec![0.0f32; size(s.pos_k.is_some(), kwin * kwin * c)],
    };
    // In task order, so the sums come in a fixed order.
    for (task, part) in parts.iter().enumerate() {
        let (grp, wy) = (task / nh, task % nh);
        for ch in 0..c {
            let qmap = ((grp / s.share) * c + ch) * plane;
            add(
                &mut g.dq[qmap + wy * win * w..][..win * w],
                &part.dq[ch * win * w..][..win * w],
            );
            let map = (grp * c + ch) * plane;
            for ky in 0..kwin {
                let Some(y) = (wy * win + ky).checked_sub(pad).filter(|&y| y < h) else {
                    continue;
                };
                let band = (ch * kwin + ky) * w;
                add(&mut g.dk[map + y * w..][..w], &part.dk[band..][..w]);
                add(&mut g.dv[map + y * w..][..w], &part.dv[band..][..w]);
            }
        }
        add(&mut g.dbias, &part.dbias);
        add(&mut g.dpos_q, &part.dpos_q);
        add(&mut g.dpos_k, &part.dpos_k);
    }
    g
}

fn strip<const D: usize>(
    task: usize,
    maps: [&[f32]; 4],
    z: Sizes,
    s: &WindowSpec,
    kept: Option<&[f32]>,
) -> StripGrads {
    #[cfg(target_arch = "x86_64")]
    if base::isa::Isa::chosen() != base::isa::Isa::Portable {
        // SAFETY: `Isa::chosen` names a build the CPU has, and every build past the
        // portable one has AVX2.
        return unsafe { strip_avx2::<D>(task, maps, z, s, kept) };
    }
    strip_body::<D>(task, maps, z, s, kept)
}

/// The same code compiled for AVX2 (no multiply-add contracted: the portable build's bits).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn strip_avx2<const D: usize>(
    task: usize,
    maps: [&[f32]; 4],
    z: Sizes,
    s: &WindowSpec,
    kept: Option<&[f32]>,
) -> StripGrads {
    strip_body::<D>(task, maps, z, s, kept)
}

/// Keys of one key-window row inside the map: adjacent in the map, in the band and in the
/// window's slots.
struct Run {
    /// The first key's index among the window's keys inside the map, its slot in the key
    /// window, its pixel in the map and in the band.
    key: usize,
    slot: usize,
    px: usize,
    band: usize,
    len: usize,
}

#[inline(always)]
fn strip_body<const D: usize>(
    task: usize,
    maps: [&[f32]; 4],
    z: Sizes,
    s: &WindowSpec,
    kept: Option<&[f32]>,
) -> StripGrads {
    let [q, k, v, dout] = maps;
    let Sizes { c, h, w } = z;
    let (heads, win, kwin) = (s.heads, s.win, s.kwin);
    let plane = h * w;
    let (nh, nw) = (h / win, w / win);
    let (lq, lk) = (win * win, kwin * kwin);
    let pad = (kwin - win) / 2;
    let scale = (D as f32).powf(-0.5);
    let (g, wy) = (task / nh, task % nh);
    let at = |m: usize| m * c * plane..(m + 1) * c * plane;
    let (qmap, kmap, vmap, omap) = (&q[at(g / s.share)], &k[at(g)], &v[at(g)], &dout[at(g)]);
    let size = |on: bool, n: usize| if on { n } else { 0 };
    let mut out = StripGrads {
        dq: vec![0.0f32; c * win * w],
        dk: vec![0.0f32; c * kwin * w],
        dv: vec![0.0f32; c * kwin * w],
        dbias: vec![0.0f32; size(s.bias.is_some(), heads * lq * lk)],
        dpos_q: vec![0.0f32; size(s.pos_q.is_some(), lq * c)],
        dpos_k: vec![0.0f32; size(s.pos_k.is_some(), lk * c)],
    };
    // Per window and head: queries (scaled) and output gradients by query, `[lq, D]`; keys,
    // values and their gradients transposed, `[D, np]`, so that every inner loop runs along
    // contiguous keys (in chunks of 8, rows padded with zeros: [`super::lanes`]) instead of
    // summing across the few channels of a head; the softmax `p` and its gradient `ds`,
    // `[lq, np]`. The products are [`lanes::weighted_rows`] and [`lanes::dots`]: each sum in
    // the order the reference loops (in the tests) take, held in registers.
    let lkp = lanes::padded(lk);
    let mut qb = vec![[0.0f32; D]; lq];
    let mut ob = vec![[0.0f32; D]; lq];
    let mut kt = vec![0.0f32; D * lkp];
    let mut vt = vec![0.0f32; D * lkp];
    let mut dkt = vec![0.0f32; D * lkp];
    let mut dvt = vec![0.0f32; D * lkp];
    let mut p = vec![0.0f32; lq * lkp];
    let mut ds = vec![0.0f32; lq * lkp];
    // The position embeddings by channel (`[c, lq]`, `[c, lk]`), so that a channel's terms
    // are read along the window's pixels.
    let by_channel = |pos: Option<&[f32]>, l: usize| {
        pos.map(|pos| {
            let mut t = vec![0.0f32; c * l];
            for (slot, row) in pos.chunks_exact(c).take(l).enumerate() {
                for (ch, &e) in row.iter().enumerate() {
                    t[ch * l + slot] = e;
                }
            }
            t
        })
    };
    let (pos_q, pos_k) = (by_channel(s.pos_q, lq), by_channel(s.pos_k, lk));
    // A query's pixel from its window's corner (the same offset in the map and in the strip).
    let qrel: Vec<usize> = (0..lq).map(|qi| (qi / win) * w + qi % win).collect();
    // The slots (in the key window) of the keys inside the map, in order, and the same keys
    // by key-window row.
    let mut slots: Vec<usize> = Vec::with_capacity(lk);
    let mut runs: Vec<Run> = Vec::with_capacity(kwin);
    for wx in 0..nw {
        let (y0, x0) = (wy * win, wx * win);
        slots.clear();
        runs.clear();
        for ky in 0..kwin {
            let first = slots.len();
            // The first key of the row inside the map: its pixel in the map and in the band.
            let mut start = None;
            for kx in 0..kwin {
                let y = (y0 + ky) as isize - pad as isize;
                let x = (x0 + kx) as isize - pad as isize;
                if (0..h as isize).contains(&y) && (0..w as isize).contains(&x) {
                    slots.push(ky * kwin + kx);
                    start.get_or_insert((y as usize * w + x as usize, ky * w + x as usize));
                }
            }
            if let Some((px, band)) = start {
                runs.push(Run {
                    key: first,
                    slot: slots[first],
                    px,
                    band,
                    len: slots.len() - first,
                });
            }
        }
        let n = slots.len();
        let np = lanes::padded(n);
        let corner = y0 * w + x0;
        for head in 0..heads {
            let ch0 = head * D;
            for i in 0..D {
                let ch = (ch0 + i) * plane;
                let (qwin, owin) = (&qmap[ch + corner..], &omap[ch + corner..]);
                // `+ 0` without a position term, as the forward adds it (−0 becomes +0).
                match &pos_q {
                    Some(pq) => {
                        let pq = &pq[(ch0 + i) * lq..][..lq];
                        for ((qi, &r), &e) in qrel.iter().enumerate().zip(pq) {
                            qb[qi][i] = (qwin[r] + e) * scale;
                        }
                    }
                    None => {
                        for (qi, &r) in qrel.iter().enumerate() {
                            qb[qi][i] = (qwin[r] + 0.0) * scale;
                        }
                    }
                }
                for (qi, &r) in qrel.iter().enumerate() {
                    ob[qi][i] = owin[r];
                }
                let (krow, vrow) = (&mut kt[i * np..][..np], &mut vt[i * np..][..np]);
                for run in &runs {
                    let (kr, km) = (&mut krow[run.key..][..run.len], &kmap[ch + run.px..]);
                    match &pos_k {
                        Some(pk) => {
                            let pk = &pk[(ch0 + i) * lk + run.slot..][..run.len];
                            for ((kv, &m), &e) in kr.iter_mut().zip(km).zip(pk) {
                                *kv = m + e;
                            }
                        }
                        None => {
                            for (kv, &m) in kr.iter_mut().zip(km) {
                                *kv = m + 0.0;
                            }
                        }
                    }
                    vrow[run.key..][..run.len].copy_from_slice(&vmap[ch + run.px..][..run.len]);
                }
                krow[n..].fill(0.0);
                vrow[n..].fill(0.0);
            }
            let ds = &mut ds[..lq * np];
            let (kt, vt) = (&kt[..D * np], &vt[..D * np]);
            let p: &[f32] = if let Some(kept) = kept {
                // The forward's softmax rows, as kept (the same bits as computed here): read
                // in place where the window has every key (rows of `lkp`), else copied out.
                let kept = &kept[(wx * heads + head) * lq * lkp..][..lq * lkp];
                if np == lkp {
                    kept
                } else {
                    let p = &mut p[..lq * np];
                    for (row, from) in p.chunks_exact_mut(np).zip(kept.chunks_exact(lkp)) {
                        row.copy_from_slice(&from[..np]);
                    }
                    p
                }
            } else {
                let p = &mut p[..lq * np];
                // Logits and softmax rows, as the forward computes them.
                let bias = s.bias.map(|b| &b[head * lq * lk..][..lq * lk]);
                logit_rows(p, slots.iter().copied(), n, bias, &qb, kt);
                for row in p.chunks_exact_mut(np) {
                    lanes::softmax(row, n, exp_nonpositive);
                }
                p
            };
            // dP = dO·Vᵀ (into ds); dV = Pᵀ·dO.
            lanes::weighted_rows(ds, np, vt, |qi, i| ob[qi][i]);
            lanes::weighted_rows(&mut dvt[..D * np], np, p, |i, qi| ob[qi][i]);
            // dS = P ⊙ (dP − rowsum(P ⊙ dP)) (zero in the padding, where P is).
            for (dsrow, prow) in ds.chunks_exact_mut(np).zip(p.chunks_exact(np)) {
                let total = lanes::dot(dsrow, prow);
                for (d, &pj) in dsrow.iter_mut().zip(prow) {
                    *d = pj * (*d - total);
                }
            }
            // dK = dSᵀ·(s·Q); dQ = s·dS·K (into the strip); the position terms.
            lanes::weighted_rows(&mut dkt[..D * np], np, ds, |i, qi| qb[qi][i]);
            for (qi, dsrow) in ds.chunks_exact(np).enumerate() {
                let mut dq = lanes::dots::<D>(dsrow, kt);
                let strip = x0 + qrel[qi];
                for (i, g) in dq.iter_mut().enumerate() {
                    *g *= scale;
                    out.dq[(ch0 + i) * win * w + strip] = *g;
                }
                if !out.dpos_q.is_empty() {
                    add(&mut out.dpos_q[qi * c + ch0..][..D], &dq);
                }
            }
            if !out.dbias.is_empty() {
                for (qi, dsrow) in ds.chunks_exact(np).enumerate() {
                    let db = &mut out.dbias[(head * lq + qi) * lk..][..lk];
                    if n == lk {
                        // A whole key window: its slots in order.
                        add(db, &dsrow[..lk]);
                    } else {
                        for (&d, &slot) in dsrow.iter().zip(&slots) {
                            db[slot] += d;
                        }
                    }
                }
            }
            for i in 0..D {
                let (dkrow, dvrow) = (&dkt[i * np..][..n], &dvt[i * np..][..n]);
                let band = (ch0 + i) * kwin * w;
                for run in &runs {
                    let (j, at, len) = (run.key, band + run.band, run.len);
                    add(&mut out.dk[at..][..len], &dkrow[j..][..len]);
                    add(&mut out.dv[at..][..len], &dvrow[j..][..len]);
                }
                if !out.dpos_k.is_empty() {
                    for (&d, &slot) in dkrow.iter().zip(&slots) {
                        out.dpos_k[slot * c + ch0 + i] += d;
                    }
                }
            }
        }
    }
    out
}

#[derive(Debug)]
struct AttentionBackward {
    kind: Kind,
    win: usize,
    kwin: usize,
}

impl AttentionBackward {
    /// The gradients of the node's inputs, in their order.
    fn grads(
        &self,
        dout: FlexTensor,
        inputs: Vec<FlexTensor>,
        probs: Option<&Probs>,
    ) -> Vec<FlexTensor> {
        let dout = dout.to_contiguous();
        let inputs: Vec<FlexTensor> = inputs.into_iter().map(|t| t.to_contiguous()).collect();
        let (maps, pos) = inputs.split_at(3);
        let [bq, c, h, w] = flex_dims::<4>(&maps[0]);
        let g = flex_dims::<4>(&maps[1])[0];
        let spec = spec(self.kind, pos, self.win, self.kwin, g / bq.max(1));
        let grads = attend_backward(
            flex_slice(&maps[0]),
            flex_slice(&maps[1]),
            flex_slice(&maps[2]),
            flex_slice(&dout),
            [c, h, w],
            &spec,
            probs.map(|p| p.0.as_slice()),
        );
        let tensor = |v: Vec<f32>, like: &FlexTensor| {
            let shape = like.layout().shape().to_vec();
            FlexTensor::from_data(TensorData::new(v, shape))
        };
        let mut out = vec![
            tensor(grads.dq, &maps[0]),
            tensor(grads.dk, &maps[1]),
            tensor(grads.dv, &maps[2]),
        ];
        match self.kind {
            Kind::Window => out.push(tensor(grads.dbias, &pos[0])),
            Kind::Cross { .. } => {
                out.push(tensor(grads.dpos_q, &pos[0]));
                out.push(tensor(grads.dpos_k, &pos[1]));
            }
        }
        out
    }
}

impl<const N: usize> Backward<Flex, N> for AttentionBackward {
    /// The inputs' nodes, and the forward's softmax rows when it kept them.
    type State = ([NodeId; N], Option<Probs>);

    fn backward(
        self,
        ops: Ops<Self::State, N>,
        grads: &mut Gradients,
        checkpointer: &mut Checkpointer,
    ) {
        let dout = grads.consume::<Flex>(&ops.node);
        let (ids, probs) = ops.state;
        let inputs = ids
            .iter()
            .map(|&id| checkpointer.retrieve_node_output::<FlexTensor>(id))
            .collect();
        let tensors = self.grads(dout, inputs, probs.as_ref());
        for (parent, grad) in ops.parents.into_iter().zip(tensors) {
            if let Some(node) = parent {
                grads.register::<Flex>(node.id, grad);
            }
        }
    }
}

/// Records one attention node of `N` inputs under autodiff.
fn tracked<C: CheckpointStrategy, const N: usize>(
    inputs: [FloatTensor<Autodiff<Flex, C>>; N],
    backward: AttentionBackward,
    forward: impl FnOnce([FlexTensor; N], bool) -> (FlexTensor, Option<Probs>),
) -> FloatTensor<Autodiff<Flex, C>> {
    let nodes = inputs.each_ref().map(|t| t.node());
    match backward.prepare::<C>(nodes).compute_bound().stateful() {
        OpsKind::Tracked(mut prep) => {
            let ids = inputs.each_ref().map(|t| prep.checkpoint(t));
            let (y, probs) = forward(inputs.map(|t| t.into_primitive()), true);
            prep.finish((ids, probs), y)
        }
        OpsKind::UnTracked(prep) => {
            prep.finish(forward(inputs.map(|t| t.into_primitive()), false).0)
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
        let kind = Kind::Window;
        tracked::<C, _>(
            [q, k, v, bias],
            AttentionBackward { kind, win, kwin },
            |[q, k, v, b], keep| forward([q, k, v], vec![b], kind, win, kwin, keep),
        )
    }

    fn window_attention_qkv(
        qkv: FloatTensor<Self>,
        bias: FloatTensor<Self>,
        qe: usize,
        win: usize,
        kwin: usize,
    ) -> FloatTensor<Self> {
        let nodes = [qkv.node(), bias.node()];
        let backward = QkvBackward { qe, win, kwin };
        let run = |qkv: FloatTensor<Self>, bias: FloatTensor<Self>, keep| {
            qkv_forward(
                qkv.into_primitive(),
                bias.into_primitive(),
                qe,
                win,
                kwin,
                keep,
            )
        };
        match backward.prepare::<C>(nodes).compute_bound().stateful() {
            OpsKind::Tracked(mut prep) => {
                let bias_id = prep.checkpoint(&bias);
                let (y, kept) = run(qkv, bias, true);
                prep.finish((bias_id, kept.expect("kept when asked")), y)
            }
            OpsKind::UnTracked(prep) => prep.finish(run(qkv, bias, false).0),
        }
    }

    fn cross_attention(
        q: FloatTensor<Self>,
        k: FloatTensor<Self>,
        v: FloatTensor<Self>,
        pos_q: FloatTensor<Self>,
        pos_k: FloatTensor<Self>,
        heads: usize,
        win: usize,
        kwin: usize,
    ) -> FloatTensor<Self> {
        let kind = Kind::Cross { heads };
        tracked::<C, _>(
            [q, k, v, pos_q, pos_k],
            AttentionBackward { kind, win, kwin },
            |[q, k, v, pq, pk], keep| forward([q, k, v], vec![pq, pk], kind, win, kwin, keep),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The backward of one strip as first written: one `axpy` per key row and query, one
    /// `axpy_dot` per query and channel, scalar scatters. The kernel must give its bits.
    fn reference_strip<const D: usize>(
        task: usize,
        maps: [&[f32]; 4],
        z: Sizes,
        s: &WindowSpec,
        kept: Option<&[f32]>,
    ) -> StripGrads {
        let [q, k, v, dout] = maps;
        let Sizes { c, h, w } = z;
        let (heads, win, kwin) = (s.heads, s.win, s.kwin);
        let plane = h * w;
        let (nh, nw) = (h / win, w / win);
        let (lq, lk) = (win * win, kwin * kwin);
        let pad = (kwin - win) / 2;
        let scale = (D as f32).powf(-0.5);
        let (g, wy) = (task / nh, task % nh);
        let at = |m: usize| m * c * plane..(m + 1) * c * plane;
        let (qmap, kmap, vmap, omap) = (&q[at(g / s.share)], &k[at(g)], &v[at(g)], &dout[at(g)]);
        let size = |on: bool, n: usize| if on { n } else { 0 };
        let mut out = StripGrads {
            dq: vec![0.0f32; c * win * w],
            dk: vec![0.0f32; c * kwin * w],
            dv: vec![0.0f32; c * kwin * w],
            dbias: vec![0.0f32; size(s.bias.is_some(), heads * lq * lk)],
            dpos_q: vec![0.0f32; size(s.pos_q.is_some(), lq * c)],
            dpos_k: vec![0.0f32; size(s.pos_k.is_some(), lk * c)],
        };
        // Per window and head: queries (scaled) and output gradients by query, `[lq, D]`; keys,
        // values and their gradients transposed, `[D, np]`, so that every inner loop runs along
        // contiguous keys (in chunks of 8, rows padded with zeros: [`super::lanes`]) instead of
        // summing across the few channels of a head; the softmax `p` and its gradient `ds`,
        // `[lq, np]`.
        let lkp = lanes::padded(lk);
        let mut qb = vec![[0.0f32; D]; lq];
        let mut ob = vec![[0.0f32; D]; lq];
        let mut kt = vec![0.0f32; D * lkp];
        let mut vt = vec![0.0f32; D * lkp];
        let mut dkt = vec![0.0f32; D * lkp];
        let mut dvt = vec![0.0f32; D * lkp];
        let mut p = vec![0.0f32; lq * lkp];
        let mut ds = vec![0.0f32; lq * lkp];
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
            let np = lanes::padded(n);
            for head in 0..heads {
                let ch0 = head * D;
                for i in 0..D {
                    let ch = (ch0 + i) * plane;
                    for qi in 0..lq {
                        let px = (y0 + qi / win) * w + x0 + qi % win;
                        let pos = s.pos_q.map_or(0.0, |p| p[qi * c + ch0 + i]);
                        qb[qi][i] = (qmap[ch + px] + pos) * scale;
                        ob[qi][i] = omap[ch + px];
                    }
                    let (krow, vrow) = (&mut kt[i * np..][..np], &mut vt[i * np..][..np]);
                    for (j, &(slot, px, _)) in inside.iter().enumerate() {
                        krow[j] = kmap[ch + px] + s.pos_k.map_or(0.0, |p| p[slot * c + ch0 + i]);
                        vrow[j] = vmap[ch + px];
                    }
                    krow[n..].fill(0.0);
                    vrow[n..].fill(0.0);
                }
                let p = &mut p[..lq * np];
                let ds = &mut ds[..lq * np];
                if let Some(kept) = kept {
                    // The forward's softmax rows, as kept (the same bits as computed here).
                    let at = (wx * heads + head) * lq * lkp;
                    for (qi, row) in p.chunks_exact_mut(np).enumerate() {
                        row.copy_from_slice(&kept[at + qi * lkp..][..np]);
                    }
                } else {
                    // Logits and softmax rows, as the forward computes them.
                    let bias = s.bias.map(|b| &b[head * lq * lk..][..lq * lk]);
                    let slots = inside.iter().map(|&(slot, _, _)| slot);
                    logit_rows(p, slots, n, bias, &qb, &kt[..D * np]);
                    for row in p.chunks_exact_mut(np) {
                        lanes::softmax(row, n, exp_nonpositive);
                    }
                }
                // dP = dO·Vᵀ (into ds); dV = Pᵀ·dO.
                ds.fill(0.0);
                dvt[..D * np].fill(0.0);
                for i in 0..D {
                    let vrow = &vt[i * np..][..np];
                    let dvrow = &mut dvt[i * np..][..np];
                    for qi in 0..lq {
                        let o = ob[qi][i];
                        lanes::axpy(&mut ds[qi * np..][..np], o, vrow);
                        lanes::axpy(dvrow, o, &p[qi * np..][..np]);
                    }
                }
                // dS = P ⊙ (dP − rowsum(P ⊙ dP)) (zero in the padding, where P is).
                for (dsrow, prow) in ds.chunks_exact_mut(np).zip(p.chunks_exact(np)) {
                    let total = lanes::dot(dsrow, prow);
                    for (d, &pj) in dsrow.iter_mut().zip(prow) {
                        *d = pj * (*d - total);
                    }
                }
                // dK = dSᵀ·(s·Q); dQ = s·dS·K (into the strip); the position terms.
                dkt[..D * np].fill(0.0);
                for i in 0..D {
                    let krow = &kt[i * np..][..np];
                    let dkrow = &mut dkt[i * np..][..np];
                    for qi in 0..lq {
                        let dq = lanes::axpy_dot(dkrow, qb[qi][i], &ds[qi * np..][..np], krow);
                        let g = dq * scale;
                        let (qy, qx) = (qi / win, qi % win);
                        out.dq[((ch0 + i) * win + qy) * w + x0 + qx] = g;
                        if !out.dpos_q.is_empty() {
                            out.dpos_q[qi * c + ch0 + i] += g;
                        }
                    }
                }
                if !out.dbias.is_empty() {
                    for (qi, dsrow) in ds.chunks_exact(np).enumerate() {
                        let db = &mut out.dbias[(head * lq + qi) * lk..][..lk];
                        for (&d, &(slot, _, _)) in dsrow.iter().zip(&inside) {
                            db[slot] += d;
                        }
                    }
                }
                for i in 0..D {
                    let (dkrow, dvrow) = (&dkt[i * np..][..n], &dvt[i * np..][..n]);
                    for (j, &(slot, _, band)) in inside.iter().enumerate() {
                        let at = (ch0 + i) * kwin * w + band;
                        out.dk[at] += dkrow[j];
                        out.dv[at] += dvrow[j];
                        if !out.dpos_k.is_empty() {
                            out.dpos_k[slot * c + ch0 + i] += dkrow[j];
                        }
                    }
                }
            }
        }
        out
    }

    /// Values in [-2, 2): the shared test stream, doubled.
    fn values(n: usize, seed: u64) -> Vec<f32> {
        let v = super::super::test_values::values(n, seed);
        v.into_iter().map(|x| 2.0 * x).collect()
    }

    /// One strip's gradients from the kernel (the build the CPU runs) and from
    /// [`reference_strip`] (portable), compared bit for bit.
    fn same_strip<const D: usize>(
        task: usize,
        maps: [&[f32]; 4],
        z: Sizes,
        s: &WindowSpec,
        kept: Option<&[f32]>,
    ) {
        let a = strip::<D>(task, maps, z, s, kept);
        let b = reference_strip::<D>(task, maps, z, s, kept);
        let bits = |x: &[f32]| x.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        for (name, x, y) in [
            ("dq", &a.dq, &b.dq),
            ("dk", &a.dk, &b.dk),
            ("dv", &a.dv, &b.dv),
            ("dbias", &a.dbias, &b.dbias),
            ("dpos_q", &a.dpos_q, &b.dpos_q),
            ("dpos_k", &a.dpos_k, &b.dpos_k),
        ] {
            assert_eq!(bits(x), bits(y), "{name}: task {task}, head width {D}");
        }
        assert!(a.dk.iter().any(|&v| v != 0.0) && a.dq.iter().any(|&v| v != 0.0));
    }

    /// The kernel's strips are the reference's bit for bit: window attention (position
    /// logits) and cross-attention (embeddings, three maps per query map), heads of 4, 8 and
    /// 16 channels, every strip of a map whose windows are cut off at each edge, with the
    /// forward's softmax and without.
    #[test]
    fn strips_are_the_reference_strips_bit_for_bit() {
        let (h, w, win, kwin) = (12, 16, 4, 6);
        for (c, heads) in [(16, 4), (16, 2), (32, 2)] {
            let plane = c * h * w;
            let bias = values(heads * win * win * kwin * kwin, 5);
            let pos_q = values(win * win * c, 6);
            let pos_k = values(kwin * kwin * c, 7);
            let window = WindowSpec {
                heads,
                win,
                kwin,
                share: 1,
                pos_q: None,
                pos_k: None,
                bias: Some(&bias),
            };
            let cross = WindowSpec {
                heads,
                win,
                kwin,
                share: 3,
                pos_q: Some(&pos_q),
                pos_k: Some(&pos_k),
                bias: None,
            };
            for (groups, spec) in [(1, window), (3, cross)] {
                let q = values(plane, 1);
                let k = values(groups * plane, 2);
                let v = values(groups * plane, 3);
                let dout = values(groups * plane, 4);
                let (_, kept) = attend_maps_keeping(&q, &k, &v, [c, h, w], &spec).unwrap();
                let z = Sizes { c, h, w };
                let maps = [&q[..], &k[..], &v[..], &dout[..]];
                assert_eq!(kept.len(), groups * (h / win), "a softmax per strip");
                for (task, rows) in kept.iter().enumerate() {
                    for probs in [Some(rows.as_slice()), None] {
                        match c / heads {
                            4 => same_strip::<4>(task, maps, z, &spec, probs),
                            8 => same_strip::<8>(task, maps, z, &spec, probs),
                            _ => same_strip::<16>(task, maps, z, &spec, probs),
                        }
                    }
                }
            }
        }
    }

    /// The softmax a forward kept gives the backward the bits it computes without it, for
    /// window attention (position logits) and the shared-query cross-attention (embeddings),
    /// on maps with border windows.
    #[test]
    fn kept_softmax_gives_the_recomputed_gradients_bit_for_bit() {
        let (c, h, w, win, kwin) = (16, 12, 8, 4, 6);
        let plane = c * h * w;
        let bias = values(2 * win * win * kwin * kwin, 5);
        let pos_q = values(win * win * c, 6);
        let pos_k = values(kwin * kwin * c, 7);
        let specs = [
            (
                1,
                WindowSpec {
                    heads: 2,
                    win,
                    kwin,
                    share: 1,
                    pos_q: None,
                    pos_k: None,
                    bias: Some(&bias),
                },
            ),
            (
                3,
                WindowSpec {
                    heads: 2,
                    win,
                    kwin,
                    share: 3,
                    pos_q: Some(&pos_q),
                    pos_k: Some(&pos_k),
                    bias: None,
                },
            ),
        ];
        for (groups, spec) in specs {
            let q = values(plane, 1);
            let k = values(groups * plane, 2);
            let v = values(groups * plane, 3);
            let dout = values(groups * plane, 4);
            let dims = [c, h, w];
            let (out, kept) = attend_maps_keeping(&q, &k, &v, dims, &spec).unwrap();
            let plain = attend_maps(&q, &k, &v, dims, &spec).unwrap();
            assert_eq!(out, plain);
            let with = attend_backward(&q, &k, &v, &dout, dims, &spec, Some(&kept));
            let without = attend_backward(&q, &k, &v, &dout, dims, &spec, None);
            for (name, a, b) in [
                ("dq", &with.dq, &without.dq),
                ("dk", &with.dk, &without.dk),
                ("dv", &with.dv, &without.dv),
                ("dbias", &with.dbias, &without.dbias),
                ("dpos_q", &with.dpos_q, &without.dpos_q),
                ("dpos_k", &with.dpos_k, &without.dpos_k),
            ] {
                let bits = |x: &[f32]| x.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(a), bits(b), "{name} differs (groups {groups})");
                assert!(a.iter().all(|v| v.is_finite()), "{name} not finite");
            }
            assert!(with.dq.iter().any(|&v| v != 0.0));
        }
    }

    #[test]
    fn the_qkv_node_gives_the_bits_of_slices_enhancement_and_attention() {
        use burn::tensor::Device;
        let device = Device::flex().autodiff();
        let bits = |t: Vec<f32>| t.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        // Two items, masked border keys; with and without the query enhancement.
        for (c, heads, qe, h, w) in [(16, 2, 3, 12, 8), (8, 1, 0, 8, 12), (16, 4, 5, 8, 8)] {
            let (b, win, kwin) = (2, 4, 6);
            let qkv_values = values(b * 3 * c * h * w, 5);
            let bias_values = values(heads * win * win * kwin * kwin, 6);
            let wts = Tensor::<4>::from_data(
                TensorData::new(values(b * c * h * w, 7), [b, c, h, w]),
                &device,
            );
            let run = |fused: bool| {
                let qkv = Tensor::<4>::from_data(
                    TensorData::new(qkv_values.clone(), [b, 3 * c, h, w]),
                    &device,
                )
                .require_grad();
                let bias = Tensor::<3>::from_data(
                    TensorData::new(bias_values.clone(), [heads, win * win, kwin * kwin]),
                    &device,
                )
                .require_grad();
                let y = if fused {
                    attend_qkv_tensor(qkv.clone(), bias.clone(), qe, win, kwin)
                } else {
                    let mut parts = qkv.clone().chunk(3, 1);
                    let v = parts.pop().unwrap();
                    let k = parts.pop().unwrap();
                    let q = parts.pop().unwrap();
                    let q = if qe > 1 {
                        super::super::query_box::enhance_tensor(q, qe)
                    } else {
                        q
                    };
                    attend_tensor(q, k, v, bias.clone(), win, kwin)
                };
                let g = (y.clone() * wts.clone()).sum().backward();
                let read = |t: Tensor<4>| t.try_into_vec_as::<f32>().unwrap();
                [
                    read(y),
                    read(qkv.grad(&g).unwrap()),
                    bias.grad(&g).unwrap().try_into_vec_as::<f32>().unwrap(),
                ]
            };
            let (fused, chained) = (run(true), run(false));
            for (name, a, r) in ["output", "q/k/v gradient", "position gradient"]
                .iter()
                .zip(fused)
                .zip(chained)
                .map(|((n, a), r)| (n, a, r))
            {
                assert!(a.iter().all(|v| v.is_finite()), "{name} not finite");
                assert!(a.iter().any(|&v| v != 0.0), "{name} all zero");
                assert_eq!(bits(a), bits(r), "{name} differs ({c}/{heads}, qe {qe})");
            }
        }
    }
}
