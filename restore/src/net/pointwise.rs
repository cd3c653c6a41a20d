//! The 1×1 convolution on the CPU, forward and backward, as a burn backend extension.
//!
//! Every projection of the network is one (STAF's q/k/v and output, the GDFN's two, the
//! fusion's, MAFG's embeddings): a third of a `tiny` forward pass. burn's CPU 1×1 path is a
//! general matrix product that packs its operands, writes a zeroed output and adds the bias in
//! a second pass; in training it went through a batched matrix product whose outputs burn
//! allocates zeroed and then copies to realign. With the network's few channels (3 to 170)
//! the products are thin, and a plain register-blocked loop over the NCHW planes does better:
//! 16 pixels of 6 output channels in registers, the bias as the sums' start, every input
//! channel's 16 pixels read once per 6 outputs, the output written once and never zeroed.
//! The backward is the same loop with the weights transposed for `dx`, and per-channel dot
//! products over the pixels for `dW` and `db`, summed in lanes in a fixed order, batch item
//! by batch item (so a gradient does not depend on the thread count).
//!
//! Every build fuses each multiply-add (one rounding: FMA in the vector builds, `mul_add` in
//! the portable one) in the same order, so they give the same bits; the output is within
//! 1e-6 of its scale of an f64 sum (the tests below; `restore/tests/kernels.rs` checks the
//! network's bits in both builds and its gradients against burn's).

use super::kernels::{flex_dims, flex_slice};
use super::lanes::LANES;
use burn::backend::autodiff::NodeId;
use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::flex::FlexTensor;
use burn::backend::{Autodiff, Backend, Dispatch, Flex, backend_extension, tensor::FloatTensor};
use burn::tensor::{Tensor, TensorData};
use rayon::prelude::*;

/// Pixels per task: enough work to amortise a task, small enough that a 512² plane makes
/// a few hundred tasks for the threads to share.
const TASK_PX: usize = 1024;

/// A raw output pointer the tasks write through: each task writes its own pixels of every
/// output plane, so no two tasks touch one value.
#[derive(Clone, Copy)]
pub(super) struct Out(pub(super) *mut f32);
// SAFETY: tasks write disjoint elements (see `project`); the pointer outlives them.
unsafe impl Send for Out {}
unsafe impl Sync for Out {}

impl Out {
    /// # Safety
    /// As `pointer::add`: `count` values past the pointer stay inside its allocation.
    pub(super) unsafe fn add(self, count: usize) -> Out {
        // SAFETY: the caller's contract.
        Out(unsafe { self.0.add(count) })
    }
}

/// `x: [b, cin, h, w]`, `weight: [cout, cin]` (row-major), `bias: [cout]` or none →
/// `[b, cout, h, w]`: `out[n][o][p] = bias[o] + Σ_i weight[o][i] · x[n][i][p]`.
pub fn pointwise(
    x: &[f32],
    weight: &[f32],
    bias: Option<&[f32]>,
    cout: usize,
    [b, cin, h, w]: [usize; 4],
) -> Vec<f32> {
    let plane = h * w;
    assert_eq!(x.len(), b * cin * plane, "map of {b}x{cin}x{h}x{w}");
    assert_eq!(weight.len(), cout * cin, "{cout}x{cin} weights");
    if let Some(bias) = bias {
        assert_eq!(bias.len(), cout, "{cout} biases");
    }
    let len = b * cout * plane;
    let mut out = Vec::<f32>::with_capacity(len);
    let dst = Out(out.as_mut_ptr());
    let blocks = plane.div_ceil(TASK_PX);
    (0..b * blocks).into_par_iter().for_each(|task| {
        let (n, blk) = (task / blocks, task % blocks);
        let p0 = blk * TASK_PX;
        let p1 = (p0 + TASK_PX).min(plane);
        let src = &x[n * cin * plane..][..cin * plane];
        // SAFETY: `out` has capacity for `b·cout·plane` values; this task writes only
        // item `n`'s pixels `p0..p1` of each of its `cout` planes, inside that capacity.
        let item = unsafe { dst.add(n * cout * plane) };
        project(item, src, weight, bias, (cout, cin, plane), p0..p1);
    });
    // SAFETY: the tasks above wrote every pixel of every plane of every item.
    unsafe { out.set_len(len) };
    out
}

