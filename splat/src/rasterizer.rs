//! The interface every rasterizer implements: the CPU one here (the reference), the GPU one
//! beside it. Two ways in, as callers need them:
//! - *upload once, render many* (evaluation, novel views, a viewer): [`Rasterizer::upload`]
//!   then [`Rasterizer::render`] per camera, which keeps nothing for a backward pass;
//! - *training*: [`Rasterizer::render_for_backward`] keeps what the backward pass needs,
//!   then [`Rasterizer::backward`] turns pixel gradients into parameter gradients.

use glam::Vec3;

use crate::camera::Camera;
use crate::cpu::render::{self, ForwardState, Gradients, RenderOutput, RenderSettings};
use crate::error::SplatError;
use crate::model::Gaussians;

/// Loss gradients with respect to the images of one forward pass, row-major like them.
#[derive(Clone, Copy, Debug)]
pub struct PixelGradients<'a> {
    pub color: &'a [Vec3],
    pub alpha: Option<&'a [f32]>,
    pub depth: Option<&'a [f32]>,
}

impl<'a> PixelGradients<'a> {
    pub fn color(color: &'a [Vec3]) -> Self {
        Self {
            color,
            alpha: None,
            depth: None,
        }
    }
}

pub trait Rasterizer {
    /// The splats where this rasterizer reads them: a borrow of the model on the CPU, buffers
    /// on a GPU.
    type Scene<'a>
    where
        Self: 'a;
    /// What a forward pass keeps for its backward pass.
    type Saved;

    /// A short name for logs and summaries.
    fn name(&self) -> &str;

    /// Makes `g` renderable; validates it once.
    fn upload<'a>(&'a self, g: &'a Gaussians) -> Result<Self::Scene<'a>, SplatError>;

    /// Renders for looking at: nothing is kept for a backward pass.
    fn render(
        &self,
        scene: &Self::Scene<'_>,
        cam: &Camera,
        settings: &RenderSettings,
    ) -> Result<RenderOutput, SplatError>;

    /// Renders and keeps what [`Rasterizer::backward`] needs.
    fn render_for_backward(
        &self,
        scene: &Self::Scene<'_>,
        cam: &Camera,
        settings: &RenderSettings,
    ) -> Result<(RenderOutput, Self::Saved), SplatError>;

    /// Parameter gradients (and densification statistics) from the pixel gradients of the
    /// forward pass that made `saved`, on the same scene.
    fn backward(
        &self,
        scene: &Self::Scene<'_>,
        saved: &Self::Saved,
        pixel: PixelGradients<'_>,
    ) -> Result<Gradients, SplatError>;
}

/// The CPU rasterizer (rayon): the numerical reference for every other implementation.
#[derive(Clone, Copy, Debug, Default)]
pub struct CpuRasterizer;

impl Rasterizer for CpuRasterizer {
    type Scene<'a> = &'a Gaussians;
    type Saved = ForwardState;

    fn name(&self) -> &str {
        "cpu"
    }

    fn upload<'a>(&'a self, g: &'a Gaussians) -> Result<&'a Gaussians, SplatError> {
        g.validate()?;
        Ok(g)
    }

    fn render(
        &self,
        scene: &&Gaussians,
        cam: &Camera,
        settings: &RenderSettings,
    ) -> Result<RenderOutput, SplatError> {
        render::render(scene, cam, settings)
    }

    fn render_for_backward(
        &self,
        scene: &&Gaussians,
        cam: &Camera,
        settings: &RenderSettings,
    ) -> Result<(RenderOutput, ForwardState), SplatError> {
        render::render_for_backward(scene, cam, settings)
    }

    fn backward(
        &self,
        scene: &&Gaussians,
        saved: &ForwardState,
        pixel: PixelGradients<'_>,
    ) -> Result<Gradients, SplatError> {
        render::render_backward(scene, saved, pixel.color, pixel.alpha, pixel.depth)
    }
}
