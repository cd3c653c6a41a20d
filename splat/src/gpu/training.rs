//! A model trained on the GPU: its parameters and Adam moments stay resident across steps,
//! and a step reads back only the rendered images (for the loss, which runs on the host), the
//! screen-space mean gradients densification accumulates, and one word of finiteness flags.
//! The host copy is brought back ([`GpuTraining::download`]) when something there needs it —
//! densification, SH-band tests, evaluation, checkpoints — and the model is uploaded again
//! only when the host changed it. [`GpuTrainer`] puts that behind [`SplatTrainer`].

use crate::camera::Camera;
use crate::cpu::render::{RenderOutput, RenderSettings};
use crate::error::SplatError;
use crate::model::Gaussians;
use crate::optim::{Adam, LearningRates};
use crate::rasterizer::PixelGradients;
use crate::trainer::{Regularisers, SplatTrainer, StepReport, check_shapes};

use super::util::{
    Pool, Scratch, bind_resources, blocks, dispatch, f32s, grid, part, read_back, storage_init,
    u32s, uniform,
};
use super::{GpuRasterizer, GpuSaved, GpuScene};

/// A model and its optimiser state on one GPU.
pub struct GpuTraining {
    raster: GpuRasterizer,
    scene: GpuScene<'static>,
    m: wgpu::Buffer,
    v: wgpu::Buffer,
    steps: u64,
    beta1: f32,
    beta2: f32,
    eps: f32,
    /// Working buffers, reused from step to step.
    pool: Pool,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct AdamUniform {
    n: u32,
    stride: u32,
    reg: f32,
    eps: f32,
    b1: f32,
    b2: f32,
    bc1: f32,
    bc2: f32,
    lr_a: [f32; 4],
    lr_b: [f32; 4],
}

impl GpuTraining {
    /// Uploads `model` and the moments of `adam`, which must have the model's shape.
    pub fn new(raster: &GpuRasterizer, model: &Gaussians, adam: &Adam) -> Result<Self, SplatError> {
        check_shapes(model, adam)?;
        let (m, v) = adam.moments();
        let scene = raster.upload_static(model)?;
        let dev = &raster.ctx.device;
        Ok(Self {
            m: storage_init(dev, "adam m", bytemuck::cast_slice(&m.packed())),
            v: storage_init(dev, "adam v", bytemuck::cast_slice(&v.packed())),
            raster: raster.clone(),
            scene,
            steps: adam.steps_taken(),
            beta1: adam.beta1,
            beta2: adam.beta2,
            eps: adam.eps,
            pool: Pool::default(),
        })
    }

    pub fn len(&self) -> usize {
        self.scene.len()
    }

    pub fn is_empty(&self) -> bool {
        self.scene.is_empty()
    }

    /// Renders the resident model, keeping what the backward pass needs (in working buffers
    /// the next render reuses, so only the latest render can be backpropagated).
    pub fn render_for_backward(
        &mut self,
        cam: &Camera,
        settings: &RenderSettings,
    ) -> Result<(RenderOutput, GpuSaved), SplatError> {
        self.pool.reset();
        self.raster.forward(
            &self.scene,
            cam,
            settings,
            &mut Scratch(Some(&mut self.pool)),
        )
    }

    /// Bytes of working buffers kept between steps.
    pub fn scratch_bytes(&self) -> u64 {
        self.pool.bytes()
    }

    /// Backpropagates `pixel` through the render `saved` and takes one Adam step with `lr`,
    /// adding the regularisers' gradients first.
    pub fn step(
        &mut self,
        saved: &GpuSaved,
        pixel: PixelGradients<'_>,
        lr: &LearningRates,
        reg: Regularisers,
    ) -> Result<StepReport, SplatError> {
        let (raster, scene) = (&self.raster, &self.scene);
        let dev = &raster.ctx.device;
        let mut enc = dev.create_command_encoder(&Default::default());
        let (screen, grads) = raster.encode_backward(
            scene,
            saved,
            pixel,
            &mut enc,
            &mut Scratch(Some(&mut self.pool)),
        )?;
        let flags = self.encode_adam(&grads, lr, reg, &mut enc, true)?;
        self.finish(enc, Some(&screen), &flags)
    }