/// One item's pixels `range` of all `cout` planes.
fn project(
    dst: Out,
    x: &[f32],
    weight: &[f32],
    bias: Option<&[f32]>,
    dims: (usize, usize, usize),
    range: std::ops::Range<usize>,
) {
    #[cfg(target_arch = "x86_64")]
    match base::isa::Isa::chosen() {
        // SAFETY: `Isa::chosen` names a build the CPU has; the writes stay inside `range`
        // (see `pointwise`).
        base::isa::Isa::Avx512 => {
            return unsafe { project_avx512(dst, x, weight, bias, dims, range) };
        }
        // SAFETY: as above.
        base::isa::Isa::Avx2 => return unsafe { project_avx2(dst, x, weight, bias, dims, range) },
        base::isa::Isa::Portable => {}
    }
    // SAFETY: as above.
    unsafe { project_portable(dst, x, weight, bias, dims, range) }
}

/// # Safety
/// `dst` points at `cout` planes of `plane` values each, and the caller owns their pixels
/// `range`.
unsafe fn project_portable(
    dst: Out,
    x: &[f32],
    weight: &[f32],
    bias: Option<&[f32]>,
    (cout, cin, plane): (usize, usize, usize),
    range: std::ops::Range<usize>,
) {
    let mut acc = vec![0.0f32; range.len()];
    for o in 0..cout {
        acc.fill(bias.map_or(0.0, |b| b[o]));
        for i in 0..cin {
            let wv = weight[o * cin + i];
            let row = &x[i * plane + range.start..][..range.len()];
            for (a, &v) in acc.iter_mut().zip(row) {
                *a = wv.mul_add(v, *a);
            }
        }
        for (k, &a) in acc.iter().enumerate() {
            // SAFETY: inside plane `o`, at a pixel of `range` (the caller's contract).
            unsafe { *dst.0.add(o * plane + range.start + k) = a };
        }
    }
}

/// A build of the projection over [`blocks`], its tiles `$tile::<R>` for `R` up to `$rows`
/// output channels × `$cols` pixels, compiled with `$features`.
macro_rules! project_build {
    ($(#[$doc:meta])* $name:ident, $features:literal, $tile:ident, $rows:literal, $cols:expr,
     [$($r:literal),*]) => {
        $(#[$doc])*
        /// # Safety
        /// As [`project_portable`]; the CPU has the build's features.
        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = $features)]
        unsafe fn $name(
            dst: Out,
            x: &[f32],
            weight: &[f32],
            bias: Option<&[f32]>,
            dims: (usize, usize, usize),
            range: std::ops::Range<usize>,
        ) {
            let (cin, plane) = (dims.1, dims.2);
            let tile = |rows: usize, src: *const f32, w: *const f32, b: &[f32], out: *mut f32| {
                // SAFETY: `blocks`' contract for its tiles; the build's features are enabled.
                unsafe {
                    match rows {
                        $($r => $tile::<$r>(src, w, b, out, cin, plane),)*
                        _ => unreachable!("a tile has 1 to {} rows", $rows),
                    }
                }
            };
            // SAFETY: the caller's contract.
            unsafe { blocks::<$rows, { $cols }>(dst, x, weight, bias, dims, range, tile) }
        }
    };
}

project_build!(
    /// 6 output channels × 16 pixels per tile, in 12 of AVX2's 16 registers.
    project_avx2, "avx2,fma", tile8, 6, 2 * LANES, [1, 2, 3, 4, 5, 6]
);
project_build!(
    /// 12 output channels × 32 pixels per tile, in 24 of AVX-512's 32 registers.
    project_avx512, "avx512f,avx512vl,avx2,fma", tile16, 12, 32,
    [1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12]
);

