//! The wgpu device the rasterizer runs on: chosen once, shared by every scene and render.

use crate::error::SplatError;

/// An adapter, its device and queue.
pub struct GpuContext {
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub info: wgpu::AdapterInfo,
    pub limits: wgpu::Limits,
}

impl GpuContext {
    /// The most capable adapter there is (`WGPU_BACKEND` and the other wgpu environment
    /// variables are honoured); an error, never a panic, when there is none.
    pub fn new() -> Result<Self, SplatError> {
        let instance =
            wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
        let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            ..Default::default()
        }))
        .map_err(|e| SplatError::Gpu(format!("no GPU adapter: {e}")))?;
        let info = adapter.get_info();
        // Ask for what the adapter offers: large scenes need large storage buffers.
        let limits = adapter.limits();
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("splat"),
            required_limits: limits.clone(),
            ..Default::default()
        }))
        .map_err(|e| SplatError::Gpu(format!("cannot open {}: {e}", info.name)))?;
        Ok(Self {
            device,
            queue,
            info,
            limits,
        })
    }

    /// A device somebody else opened (a window's renderer), so the splats render where they
    /// are shown, without a copy between devices.
    pub fn from_parts(device: wgpu::Device, queue: wgpu::Queue, info: wgpu::AdapterInfo) -> Self {
        let limits = device.limits();
        Self {
            device,
            queue,
            info,
            limits,
        }
    }

    /// "NAME (BACKEND, TYPE)", for logs.
    pub fn describe(&self) -> String {
        format!(
            "{} ({:?}, {:?})",
            self.info.name, self.info.backend, self.info.device_type
        )
    }

    /// Refuses a buffer larger than the device can create.
    pub fn check_buffer(&self, what: &str, bytes: u64) -> Result<(), SplatError> {
        let max = self.limits.max_buffer_size;
        if bytes > max {
            return Err(SplatError::Gpu(format!(
                "{what} needs {bytes} bytes, more than this GPU holds in one buffer ({max})"
            )));
        }
        Ok(())
    }

    /// Refuses a buffer larger than the device can bind.
    pub fn check_size(&self, what: &str, bytes: u64) -> Result<(), SplatError> {
        let max = self
            .limits
            .max_storage_buffer_binding_size
            .min(self.limits.max_buffer_size);
        if bytes > max {
            return Err(SplatError::Gpu(format!(
                "{what} needs {bytes} bytes, more than this GPU binds in one buffer ({max})"
            )));
        }
        Ok(())
    }
}