    /// One Adam step with gradients given by the host (the optimiser on its own, for tests).
    #[doc(hidden)]
    pub fn apply_gradients(
        &mut self,
        grads: &Gaussians,
        lr: &LearningRates,
        reg: Regularisers,
    ) -> Result<StepReport, SplatError> {
        if grads.len() != self.len() || grads.sh_degree != self.scene.sh_degree {
            return Err(SplatError::InvalidInput(
                "gradients differ in shape from the model".into(),
            ));
        }
        let dev = &self.raster.ctx.device;
        let g = storage_init(dev, "gradients", bytemuck::cast_slice(&grads.packed()));
        let mut enc = dev.create_command_encoder(&Default::default());
        let flags = self.encode_adam(&g, lr, reg, &mut enc, false)?;
        self.finish(enc, None, &flags)
    }

    fn encode_adam(
        &mut self,
        grads: &wgpu::Buffer,
        lr: &LearningRates,
        reg: Regularisers,
        enc: &mut wgpu::CommandEncoder,
        // In the step's pool (after a render, which starts the pool over) or a buffer of its own.
        pooled: bool,
    ) -> Result<wgpu::Buffer, SplatError> {
        let (raster, scene) = (&self.raster, &self.scene);
        let dev = &raster.ctx.device;
        let values = scene.n as u64 * scene.stride as u64;
        let n = u32::try_from(values).map_err(|_| {
            SplatError::Gpu(format!("{values} parameters are more than a u32 counts"))
        })?;
        self.steps += 1;
        let t = self.steps as i32;
        let u = AdamUniform {
            n,
            stride: scene.stride,
            reg: reg.opacity.max(0.0) / scene.n.max(1) as f32,
            eps: self.eps,
            b1: self.beta1,
            b2: self.beta2,
            bc1: 1.0 - self.beta1.powi(t),
            bc2: 1.0 - self.beta2.powi(t),
            lr_a: [lr.means, lr.log_scales, lr.rotations, lr.opacities],
            lr_b: [
                lr.sh_dc,
                lr.sh_rest,
                reg.scale.max(0.0) / (3 * scene.n.max(1)) as f32,
                0.0,
            ],
        };
        let flags = Scratch(pooled.then_some(&mut self.pool)).storage(dev, "adam flags", 4);
        enc.clear_buffer(&flags, 0, None);
        let k = &raster.kernels;
        let bytes = 4 * scene.stride as u64;
        // Piece by piece, as the projection binds the parameters: each piece starts at a
        // Gaussian, so a value's group is still its index modulo the stride.
        for (first, count) in raster.chunks(scene.n, scene.stride) {
            let cfg = AdamUniform {
                n: count * scene.stride,
                ..u
            };
            let cfg = uniform(dev, "adam step", bytemuck::bytes_of(&cfg));
            let (at, len) = (bytes * first as u64, bytes * count as u64);
            let g = bind_resources(
                dev,
                &k.adam,
                vec![
                    cfg.as_entire_binding(),
                    part(&scene.params, at, len),
                    part(grads, at, len),
                    part(&self.m, at, len),
                    part(&self.v, at, len),
                    flags.as_entire_binding(),
                ],
            );
            dispatch(enc, &k.adam, &g, grid(blocks(count * scene.stride)));
        }
        Ok(flags)
    }

    fn finish(
        &self,
        enc: wgpu::CommandEncoder,
        screen: Option<&wgpu::Buffer>,
        flags: &wgpu::Buffer,
    ) -> Result<StepReport, SplatError> {
        let raster = &self.raster;
        let screen_bytes = if screen.is_some() {
            48 * self.scene.n as u64
        } else {
            0
        };
        let bytes = read_back(
            &raster.ctx.device,
            &raster.ctx.queue,
            enc,
            &[(flags, 0, 4), (screen.unwrap_or(flags), 0, screen_bytes)],
        )?;
        let flag = u32s(&bytes[0])[0];
        Ok(StepReport {
            means2d: f32s(&bytes[1])
                .chunks_exact(12)
                .map(|v| [v[0], v[1]])
                .collect(),
            nonfinite_gradient: flag & 1 != 0,
            nonfinite_parameter: flag & 2 != 0,
        })
    }