/// Pixels copied side by side per block of [`blocks`].
pub(super) const BLOCK: usize = 64;

/// The pixels `range` in blocks of [`BLOCK`]: each block's input planes copied side by side
/// (the planes lie a whole plane apart, so the same pixels of all of them fall in the same
/// few cache sets; side by side every tile reads them from L1), then `tile` over `ROWS`
/// output channels × `COLS` pixels at a time; the pixels past the last whole block through
/// the portable loop.
///
/// # Safety
/// As [`project_portable`]; `tile(rows, src, w, bias, out)` may be called with `src` at `cin`
/// rows of `BLOCK` values (reading `COLS` from each), `w` at `rows ≤ ROWS` rows of `cin`
/// weights, `bias` with at least `rows` values and `out` at `rows` output rows `plane` apart
/// with `COLS` writable values each; `COLS` divides [`BLOCK`].
#[inline(always)]
unsafe fn blocks<const ROWS: usize, const COLS: usize>(
    dst: Out,
    x: &[f32],
    weight: &[f32],
    bias: Option<&[f32]>,
    (cout, cin, plane): (usize, usize, usize),
    range: std::ops::Range<usize>,
    tile: impl Fn(usize, *const f32, *const f32, &[f32], *mut f32),
) {
    let mut buf = vec![0.0f32; cin * BLOCK];
    let biases: Vec<f32> = (0..cout).map(|o| bias.map_or(0.0, |b| b[o])).collect();
    let mut q = range.start;
    while q + BLOCK <= range.end {
        for (i, row) in buf.chunks_exact_mut(BLOCK).enumerate() {
            row.copy_from_slice(&x[i * plane + q..][..BLOCK]);
        }
        let mut o0 = 0;
        while o0 < cout {
            let rows = ROWS.min(cout - o0);
            for t in (0..BLOCK).step_by(COLS) {
                // SAFETY: rows `o0..o0 + rows` of the weights, biases and output planes
                // exist; pixels `q + t .. q + t + COLS` lie in `range` (the caller owns them).
                let out = unsafe { dst.0.add(o0 * plane + q + t) };
                tile(
                    rows,
                    buf[t..].as_ptr(),
                    weight[o0 * cin..].as_ptr(),
                    &biases[o0..],
                    out,
                );
            }
            o0 += ROWS;
        }
        q += BLOCK;
    }
    if q < range.end {
        // SAFETY: the rest of `range`, under the same contract.
        unsafe { project_portable(dst, x, weight, bias, (cout, cin, plane), q..range.end) };
    }
}

/// A register tile `$name::<R>`: `R` output channels × two `$vec` registers of `$lanes`
/// pixels, `out[j][k] = bias[j] + Σ_i w[j·cin + i] · src[i·BLOCK + k]`, each product added
/// fused (one rounding) in `i`'s order (the portable loop's bits), compiled with `$features`.
macro_rules! tile_build {
    ($(#[$doc:meta])* $name:ident, $features:literal, $lanes:expr, $zero:ident, $splat:ident,
     $load:ident, $fma:ident, $store:ident) => {
        $(#[$doc])*
        /// # Safety
        /// `src` has `cin` rows of [`BLOCK`] values (two registers read from each), `w` `R`
        /// rows of `cin`, `bias` at least `R` values, `out` `R` rows `plane` apart with two
        /// registers' worth of writable values each; the CPU has the build's features.
        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = $features)]
        #[inline]
        pub(super) unsafe fn $name<const R: usize>(
            src: *const f32,
            w: *const f32,
            bias: &[f32],
            out: *mut f32,
            cin: usize,
            plane: usize,
        ) {
            use std::arch::x86_64::*;
            let mut acc = [[$zero(); 2]; R];
            for (j, a) in acc.iter_mut().enumerate() {
                let b = $splat(bias[j]);
                *a = [b, b];
            }
            for i in 0..cin {
                // SAFETY: the caller's contract.
                unsafe {
                    let p = src.add(i * BLOCK);
                    let (x0, x1) = ($load(p), $load(p.add($lanes)));
                    for (j, a) in acc.iter_mut().enumerate() {
                        let wv = $splat(*w.add(j * cin + i));
                        a[0] = $fma(wv, x0, a[0]);
                        a[1] = $fma(wv, x1, a[1]);
                    }
                }
            }
            for (j, a) in acc.iter().enumerate() {
                // SAFETY: the caller's contract.
                unsafe {
                    let p = out.add(j * plane);
                    $store(p, a[0]);
                    $store(p.add($lanes), a[1]);
                }
            }
        }
    };
}

