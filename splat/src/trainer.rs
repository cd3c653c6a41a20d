//! One training step behind one interface: a [`SplatTrainer`] owns the model, its Adam state
//! and wherever they live (host memory, GPU buffers). A step is [`SplatTrainer::render`] →
//! the caller's loss on the image → [`SplatTrainer::step`] (backward, the opacity penalty,
//! Adam, the screen-space statistics densification reads). Hooks that read or edit the model
//! go through [`SplatTrainer::host`] and [`SplatTrainer::host_mut`]; moving it between device
//! and host is the trainer's business, not the loop's.
//!
//! [`CpuTrainer`] is the reference; the GPU's (`gpu::GpuTrainer`) keeps the model resident and
//! is tested against it.

use crate::camera::Camera;
use crate::error::SplatError;
use crate::model::{Gaussians, sigmoid};
use crate::optim::{Adam, LearningRates};
use crate::rasterizer::{CpuRasterizer, PixelGradients, Rasterizer};
use crate::render::{ForwardState, Gradients, RenderOutput, RenderSettings};

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

    /// Backpropagates `pixel` through the render `saved`, adds the gradient of
    /// `opacity_reg · mean(sigmoid(logit opacity))`, and takes one Adam step with `lr`.
    fn step(
        &mut self,
        saved: Self::Saved,
        pixel: PixelGradients<'_>,
        lr: &LearningRates,
        opacity_reg: f32,
    ) -> Result<StepReport, SplatError>;

    /// The model and optimiser as they stand, for reading.
    fn host(&mut self) -> Result<(&Gaussians, &Adam), SplatError>;

    /// The model and optimiser for editing (densification, SH bands); the trainer's own copy
    /// follows the edit at the next render.
    fn host_mut(&mut self) -> Result<(&mut Gaussians, &mut Adam), SplatError>;

    /// The model and optimiser, the trainer given up.
    fn into_host(self) -> Result<(Gaussians, Adam), SplatError>;
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
        opacity_reg: f32,
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
        add_opacity_penalty(
            &mut grads.params.logit_opacities,
            &self.model.logit_opacities,
            opacity_reg,
        );
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
