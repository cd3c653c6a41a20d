//! One training step behind one interface: a [`SplatTrainer`] owns the model, its Adam state
//! and wherever they live (host memory, GPU buffers). A step is [`SplatTrainer::render`] →
//! the caller's loss on the image → [`SplatTrainer::step`] (backward, the regularisers,
//! Adam, the screen-space statistics densification reads). Hooks that read or edit the model
//! go through [`SplatTrainer::host`] and [`SplatTrainer::host_mut`]; moving it between device
//! and host is the trainer's business, not the loop's.
//!
//! [`CpuTrainer`] is the reference; the GPU's (`gpu::GpuTrainer`) keeps the model resident and
//! is tested against it.

use crate::camera::Camera;
use crate::cpu::render::{ForwardState, Gradients, RenderOutput, RenderSettings};
use crate::error::SplatError;
use crate::model::{Gaussians, sigmoid};
use crate::optim::{Adam, LearningRates};
use crate::rasterizer::{CpuRasterizer, PixelGradients, Rasterizer};

/// What one step leaves on the host.
#[derive(Clone, Debug, Default)]
pub struct StepReport {
    /// Screen-space mean gradient per Gaussian (what densification accumulates).
    pub means2d: Vec<[f32; 2]>,
    /// Some gradient was not finite: the model was not updated with it.
    pub nonfinite_gradient: bool,
    /// Some parameter is not finite after the update.
    pub nonfinite_parameter: bool,
}

/// A model being trained, with its optimiser state, wherever both live.
pub trait SplatTrainer {
    /// What a render keeps for its step (only the latest render may be stepped).
    type Saved;

    /// Number of Gaussians.
    fn len(&self) -> usize;

    fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// SH degree the model stores.
    fn sh_degree(&self) -> u32;

    /// Renders the model as it stands, keeping what [`SplatTrainer::step`] needs.
    fn render(
        &mut self,
        cam: &Camera,
        settings: &RenderSettings,
    ) -> Result<(RenderOutput, Self::Saved), SplatError>;

    /// Backpropagates `pixel` through the render `saved`, adds the gradients of the
    /// regularisers `reg`, and takes one Adam step with `lr`.
    fn step(
        &mut self,
        saved: Self::Saved,
        pixel: PixelGradients<'_>,
        lr: &LearningRates,
        reg: Regularisers,
    ) -> Result<StepReport, SplatError>;

    /// The model and optimiser as they stand, for reading.
    fn host(&mut self) -> Result<(&Gaussians, &Adam), SplatError>;

    /// The model and optimiser for editing (densification, SH bands); the trainer's own copy
    /// follows the edit at the next render.
    fn host_mut(&mut self) -> Result<(&mut Gaussians, &mut Adam), SplatError>;

    /// The model and optimiser, the trainer given up.
    fn into_host(self) -> Result<(Gaussians, Adam), SplatError>;
}

/// Penalties added to the image loss: `opacity · mean(sigmoid(logit opacity))` and
/// `scale · mean(exp(log scale))` over every axis (MCMC densification's pair, which keeps
/// Gaussians transparent and small unless the images need them). Zero turns one off.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Regularisers {
    pub opacity: f32,
    pub scale: f32,
}

impl Regularisers {
    /// Adds both penalties' gradients to `grads` for `model`.
    pub fn add_gradients(&self, grads: &mut Gaussians, model: &Gaussians) {
        add_opacity_penalty(
            &mut grads.logit_opacities,
            &model.logit_opacities,
            self.opacity,
        );
        add_scale_penalty(&mut grads.log_scales, &model.log_scales, self.scale);
    }
}

/// Adds `∂/∂x of weight · mean(exp(x))` over every axis to the log-scale gradients. (The
/// GPU's Adam kernel adds the same term in WGSL.)
pub fn add_scale_penalty(grads: &mut [glam::Vec3], log_scales: &[glam::Vec3], weight: f32) {
    if weight <= 0.0 {
        return;
    }
    let k = weight / (3 * log_scales.len()).max(1) as f32;
    for (g, &x) in grads.iter_mut().zip(log_scales) {
        *g += k * x.exp();
    }
}