tile_build!(
    /// 16 pixels in AVX2 registers.
    tile8, "avx2,fma", LANES, _mm256_setzero_ps, _mm256_set1_ps, _mm256_loadu_ps,
    _mm256_fmadd_ps, _mm256_storeu_ps
);
tile_build!(
    /// 32 pixels in AVX-512 registers (32 of them: up to 12 rows).
    tile16, "avx512f,fma", 16, _mm512_setzero_ps, _mm512_set1_ps, _mm512_loadu_ps,
    _mm512_fmadd_ps, _mm512_storeu_ps
);

/// The gradients of [`pointwise`] from the output gradient `dy: [b, cout, h, w]`:
/// `(dx: [b, cin, h, w], dW: [cout, cin], db: [cout])`.
pub fn pointwise_backward(
    x: &[f32],
    dy: &[f32],
    weight: &[f32],
    cout: usize,
    [b, cin, h, w]: [usize; 4],
) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
    let plane = h * w;
    assert!(x.len() == b * cin * plane && dy.len() == b * cout * plane);
    assert_eq!(weight.len(), cout * cin);
    if x.is_empty() {
        return (Vec::new(), vec![0.0; cout * cin], vec![0.0; cout]);
    }
    let mut wt = vec![0.0f32; cin * cout];
    for o in 0..cout {
        for i in 0..cin {
            wt[i * cout + o] = weight[o * cin + i];
        }
    }
    let dx = pointwise(dy, &wt, None, cin, [b, cout, h, w]);
    // dW = Σ_n dy_n · x_nᵀ, one matrix product per item (in parallel), summed in item order
    // so the gradient does not depend on the thread count.
    let per_item: Vec<Vec<f32>> = (0..b)
        .into_par_iter()
        .map(|n| {
            let mut dw = vec![0.0f32; cout * cin];
            let (g, xi) = (&dy[n * cout * plane..], &x[n * cin * plane..]);
            // SAFETY: dst is `cout × cin` row-major; lhs `dy_n` is `cout × plane` row-major;
            // rhs is `x_nᵀ`, `plane × cin` read column by column from `x_n`'s planes; every
            // pointer and stride stays inside its slice.
            unsafe {
                gemm::gemm(
                    cout,
                    cin,
                    plane,
                    dw.as_mut_ptr(),
                    1,
                    cin as isize,
                    false,
                    g.as_ptr(),
                    1,
                    plane as isize,
                    xi.as_ptr(),
                    plane as isize,
                    1,
                    0.0,
                    1.0,
                    false,
                    false,
                    false,
                    gemm::Parallelism::None,
                );
            }
            dw
        })
        .collect();
    let mut dweight = vec![0.0f32; cout * cin];
    for dw in per_item {
        dweight.iter_mut().zip(dw).for_each(|(a, v)| *a += v);
    }
    let dbias = (0..cout)
        .map(|o| {
            (0..b)
                .map(|n| lane_sum(&dy[(n * cout + o) * plane..][..plane]))
                .sum()
        })
        .collect();
    (dx, dweight, dbias)
}

/// `Σ a` in 8 lanes, added in a fixed order.
fn lane_sum(a: &[f32]) -> f32 {
    let (ac, ar) = a.as_chunks::<LANES>();
    let mut acc = [0.0f32; LANES];
    for x in ac {
        for l in 0..LANES {
            acc[l] += x[l];
        }
    }
    reduce(acc) + ar.iter().sum::<f32>()
}

