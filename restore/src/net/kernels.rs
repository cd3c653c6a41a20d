//! Which implementation of the network's costly operations a forward pass uses: the fast
//! ones (the default), or the obvious ones they replaced, kept beside them so each fast path
//! is checked against its reference (`restore/tests/kernels.rs`) and timed side by side with
//! it in one run (`metasplat bench restorer`).
//!
//! The choice is per thread: the network reads it on the thread that calls `forward`, so
//! tests running in parallel cannot change each other's.

use burn::backend::flex::FlexTensor;
use burn::tensor::{Device, Tensor};
use std::cell::Cell;

#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Kernels {
    /// Attention as one fused op per window batch (no logits tensor for the whole tile, no
    /// materialised mask), query enhancement as two 1-D box passes, 1×1 convolutions as
    /// register-blocked loops on the CPU (`net/pointwise`) or matrix products elsewhere.
    Fast,
    /// The operations as first written: logits, additive mask and softmax as tensors, a
    /// `k × k` average pool, 1×1 convolutions through burn's `Conv2d`.
    Reference,
}

impl Kernels {
    pub fn name(self) -> &'static str {
        match self {
            Kernels::Fast => "fast",
            Kernels::Reference => "reference",
        }
    }
}

thread_local! {
    static CURRENT: Cell<Kernels> = const { Cell::new(Kernels::Fast) };
}

/// The kernels a forward pass on this thread uses now.
pub fn current() -> Kernels {
    CURRENT.with(Cell::get)
}

/// Runs `f` with `kernels` on this thread, then restores the previous choice (also when `f`
/// panics).
pub fn with_kernels<R>(kernels: Kernels, f: impl FnOnce() -> R) -> R {
    struct Restore(Kernels);
    impl Drop for Restore {
        fn drop(&mut self) {
            CURRENT.with(|c| c.set(self.0));
        }
    }
    let _restore = Restore(CURRENT.with(|c| c.replace(kernels)));
    f()
}

/// Whether a hand-written CPU kernel may stand in for the tensor formulation: on burn's CPU
/// backend (the kernels read and write host memory) and without gradients (they have none).
pub fn direct_applies(t: &Tensor<4>) -> bool {
    !t.is_autodiff() && t.device() == Device::flex()
}

/// A CPU tensor's values, in its logical order.
pub fn host<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.try_into_vec_as::<f32>().expect("flex tensors read back")
}

/// Whether a backend extension of this module (hand-written kernels with their own
/// gradients) may stand in for the tensor formulation: the fast kernels run and `t` is on
/// burn's CPU backend, with or without autodiff (the extensions are registered for both).
pub fn extension_applies(t: &Tensor<4>) -> bool {
    current() == Kernels::Fast && (direct_applies(t) || super::conv_train::trained_applies(t))
}

/// A dense CPU tensor's values, as the backend extensions' kernels read them.
pub(super) fn flex_slice(t: &FlexTensor) -> &[f32] {
    t.as_slice::<f32>()
        .expect("the restorer's maps are f32 on the CPU")
}

/// A CPU tensor's first `D` dimensions.
pub(super) fn flex_dims<const D: usize>(t: &FlexTensor) -> [usize; D] {
    let s = t.layout().shape();
    std::array::from_fn(|i| s[i])
}
