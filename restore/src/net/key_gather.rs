//! The overlapping key windows of every query window, gathered on the CPU, with the
//! scatter-add that is their gradient.
//!
//! As tensors ([`super::window::key_windows`]) they are a padded map unfolded along both
//! axes and permuted; burn's gradient of `unfold` was 11 % of a `tiny` training step. Here
//! the map is turned pixel-major once (each pixel's channels side by side), each window row
//! is one copy per key row, and the gradient is gathered per image row: every pixel adds up
//! the key slots that read it (at most `⌈kwin/win⌉²` windows), so no two tasks write the same
//! memory and the sums come in a fixed order. Registered with burn as a backend extension
//! ([`KeyWindowOps`]); it stands in only on burn's CPU backend, under autodiff or not.

use burn::backend::TensorMetadata;
use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops};
use burn::backend::flex::FlexTensor;
use burn::backend::{Autodiff, Backend, Dispatch, Flex, backend_extension, tensor::FloatTensor};
use burn::tensor::{Tensor, TensorData};
use rayon::prelude::*;

/// Sizes of one gather: the map `[b, c, h, w]`, query window `win`, key window `kwin`.
#[derive(Clone, Copy, Debug)]
pub struct Windows {
    pub b: usize,
    pub c: usize,
    pub h: usize,
    pub w: usize,
    pub win: usize,
    pub kwin: usize,
}

impl Windows {
    fn pad(&self) -> isize {
        ((self.kwin - self.win) / 2) as isize
    }
    fn count(&self) -> (usize, usize) {
        (self.h / self.win, self.w / self.win)
    }
    /// For key row (or column) `k` of window `i`: the map row it reads, if inside.
    fn source(&self, i: usize, k: usize, len: usize) -> Option<usize> {
        let y = (i * self.win + k) as isize - self.pad();
        (0..len as isize).contains(&y).then_some(y as usize)
    }
}

/// `[b, c, h, w]` → `[b, h, w, c]`.
fn pixel_major(x: &[f32], [b, c, h, w]: [usize; 4]) -> Vec<f32> {
    let plane = h * w;
    debug_assert_eq!(x.len(), b * c * plane);
    let mut out = vec![0.0f32; x.len()];
    if plane * c == 0 {
        return out;
    }
    out.par_chunks_mut(w * c)
        .enumerate()
        .for_each(|(row, dst)| {
            let (n, y) = (row / h, row % h);
            for ch in 0..c {
                let src = &x[(n * c + ch) * plane + y * w..][..w];
                for (px, &v) in src.iter().enumerate() {
                    dst[px * c + ch] = v;
                }
            }
        });
    out
}

/// `[b, h, w, c]` → `[b, c, h, w]`.
fn channel_major(x: &[f32], [b, c, h, w]: [usize; 4]) -> Vec<f32> {
    let plane = h * w;
    let mut out = vec![0.0f32; x.len()];
    if plane * c == 0 {
        return out;
    }
    debug_assert_eq!(x.len(), b * c * plane);
    out.par_chunks_mut(plane)
        .enumerate()
        .for_each(|(task, dst)| {
            let (n, ch) = (task / c, task % c);
            let src = &x[n * plane * c..][..plane * c];
            for (p, d) in dst.iter_mut().enumerate() {
                *d = src[p * c + ch];
            }
        });
    out
}

/// `x: [b, c, h, w]` → `[b·nh·nw, kwin², c]`: the key window around every query window,
/// zero outside the map.
pub fn gather(x: &[f32], s: Windows) -> Vec<f32> {
    let Windows {
        b, c, h, w, kwin, ..
    } = s;
    let (nh, nw) = s.count();
    let px = pixel_major(x, [b, c, h, w]);
    let slot = kwin * kwin * c;
    let mut out = vec![0.0f32; b * nh * nw * slot];
    if out.is_empty() {
        return out;
    }
    out.par_chunks_mut(slot).enumerate().for_each(|(win, dst)| {
        let (n, wy, wx) = (win / (nh * nw), win / nw % nh, win % nw);
        // The key columns inside the map are one run of pixels.
        let mut inside = (0..kwin).filter_map(|kx| s.source(wx, kx, w).map(|x| (kx, x)));
        let Some((k0, x0)) = inside.next() else {
            return;
        };
        let k1 = inside.next_back().map_or(k0, |(k, _)| k);
        let run = (k1 - k0 + 1) * c;
        for ky in 0..kwin {
            let Some(y) = s.source(wy, ky, h) else {
                continue;
            };
            let src = &px[((n * h + y) * w + x0) * c..][..run];
            dst[(ky * kwin + k0) * c..][..run].copy_from_slice(src);
        }
    });
    out
}