/// The 8 lanes added pairwise in a fixed order.
#[inline(always)]
fn reduce(acc: [f32; LANES]) -> f32 {
    ((acc[0] + acc[4]) + (acc[2] + acc[6])) + ((acc[1] + acc[5]) + (acc[3] + acc[7]))
}

/// [`pointwise`] of `x: [b, cin, h, w]` with `weight: [cout, cin, 1, 1]` and an optional
/// `bias: [cout]` (on burn's CPU backend, with or without autodiff) through
/// [`PointwiseOps`].
pub fn pointwise_tensor(x: Tensor<4>, weight: Tensor<4>, bias: Option<Tensor<1>>) -> Tensor<4> {
    let [cout, cin, _, _] = weight.dims();
    let weight = weight.reshape([cout, cin]).into_dispatch();
    Tensor::<4>::from_dispatch(match bias {
        Some(bias) => <Dispatch as PointwiseOps>::pointwise_bias(
            x.into_dispatch(),
            weight,
            bias.into_dispatch(),
        ),
        None => <Dispatch as PointwiseOps>::pointwise(x.into_dispatch(), weight),
    })
}

#[backend_extension(Flex, Autodiff)]
pub trait PointwiseOps: Backend {
    /// `x: [b, cin, h, w]`, `weight: [cout, cin]` → `[b, cout, h, w]`.
    fn pointwise(x: FloatTensor<Self>, weight: FloatTensor<Self>) -> FloatTensor<Self>;
    /// The same with `bias: [cout]` added.
    fn pointwise_bias(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        bias: FloatTensor<Self>,
    ) -> FloatTensor<Self>;
}

fn flex_pointwise(x: FlexTensor, weight: FlexTensor, bias: Option<FlexTensor>) -> FlexTensor {
    let (x, weight) = (x.to_contiguous(), weight.to_contiguous());
    let bias = bias.map(|b| b.to_contiguous());
    let d = flex_dims::<4>(&x);
    let cout = flex_dims::<2>(&weight)[0];
    let y = pointwise(
        flex_slice(&x),
        flex_slice(&weight),
        bias.as_ref().map(flex_slice),
        cout,
        d,
    );
    FlexTensor::from_data(TensorData::new(y, [d[0], cout, d[2], d[3]]))
}

impl PointwiseOps for Flex {
    fn pointwise(x: FlexTensor, weight: FlexTensor) -> FlexTensor {
        flex_pointwise(x, weight, None)
    }
    fn pointwise_bias(x: FlexTensor, weight: FlexTensor, bias: FlexTensor) -> FlexTensor {
        flex_pointwise(x, weight, Some(bias))
    }
}

#[derive(Debug)]
struct PointwiseBackward;

impl PointwiseBackward {
    /// `(dx, dW, db)` for the parents `[x, weight, (bias)]`.
    fn grads(
        dy: FlexTensor,
        state: [NodeId; 2],
        checkpointer: &mut Checkpointer,
    ) -> [FlexTensor; 3] {
        let dy = dy.to_contiguous();
        let [x, weight] = state.map(|id| {
            checkpointer
                .retrieve_node_output::<FlexTensor>(id)
                .to_contiguous()
        });
        let d = flex_dims::<4>(&x);
        let [cout, cin] = flex_dims::<2>(&weight);
        let (dx, dw, db) = pointwise_backward(
            flex_slice(&x),
            flex_slice(&dy),
            flex_slice(&weight),
            cout,
            d,
        );
        [
            FlexTensor::from_data(TensorData::new(dx, d)),
            FlexTensor::from_data(TensorData::new(dw, [cout, cin])),
            FlexTensor::from_data(TensorData::new(db, [cout])),
        ]
    }
}

/// Two parents (`x`, the weights) without a bias, three with.
impl<const N: usize> Backward<Flex, N> for PointwiseBackward {
    type State = [NodeId; 2];

