//! The model as the window shows it: loaded on the window's GPU with the display settings
//! (splat scale, SH degree, background) applied, and the texture of the last render, redrawn
//! only when the camera, a setting or the model changed.

use std::sync::{Arc, Mutex};
use std::time::Instant;

use eframe::egui;
use egui::TextureHandle;
use glam::Vec3;
use splat::gpu::{GpuRasterizer, GpuScene};
use splat::{Camera, Gaussians, Rasterizer, RenderOutput, RenderSettings};

use super::draw::color_image;
use crate::ViewerError;

/// The model on the GPU and the display settings it is rendered with.
pub(super) struct ShownModel {
    raster: GpuRasterizer,
    /// The adapter, described for the panel.
    pub adapter: String,
    /// The model as loaded; the GPU holds it with the splat-scale slider applied.
    pub model: Gaussians,
    scene: GpuScene<'static>,
    pub splat_scale: f32,
    uploaded_scale: f32,
    pub background: [f32; 3],
    pub sh_degree: u32,
    /// Counts uploads: what was rendered from an older one is stale.
    pub generation: u64,
}

impl ShownModel {
    pub fn new(
        raster: GpuRasterizer,
        adapter: String,
        model: Gaussians,
        background: Vec3,
    ) -> Result<Self, ViewerError> {
        let scene = raster.upload_static(&model)?;
        Ok(Self {
            raster,
            adapter,
            sh_degree: model.sh_degree,
            model,
            scene,
            splat_scale: 1.0,
            uploaded_scale: 1.0,
            background: background.to_array(),
            generation: 0,
        })
    }

    /// Re-uploads the model when the splat-scale slider moved or a live run sent a new one.
    pub fn sync(&mut self) -> Result<(), ViewerError> {
        if self.splat_scale == self.uploaded_scale {
            return Ok(());
        }
        let mut g = self.model.clone();
        let shift = self.splat_scale.ln();
        for s in &mut g.log_scales {
            *s += Vec3::splat(shift);
        }
        self.scene = self.raster.upload_static(&g)?;
        self.uploaded_scale = self.splat_scale;
        self.generation += 1;
        Ok(())
    }

    pub fn replace(&mut self, g: Gaussians) -> Result<(), ViewerError> {
        g.validate()?;
        // The SH slider follows the model unless the user lowered it.
        let follow = self.sh_degree == self.model.sh_degree;
        self.sh_degree = if follow {
            g.sh_degree
        } else {
            self.sh_degree.min(g.sh_degree)
        };
        self.model = g;
        self.uploaded_scale = f32::NAN;
        self.sync()
    }

    /// The display settings.
    pub fn settings(&self) -> RenderSettings {
        RenderSettings {
            sh_degree: self.sh_degree.min(self.model.sh_degree),
            background: Vec3::from_array(self.background),
            ..Default::default()
        }
    }

    /// The comparison is against training's renders, which use the model's full SH degree and
    /// a black background, whatever the display settings are.
    pub fn settings_for_compare(&self) -> RenderSettings {
        RenderSettings {
            sh_degree: self.model.sh_degree,
            ..Default::default()
        }
    }

    pub fn render(
        &self,
        cam: &Camera,
        settings: &RenderSettings,
    ) -> Result<RenderOutput, ViewerError> {
        Ok(self.raster.render(&self.scene, cam, settings)?)
    }
}

/// What a shown render depends on.
#[derive(Clone, Debug, PartialEq)]
struct RenderKey {
    camera: Camera,
    sh_degree: u32,
    background: Vec3,
    generation: u64,
}

/// The texture of the latest render and the render and frame times the panel shows.
#[derive(Default)]
pub(super) struct ViewImage {
    pub texture: Option<TextureHandle>,
    key: Option<RenderKey>,
    pub render_ms: f32,
    /// Smoothed time between frames.
    pub frame_ms: f32,
    last_frame: Option<Instant>,
    /// Every render's time, for the report at the end.
    timings: Arc<Mutex<Vec<f32>>>,
}

impl ViewImage {
    pub fn new(timings: Arc<Mutex<Vec<f32>>>) -> Self {
        Self {
            timings,
            ..Self::default()
        }
    }

    /// Counts a frame for the frame rate.
    pub fn tick(&mut self) {
        let now = Instant::now();
        if let Some(last) = self.last_frame {
            let ms = now.duration_since(last).as_secs_f32() * 1e3;
            self.frame_ms = if self.frame_ms == 0.0 {
                ms
            } else {
                0.9 * self.frame_ms + 0.1 * ms
            };
        }
        self.last_frame = Some(now);
    }

    /// The next frame renders even if nothing changed.
    pub fn invalidate(&mut self) {
        self.key = None;
    }

    /// Renders `shown` from `cam` into the texture unless nothing changed since the last
    /// frame.
    pub fn update(
        &mut self,
        ctx: &egui::Context,
        shown: &ShownModel,
        cam: Camera,
    ) -> Result<(), ViewerError> {
        let settings = shown.settings();
        let key = RenderKey {
            camera: cam,
            sh_degree: settings.sh_degree,
            background: settings.background,
            generation: shown.generation,
        };
        if self.key.as_ref() == Some(&key) && self.texture.is_some() {
            return Ok(());
        }
        let start = Instant::now();
        let out = shown.render(&key.camera, &settings)?;
        self.render_ms = start.elapsed().as_secs_f32() * 1e3;
        self.timings
            .lock()
            .expect("no panics hold this lock")
            .push(self.render_ms);
        let (w, h) = (key.camera.width, key.camera.height);
        let image = color_image(w, h, &out.color);
        match &mut self.texture {
            Some(t) => t.set(image, egui::TextureOptions::NEAREST),
            None => {
                self.texture =
                    Some(ctx.load_texture("splats", image, egui::TextureOptions::NEAREST))
            }
        }
        self.key = Some(key);
        Ok(())
    }
}