/// The gradient of [`gather`]: `dk: [b·nh·nw, kwin², c]` → `[b, c, h, w]`, each pixel the
/// sum of the key slots that read it.
pub fn scatter(dk: &[f32], s: Windows) -> Vec<f32> {
    let Windows {
        b,
        c,
        h,
        w,
        win,
        kwin,
    } = s;
    let (nh, nw) = s.count();
    let slot = kwin * kwin * c;
    assert_eq!(dk.len(), b * nh * nw * slot, "key windows of {s:?}");
    let mut px = vec![0.0f32; b * h * w * c];
    if px.is_empty() {
        return px;
    }
    px.par_chunks_mut(w * c).enumerate().for_each(|(row, dst)| {
        let (n, y) = (row / h, row % h);
        for wy in 0..nh {
            // Key row `ky` of window row `wy` reads map row `y`.
            let ky = y as isize + s.pad() - (wy * win) as isize;
            if !(0..kwin as isize).contains(&ky) {
                continue;
            }
            let ky = ky as usize;
            for wx in 0..nw {
                let src = &dk[(n * nh * nw + wy * nw + wx) * slot + ky * kwin * c..][..kwin * c];
                for kx in 0..kwin {
                    let Some(x) = s.source(wx, kx, w) else {
                        continue;
                    };
                    let d = &mut dst[x * c..][..c];
                    for (d, &g) in d.iter_mut().zip(&src[kx * c..][..c]) {
                        *d += g;
                    }
                }
            }
        }
    });
    channel_major(&px, [b, c, h, w])
}

/// [`super::window::key_windows`] of `x` (on burn's CPU backend) through [`KeyWindowOps`].
pub fn key_windows_tensor(x: Tensor<4>, win: usize, kwin: usize) -> Tensor<3> {
    Tensor::<3>::from_dispatch(<Dispatch as KeyWindowOps>::key_windows(
        x.into_dispatch(),
        win,
        kwin,
    ))
}

#[backend_extension(Flex, Autodiff)]
pub trait KeyWindowOps: Backend {
    /// `x: [b, c, h, w]` → `[b·nh·nw, kwin², c]`.
    fn key_windows(x: FloatTensor<Self>, win: usize, kwin: usize) -> FloatTensor<Self>;
    /// The gradient: `dk: [b·nh·nw, kwin², c]` → `[b, c, h, w]`.
    fn key_windows_grad(
        dk: FloatTensor<Self>,
        b: usize,
        h: usize,
        w: usize,
        win: usize,
        kwin: usize,
    ) -> FloatTensor<Self>;
}

fn slice(t: &FlexTensor) -> &[f32] {
    t.as_slice::<f32>()
        .expect("the restorer's maps are f32 on the CPU")
}

impl KeyWindowOps for Flex {
    fn key_windows(x: FlexTensor, win: usize, kwin: usize) -> FlexTensor {
        let x = x.to_contiguous();
        let d = x.layout().shape().to_vec();
        let (b, c, h, w) = (d[0], d[1], d[2], d[3]);
        let s = Windows {
            b,
            c,
            h,
            w,
            win,
            kwin,
        };
        let (nh, nw) = s.count();
        let out = gather(slice(&x), s);
        FlexTensor::from_data(TensorData::new(out, [b * nh * nw, kwin * kwin, c]))
    }

    fn key_windows_grad(
        dk: FlexTensor,
        b: usize,
        h: usize,
        w: usize,
        win: usize,
        kwin: usize,
    ) -> FlexTensor {
        let dk = dk.to_contiguous();
        let c = dk.layout().shape()[2];
        let s = Windows {
            b,
            c,
            h,
            w,
            win,
            kwin,
        };
        FlexTensor::from_data(TensorData::new(scatter(slice(&dk), s), [b, c, h, w]))
    }
}

#[derive(Debug)]
struct KeyWindowBackward {
    sizes: [usize; 5],
}

impl<B: Backend + KeyWindowOps> Backward<B, 1> for KeyWindowBackward {
    type State = ();

    fn backward(self, ops: Ops<(), 1>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [parent] = ops.parents;
        let dk = grads.consume::<B>(&ops.node);
        let [b, h, w, win, kwin] = self.sizes;
        if let Some(node) = parent {
            grads.register::<B>(node.id, B::key_windows_grad(dk, b, h, w, win, kwin));
        }
    }
}

impl<B: Backend + KeyWindowOps, C: CheckpointStrategy> KeyWindowOps for Autodiff<B, C> {
    fn key_windows(x: FloatTensor<Self>, win: usize, kwin: usize) -> FloatTensor<Self> {
        let node = x.node();
        let shape = x.primitive().shape();
        let sizes = [shape[0], shape[2], shape[3], win, kwin];
        let y = B::key_windows(x.into_primitive(), win, kwin);
        KeyWindowBackward { sizes }
            .prepare::<C>([node])
            .compute_bound()
            .stateless(y)
    }

    fn key_windows_grad(
        _: FloatTensor<Self>,
        _: usize,
        _: usize,
        _: usize,
        _: usize,
        _: usize,
    ) -> FloatTensor<Self> {
        unreachable!("the key windows' gradient is not differentiated")
    }
}
