//! Where splats are rendered, chosen at run time: the CPU rasterizer or a GPU (wgpu). Runs,
//! checkpoints and outputs do not depend on the choice; only speed (and float rounding) does.

use std::sync::Arc;

use rayon::prelude::*;
use splat::gpu::{GpuContext, GpuRasterizer};
use splat::{Camera, Gaussians, Rasterizer, RenderOutput, RenderSettings};

use crate::error::{Result, TrainError};

/// What the user asked for (`--device`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum DeviceChoice {
    /// A hardware GPU when there is one, else the CPU. Software adapters (lavapipe) are
    /// passed over: the CPU rasterizer is faster than they are.
    #[default]
    Auto,
    Cpu,
    /// The GPU adapter wgpu finds, software ones included; an error when there is none.
    Gpu,
}

/// The rasterizer a run uses.
#[derive(Clone)]
pub enum Device {
    Cpu,
    Gpu(GpuRasterizer),
}

impl Device {
    /// The device for `choice`, with a sentence saying which and why.
    pub fn choose(choice: DeviceChoice) -> Result<(Device, String)> {
        let gpu = |ctx: GpuContext| {
            let d = ctx.describe();
            (
                Device::Gpu(GpuRasterizer::on(Arc::new(ctx))),
                format!("Rendering on {d}."),
            )
        };
        match choice {
            DeviceChoice::Cpu => Ok((Device::Cpu, "Rendering on the CPU.".into())),
            DeviceChoice::Gpu => GpuContext::new()
                .map(gpu)
                .map_err(|e| TrainError::Invalid(format!("--device gpu: {e}"))),
            DeviceChoice::Auto => Ok(match GpuContext::new() {
                Ok(ctx) if ctx.info.device_type != splat::gpu::DeviceType::Cpu => gpu(ctx),
                Ok(ctx) => (
                    Device::Cpu,
                    format!(
                        "Rendering on the CPU: the only GPU adapter, {}, is a software one (--device gpu uses it).",
                        ctx.describe()
                    ),
                ),
                Err(e) => (Device::Cpu, format!("Rendering on the CPU ({e}).")),
            }),
        }
    }

    pub fn name(&self) -> &str {
        match self {
            Device::Cpu => "cpu",
            Device::Gpu(_) => "gpu",
        }
    }

    /// Renders `g` from each camera (uploading it once).
    pub fn render_views(
        &self,
        g: &Gaussians,
        cameras: &[Camera],
        settings: &RenderSettings,
    ) -> Result<Vec<RenderOutput>> {
        Ok(match self {
            Device::Cpu => cameras
                .par_iter()
                .map(|c| splat::render(g, c, settings))
                .collect::<std::result::Result<_, _>>()?,
            Device::Gpu(gpu) => {
                let scene = gpu.upload(g)?;
                cameras
                    .iter()
                    .map(|c| gpu.render(&scene, c, settings))
                    .collect::<std::result::Result<_, _>>()?
            }
        })
    }

    pub fn render(
        &self,
        g: &Gaussians,
        camera: &Camera,
        settings: &RenderSettings,
    ) -> Result<RenderOutput> {
        let mut v = self.render_views(g, std::slice::from_ref(camera), settings)?;
        Ok(v.pop().expect("one camera, one image"))
    }
}