/// Adds `∂/∂x of weight · mean(sigmoid(x))` to the opacity-logit gradients: a splat no view
/// needs has no other gradient, so Adam turns even this small one into full steps towards
/// transparency. (The GPU's Adam kernel adds the same term in WGSL.)
pub fn add_opacity_penalty(grads: &mut [f32], logits: &[f32], weight: f32) {
    if weight <= 0.0 {
        return;
    }
    let k = weight / logits.len().max(1) as f32;
    for (g, &x) in grads.iter_mut().zip(logits) {
        let o = sigmoid(x);
        *g += k * o * (1.0 - o);
    }
}

fn gradients_finite(g: &Gradients) -> bool {
    g.params.is_finite()
        && g.means2d
            .iter()
            .chain(&g.means2d_abs)
            .flatten()
            .all(|v| v.is_finite())
}

/// Training on the CPU rasterizer with the host Adam: the reference for every other trainer.
pub struct CpuTrainer {
    model: Gaussians,
    adam: Adam,
}

impl CpuTrainer {
    /// Takes `model` and `adam`, which must have the model's shape.
    pub fn new(model: Gaussians, adam: Adam) -> Result<Self, SplatError> {
        check_shapes(&model, &adam)?;
        Ok(Self { model, adam })
    }
}

/// The optimiser state must have the model's shape.
pub(crate) fn check_shapes(model: &Gaussians, adam: &Adam) -> Result<(), SplatError> {
    let (m, _) = adam.moments();
    if m.len() != model.len() || m.sh_degree != model.sh_degree {
        return Err(SplatError::InvalidInput(format!(
            "optimiser state for {} Gaussians of SH degree {}, model has {} of degree {}",
            m.len(),
            m.sh_degree,
            model.len(),
            model.sh_degree
        )));
    }
    Ok(())
}

impl SplatTrainer for CpuTrainer {
    type Saved = ForwardState;

    fn len(&self) -> usize {
        self.model.len()
    }

    fn sh_degree(&self) -> u32 {
        self.model.sh_degree
    }

    fn render(
        &mut self,
        cam: &Camera,
        settings: &RenderSettings,
    ) -> Result<(RenderOutput, ForwardState), SplatError> {
        let _span = tracing::info_span!("render forward").entered();
        CpuRasterizer.render_for_backward(&&self.model, cam, settings)
    }

    fn step(
        &mut self,
        saved: ForwardState,
        pixel: PixelGradients<'_>,
        lr: &LearningRates,
        reg: Regularisers,
    ) -> Result<StepReport, SplatError> {
        let mut grads = {
            let _span = tracing::info_span!("render backward").entered();
            CpuRasterizer.backward(&&self.model, &saved, pixel)?
        };
        drop(saved);
        if !gradients_finite(&grads) {
            return Ok(StepReport {
                nonfinite_gradient: true,
                ..StepReport::default()
            });
        }
        let _span = tracing::info_span!("Adam").entered();
        reg.add_gradients(&mut grads.params, &self.model);
        self.adam.step(&mut self.model, &grads.params, lr)?;
        Ok(StepReport {
            nonfinite_parameter: !self.model.is_finite(),
            means2d: grads.means2d,
            nonfinite_gradient: false,
        })
    }

    fn host(&mut self) -> Result<(&Gaussians, &Adam), SplatError> {
        Ok((&self.model, &self.adam))
    }

    fn host_mut(&mut self) -> Result<(&mut Gaussians, &mut Adam), SplatError> {
        Ok((&mut self.model, &mut self.adam))
    }

    fn into_host(self) -> Result<(Gaussians, Adam), SplatError> {
        Ok((self.model, self.adam))
    }
}