    /// The model and optimiser as they stand on the GPU.
    pub fn download(&self) -> Result<(Gaussians, Adam), SplatError> {
        let raster = &self.raster;
        let dev = &raster.ctx.device;
        let bytes = 4 * self.scene.n as u64 * self.scene.stride as u64;
        let enc = dev.create_command_encoder(&Default::default());
        let b = read_back(
            dev,
            &raster.ctx.queue,
            enc,
            &[
                (&self.scene.params, 0, bytes),
                (&self.m, 0, bytes),
                (&self.v, 0, bytes),
            ],
        )?;
        let d = self.scene.sh_degree;
        let model = Gaussians::from_packed(&f32s(&b[0]), d)?;
        let m = Gaussians::from_packed(&f32s(&b[1]), d)?;
        let v = Gaussians::from_packed(&f32s(&b[2]), d)?;
        let mut adam = Adam::from_state(self.steps, m, v)?;
        (adam.beta1, adam.beta2, adam.eps) = (self.beta1, self.beta2, self.eps);
        Ok((model, adam))
    }
}

/// [`SplatTrainer`] on a GPU: the model and its moments resident between the steps, brought
/// to the host when a hook reads them and uploaded again after a hook edits them.
pub struct GpuTrainer {
    raster: GpuRasterizer,
    /// The host copy, current when `host_current` (else the GPU's is newer).
    model: Gaussians,
    adam: Adam,
    host_current: bool,
    /// None until the first render, and after the host copy was edited.
    resident: Option<GpuTraining>,
}

impl GpuTrainer {
    /// Takes `model` and `adam`, which must have the model's shape; nothing is uploaded until
    /// the first render.
    pub fn new(raster: &GpuRasterizer, model: Gaussians, adam: Adam) -> Result<Self, SplatError> {
        check_shapes(&model, &adam)?;
        Ok(Self {
            raster: raster.clone(),
            model,
            adam,
            host_current: true,
            resident: None,
        })
    }

    fn bring_back(&mut self) -> Result<(), SplatError> {
        if !self.host_current
            && let Some(r) = &self.resident
        {
            let _span = tracing::info_span!("model to the host").entered();
            (self.model, self.adam) = r.download()?;
        }
        self.host_current = true;
        Ok(())
    }
}

impl SplatTrainer for GpuTrainer {
    type Saved = GpuSaved;

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
    ) -> Result<(RenderOutput, GpuSaved), SplatError> {
        if self.resident.is_none() {
            let _span = tracing::info_span!("model to the GPU").entered();
            self.resident = Some(GpuTraining::new(&self.raster, &self.model, &self.adam)?);
        }
        let _span = tracing::info_span!("render forward").entered();
        self.resident
            .as_mut()
            .expect("uploaded above")
            .render_for_backward(cam, settings)
    }

    fn step(
        &mut self,
        saved: GpuSaved,
        pixel: PixelGradients<'_>,
        lr: &LearningRates,
        reg: Regularisers,
    ) -> Result<StepReport, SplatError> {
        let Some(r) = self.resident.as_mut() else {
            return Err(SplatError::InvalidInput(
                "a step needs the render it follows".into(),
            ));
        };
        let _span = tracing::info_span!("render backward and Adam").entered();
        let report = r.step(&saved, pixel, lr, reg)?;
        self.host_current = false;
        Ok(report)
    }

    fn host(&mut self) -> Result<(&Gaussians, &Adam), SplatError> {
        self.bring_back()?;
        Ok((&self.model, &self.adam))
    }

    fn host_mut(&mut self) -> Result<(&mut Gaussians, &mut Adam), SplatError> {
        self.bring_back()?;
        self.resident = None;
        Ok((&mut self.model, &mut self.adam))
    }

    fn into_host(mut self) -> Result<(Gaussians, Adam), SplatError> {
        self.bring_back()?;
        Ok((self.model, self.adam))
    }
}
