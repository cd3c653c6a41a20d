//! Where the network runs: burn's `flex` CPU backend (always built), a GPU through burn's
//! Vulkan backend (cargo feature `vulkan`), or libtorch's CPU kernels through burn's `tch`
//! backend (cargo feature `libtorch`, to measure against flex: it links a libtorch the user
//! provides, see restore/README "Backends"). Both features are off by default so CI builds
//! burn once, for the CPU. Not CUDA, nor burn's CubeCL `cpu` backend: their builds download
//! an LLVM bundle (`tracel-llvm-bundler`), which an offline machine cannot do.

use crate::error::{RestoreError, Result};
use burn::tensor::Device;

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Compute {
    /// burn `flex`: pure Rust, all cores.
    #[default]
    Cpu,
    /// burn's wgpu backend pinned to Vulkan, on the best adapter (`CUBECL_WGPU_DEFAULT_DEVICE`
    /// overrides); needs a build with `--features vulkan`.
    Vulkan,
    /// libtorch's CPU kernels through burn's `tch` backend; needs a build with `--features
    /// libtorch`.
    Libtorch,
}

impl std::str::FromStr for Compute {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "cpu" => Ok(Self::Cpu),
            "vulkan" | "gpu" => Ok(Self::Vulkan),
            "libtorch" => Ok(Self::Libtorch),
            _ => Err(format!("unknown backend '{s}' (cpu, vulkan, libtorch)")),
        }
    }
}

impl std::fmt::Display for Compute {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Cpu => f.write_str("cpu"),
            Self::Vulkan => f.write_str("vulkan"),
            Self::Libtorch => f.write_str("libtorch"),
        }
    }
}

/// True when this build can run on a GPU.
pub const VULKAN_BUILT: bool = cfg!(feature = "vulkan");

impl Compute {
    /// The device for inference (wrap in `.autodiff()` to train). A backend this build lacks
    /// is an error, not a panic.
    pub fn device(self) -> Result<Device> {
        match self {
            Self::Cpu => Ok(Device::flex()),
            Self::Vulkan => vulkan(),
            Self::Libtorch => libtorch(),
        }
    }
}

// burn marks its tch backend deprecated; it is here only to be measured against flex.
#[cfg(feature = "libtorch")]
#[allow(deprecated)]
fn libtorch() -> Result<Device> {
    Ok(Device::libtorch())
}

#[cfg(not(feature = "libtorch"))]
fn libtorch() -> Result<Device> {
    Err(RestoreError::BadInput(
        "this build has no libtorch backend: build with `cargo build --release --features libtorch` and a libtorch in LIBTORCH (see restore/README.md)".into(),
    ))
}

/// burn's wgpu runtime panics when no adapter exists, so ask wgpu first.
#[cfg(feature = "vulkan")]
fn vulkan() -> Result<Device> {
    let mut desc = wgpu::InstanceDescriptor::new_without_display_handle_from_env();
    desc.backends = wgpu::Backends::VULKAN;
    let instance = wgpu::Instance::new(desc);
    let adapter = block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
        power_preference: wgpu::PowerPreference::HighPerformance,
        ..Default::default()
    }));
    match adapter {
        Ok(_) => Ok(Device::vulkan(burn::tensor::DeviceKind::DefaultDevice)),
        Err(e) => Err(RestoreError::BadInput(format!(
            "no Vulkan adapter for --backend vulkan ({e}); install a Vulkan driver or use --backend cpu"
        ))),
    }
}

/// Native wgpu futures are ready at their first poll or after the driver answers; spin politely.
#[cfg(feature = "vulkan")]
fn block_on<F: std::future::Future>(f: F) -> F::Output {
    let mut f = std::pin::pin!(f);
    let mut cx = std::task::Context::from_waker(std::task::Waker::noop());
    loop {
        if let std::task::Poll::Ready(v) = f.as_mut().poll(&mut cx) {
            return v;
        }
        std::thread::yield_now();
    }
}

#[cfg(not(feature = "vulkan"))]
fn vulkan() -> Result<Device> {
    Err(RestoreError::BadInput(
        "this build has no GPU backend: build with `cargo build --release --features vulkan` (see restore/README.md)".into(),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_parse_and_a_missing_backend_is_an_error() {
        assert_eq!("cpu".parse(), Ok(Compute::Cpu));
        assert_eq!("vulkan".parse(), Ok(Compute::Vulkan));
        assert_eq!(Compute::Vulkan.to_string().parse(), Ok(Compute::Vulkan));
        for bad in ["cuda", "vulkan:0", ""] {
            let e = bad.parse::<Compute>().unwrap_err();
            assert!(e.contains("unknown backend"), "{bad}: {e}");
        }
        assert!(Compute::Cpu.device().is_ok());
        if !VULKAN_BUILT {
            let e = Compute::Vulkan.device().unwrap_err().to_string();
            assert!(e.contains("--features vulkan"), "{e}");
        }
        assert_eq!("libtorch".parse(), Ok(Compute::Libtorch));
        if !cfg!(feature = "libtorch") {
            let e = Compute::Libtorch.device().unwrap_err().to_string();
            assert!(e.contains("--features libtorch"), "{e}");
        }
    }
}
