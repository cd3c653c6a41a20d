//! An interactive window for splat scenes: orbit, pan, zoom and fly through them with the GPU
//! rasterizer's forward pass, jump between a capture's cameras, and compare a view with what
//! the metalens saw.
//!
//! The viewer knows splats and cameras only. What a capture adds (its photos, the blur model,
//! the restorer's images) comes in through [`CompareSource`], and a training run in progress
//! through [`LiveSource`]; the `metasplat view` command supplies both from the training
//! pipeline, so this crate never depends on it.

mod app;
pub mod controls;

use std::path::PathBuf;

use glam::Vec3;
use splat::{Camera, Gaussians};

pub use controls::{ViewCamera, nearest_camera};

#[derive(Debug, thiserror::Error)]
pub enum ViewerError {
    #[error(
        "there is no display to open a window on (neither DISPLAY nor WAYLAND_DISPLAY is set); \
         `metasplat render` renders frames without one"
    )]
    NoDisplay,
    #[error("cannot open the viewer window: {0}")]
    Window(String),
    #[error(transparent)]
    Splat(#[from] splat::SplatError),
    #[error("cannot write the screenshot {path}: {reason}")]
    Screenshot { path: PathBuf, reason: String },
    #[error("{0}")]
    Invalid(String),
}

/// One of a capture's cameras, as the viewer lists it.
#[derive(Clone, Debug)]
pub struct CaptureView {
    pub name: String,
    pub camera: Camera,
    /// Held out of training (a test view).
    pub held_out: bool,
}

/// An image of a comparison, row-major RGB in [0, 1], at the capture camera's size.
#[derive(Clone, Debug)]
pub struct Panel {
    pub name: String,
    pub width: u32,
    pub height: u32,
    pub pixels: Vec<Vec3>,
    /// PSNR against the capture's clean image, when it has one.
    pub psnr_vs_clean: Option<f64>,
    /// The PSNR is inside the view's object mask (a capture with object masks), not over the
    /// whole image.
    pub on_object: bool,
}

/// What a capture shows beside a render, from one of its cameras.
pub trait CompareSource {
    /// The comparison images for capture camera `view`, given the viewer's render from exactly
    /// that camera (at its size). The render itself is expected among the panels.
    fn panels(&mut self, view: usize, render: &[Vec3]) -> Result<Vec<Panel>, String>;
}

/// A scene that changes while it is shown: a training run writing checkpoints.
pub trait LiveSource {
    /// A newer model and a sentence saying what it is, when there is one; called about once a
    /// second.
    fn poll(&mut self) -> Option<Result<(Gaussians, String), String>>;
}

/// Where the window opens.
#[derive(Clone, Debug)]
pub enum Start {
    /// Framing the splats' bounds.
    Framing,
    /// Exactly at capture camera `i`.
    Capture(usize),
    /// From `eye` looking at `target`.
    LookAt { eye: Vec3, target: Vec3 },
}

/// Save one frame of the window as a PNG and close: for tests and documentation.
#[derive(Clone, Debug)]
pub struct Screenshot {
    pub path: PathBuf,
    /// Frames drawn before the screenshot is taken.
    pub frames: u32,
    /// Show the side panel in the picture (otherwise the splats fill the window).
    pub with_panel: bool,
    /// Open in comparison mode.
    pub compare: bool,
}

pub struct ViewerOptions {
    pub title: String,
    pub model: Gaussians,
    pub captures: Vec<CaptureView>,
    pub start: Start,
    /// Vertical field of view of the free camera, radians.
    pub fov_y: f32,
    /// Window inner size in pixels.
    pub size: [u32; 2],
    pub background: Vec3,
    pub compare: Option<Box<dyn CompareSource>>,
    pub live: Option<Box<dyn LiveSource>>,
    pub screenshot: Option<Screenshot>,
}

/// What a session measured.
#[derive(Clone, Debug, Default)]
pub struct ViewerReport {
    /// Renders timed (in screenshot mode every frame renders, so this measures the rate).
    pub renders: usize,
    /// Mean time of a render after the first (which also builds the GPU pipelines), in
    /// milliseconds: the rasterizer, the read-back and the texture upload.
    pub mean_render_ms: Option<f64>,
}

/// Opens the window and returns when it closes.
pub fn run(options: ViewerOptions) -> Result<ViewerReport, ViewerError> {
    app::run(options)
}