    fn backward(
        self,
        ops: Ops<Self::State, N>,
        grads: &mut Gradients,
        checkpointer: &mut Checkpointer,
    ) {
        let dy = grads.consume::<Flex>(&ops.node);
        let tensors = Self::grads(dy, ops.state, checkpointer);
        for (parent, grad) in ops.parents.into_iter().zip(tensors) {
            if let Some(node) = parent {
                grads.register::<Flex>(node.id, grad);
            }
        }
    }
}

impl<C: CheckpointStrategy> PointwiseOps for Autodiff<Flex, C> {
    fn pointwise(x: FloatTensor<Self>, weight: FloatTensor<Self>) -> FloatTensor<Self> {
        match PointwiseBackward
            .prepare::<C>([x.node(), weight.node()])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(mut prep) => {
                let state = [prep.checkpoint(&x), prep.checkpoint(&weight)];
                let y = Flex::pointwise(x.into_primitive(), weight.into_primitive());
                prep.finish(state, y)
            }
            OpsKind::UnTracked(prep) => {
                prep.finish(Flex::pointwise(x.into_primitive(), weight.into_primitive()))
            }
        }
    }

    fn pointwise_bias(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        bias: FloatTensor<Self>,
    ) -> FloatTensor<Self> {
        match PointwiseBackward
            .prepare::<C>([x.node(), weight.node(), bias.node()])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(mut prep) => {
                let state = [prep.checkpoint(&x), prep.checkpoint(&weight)];
                let y = Flex::pointwise_bias(
                    x.into_primitive(),
                    weight.into_primitive(),
                    bias.into_primitive(),
                );
                prep.finish(state, y)
            }
            OpsKind::UnTracked(prep) => prep.finish(Flex::pointwise_bias(
                x.into_primitive(),
                weight.into_primitive(),
                bias.into_primitive(),
            )),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::test_values::{rel_err, values};
    use super::*;

    /// The 1×1 convolution summed in f64, the obvious way.
    fn reference(
        x: &[f32],
        weight: &[f32],
        bias: Option<&[f32]>,
        cout: usize,
        [b, cin, h, w]: [usize; 4],
    ) -> Vec<f64> {
        let plane = h * w;
        let mut out = vec![0.0f64; b * cout * plane];
        for n in 0..b {
            for o in 0..cout {
                for p in 0..plane {
                    let mut s = bias.map_or(0.0, |b| b[o] as f64);
                    for i in 0..cin {
                        s += weight[o * cin + i] as f64 * x[(n * cin + i) * plane + p] as f64;
                    }
                    out[(n * cout + o) * plane + p] = s;
                }
            }
        }
        out
    }

    // Sizes that reach every path: whole blocks of 64 pixels and a remainder, output
    // channels a multiple of the 6-row tile and not, the network's 3- and 170-wide maps.
    const CASES: [(usize, [usize; 4]); 5] = [
        (6, [1, 4, 8, 16]),
        (7, [2, 5, 9, 13]),
        (170, [1, 32, 8, 9]),
        (3, [3, 8, 5, 3]),
        (16, [2, 85, 1, 1]),
    ];

    #[test]
    fn the_projection_matches_an_f64_sum_with_and_without_bias() {
        for (k, &(cout, d)) in CASES.iter().enumerate() {
            let [b, cin, h, w] = d;
            let x = values(b * cin * h * w, 1 + k as u64);
            let weight = values(cout * cin, 10 + k as u64);
            let bias = values(cout, 20 + k as u64);
            for bias in [None, Some(bias.as_slice())] {
                let fast = pointwise(&x, &weight, bias, cout, d);
                let err = rel_err(&fast, &reference(&x, &weight, bias, cout, d));
                assert!(err < 1e-6, "{cout}x{d:?}: {err:.2e} of the scale");
            }
        }
    }

    #[test]
    fn the_portable_loop_matches_an_f64_sum() {
        let (cout, d @ [_, cin, h, w]) = (7, [1, 5, 9, 13]);
        let plane = h * w;
        let x = values(cin * plane, 3);
        let weight = values(cout * cin, 4);
        let bias = values(cout, 5);
        let mut out = vec![f32::NAN; cout * plane];
        // SAFETY: `out` holds `cout` planes; the call owns all their pixels.
        unsafe {
            project_portable(
                Out(out.as_mut_ptr()),
                &x,
                &weight,
                Some(&bias),
                (cout, cin, plane),
                0..plane,
            )
        };
        let err = rel_err(&out, &reference(&x, &weight, Some(&bias), cout, d));
        assert!(err < 1e-6, "{err:.2e} of the scale");
    }

    #[test]
    fn every_build_gives_the_portable_loops_bits() {
        for (k, &(cout, [b, cin, h, w])) in CASES.iter().enumerate() {
            let plane = h * w;
            let x = values(b * cin * plane, 60 + k as u64);
            let weight = values(cout * cin, 70 + k as u64);
            let bias = values(cout, 80 + k as u64);
            let dims = (cout, cin, plane);
            let run = |isa: base::isa::Isa| -> Vec<u32> {
                let mut out = vec![f32::NAN; cout * plane];
                let dst = Out(out.as_mut_ptr());
                let x = &x[..cin * plane];
                // SAFETY: `out` holds the item's `cout` planes and the call owns all their
                // pixels; each build runs only where `Isa::available` lists it.
                unsafe {
                    match isa {
                        #[cfg(target_arch = "x86_64")]
                        base::isa::Isa::Avx512 => {
                            project_avx512(dst, x, &weight, Some(&bias), dims, 0..plane)
                        }
                        #[cfg(target_arch = "x86_64")]
                        base::isa::Isa::Avx2 => {
                            project_avx2(dst, x, &weight, Some(&bias), dims, 0..plane)
                        }
                        _ => project_portable(dst, x, &weight, Some(&bias), dims, 0..plane),
                    }
                }
                out.iter().map(|v| v.to_bits()).collect()
            };
            let portable = run(base::isa::Isa::Portable);
            for isa in base::isa::Isa::available() {
                assert_eq!(run(isa), portable, "{isa:?}, {cout}x{cin}x{plane}");
            }
        }
    }

    #[test]
    fn the_gradients_match_f64_sums() {
        for (k, &(cout, d)) in CASES.iter().enumerate() {
            let [b, cin, h, w] = d;
            let plane = h * w;
            let x = values(b * cin * plane, 30 + k as u64);
            let weight = values(cout * cin, 40 + k as u64);
            let dy = values(b * cout * plane, 50 + k as u64);
            let (dx, dw, db) = pointwise_backward(&x, &dy, &weight, cout, d);
            let mut rdx = vec![0.0f64; dx.len()];
            let mut rdw = vec![0.0f64; dw.len()];
            let mut rdb = vec![0.0f64; db.len()];
            for n in 0..b {
                for o in 0..cout {
                    for p in 0..plane {
                        let g = dy[(n * cout + o) * plane + p] as f64;
                        rdb[o] += g;
                        for i in 0..cin {
                            let xv = x[(n * cin + i) * plane + p] as f64;
                            rdx[(n * cin + i) * plane + p] += weight[o * cin + i] as f64 * g;
                            rdw[o * cin + i] += g * xv;
                        }
                    }
                }
            }
            for (what, a, r) in [("dx", &dx, &rdx), ("dW", &dw, &rdw), ("db", &db, &rdb)] {
                let err = rel_err(a, r);
                assert!(err < 1e-5, "{cout}x{d:?} {what}: {err:.2e} of the scale");
            }
        }
    }

    #[test]
    fn empty_maps_give_empty_outputs_and_zero_gradients() {
        let d = [0, 4, 8, 8];
        assert!(pointwise(&[], &[0.5; 12], None, 3, d).is_empty());
        let (dx, dw, db) = pointwise_backward(&[], &[], &[0.5; 12], 3, d);
        assert!(dx.is_empty());
        assert_eq!((dw, db), (vec![0.0; 12], vec![0.0; 3]));
    }
}
