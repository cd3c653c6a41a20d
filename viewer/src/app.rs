//! The window: eframe (winit + wgpu) with an egui side panel. The splats are rendered by
//! `splat`'s GPU rasterizer on the window's own device and shown as a texture.

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use eframe::egui;
use egui::{Color32, ColorImage, Key, PointerButton, Pos2, Rect, Sense, TextureHandle, Vec2};
use glam::Vec3;
use splat::gpu::{GpuContext, GpuRasterizer, GpuScene};
use splat::{Gaussians, Rasterizer, RenderSettings};

use crate::controls::{ViewCamera, nearest_camera};
use crate::{CaptureView, Panel, Screenshot, Start, ViewerError, ViewerOptions, ViewerReport};

/// Radians the view turns per pixel dragged.
const TURN_PER_PIXEL: f32 = 0.006;
/// How often a live run is checked for a newer model.
const LIVE_POLL: Duration = Duration::from_secs(1);

pub fn run(options: ViewerOptions) -> Result<ViewerReport, ViewerError> {
    check_display()?;
    options.model.validate()?;
    if let Start::Capture(i) = options.start
        && i >= options.captures.len()
    {
        return Err(ViewerError::Invalid(format!(
            "camera {i} does not exist: the capture has {} cameras",
            options.captures.len()
        )));
    }
    let [w, h] = options.size;
    let title = options.title.clone();
    let native = eframe::NativeOptions {
        viewport: egui::ViewportBuilder::default()
            .with_title(title.clone())
            .with_inner_size([w as f32, h as f32]),
        wgpu_options: wgpu_options(),
        ..Default::default()
    };
    // The app is built inside the event loop; an error there comes back through this slot.
    let failure: Arc<Mutex<Option<ViewerError>>> = Arc::default();
    let slot = failure.clone();
    let timings: Arc<Mutex<Vec<f32>>> = Arc::default();
    let times = timings.clone();
    let result = eframe::run_native(
        &title,
        native,
        Box::new(
            move |cc| match Viewer::new(cc, options, slot.clone(), times) {
                Ok(v) => Ok(Box::new(v)),
                Err(e) => {
                    let message = e.to_string();
                    *slot.lock().expect("no panics hold this lock") = Some(e);
                    Err(message.into())
                }
            },
        ),
    );
    if let Some(e) = failure.lock().expect("no panics hold this lock").take() {
        return Err(e);
    }
    let t = timings.lock().expect("no panics hold this lock");
    let report = ViewerReport {
        renders: t.len(),
        mean_render_ms: (t.len() > 1)
            .then(|| t[1..].iter().map(|&v| v as f64).sum::<f64>() / (t.len() - 1) as f64),
    };
    result.map(|()| report).map_err(|e| match e {
        eframe::Error::Wgpu(e) => ViewerError::Window(format!(
            "no GPU can draw into the window ({e}); `metasplat render --device cpu` renders frames without one"
        )),
        e => ViewerError::Window(e.to_string()),
    })
}

/// winit needs an X11 or Wayland display on Unix; without one it would fail deep inside the
/// event loop with a less helpful message.
fn check_display() -> Result<(), ViewerError> {
    if cfg!(all(unix, not(target_os = "macos")))
        && std::env::var_os("DISPLAY").is_none_or(|d| d.is_empty())
        && std::env::var_os("WAYLAND_DISPLAY").is_none_or(|d| d.is_empty())
    {
        return Err(ViewerError::NoDisplay);
    }
    Ok(())
}

/// eframe's device, opened with the adapter's own limits: large scenes need storage buffers
/// larger than wgpu's defaults.
fn wgpu_options() -> egui_wgpu::WgpuConfiguration {
    let mut setup = egui_wgpu::WgpuSetupCreateNew::without_display_handle();
    setup.instance_descriptor.backends =
        wgpu::Backends::from_env().unwrap_or(wgpu::Backends::PRIMARY);
    setup.device_descriptor = Arc::new(|adapter: &wgpu::Adapter| wgpu::DeviceDescriptor {
        label: Some("metasplat viewer"),
        required_limits: adapter.limits(),
        ..Default::default()
    });
    egui_wgpu::WgpuConfiguration {
        wgpu_setup: egui_wgpu::WgpuSetup::CreateNew(setup),
        ..Default::default()
    }
}

use eframe::egui_wgpu;

/// The panels shown for one capture camera and model generation, with their textures.
type Comparison = (usize, u64, Vec<(Panel, TextureHandle)>);

#[derive(Clone, Copy, PartialEq)]
enum CompareLayout {
    SideBySide,
    Swipe,
}

struct Viewer {
    raster: GpuRasterizer,
    adapter: String,
    /// The model as loaded; the GPU holds it with the splat-scale slider applied.
    model: Gaussians,
    scene: GpuScene<'static>,
    captures: Vec<CaptureView>,
    home: ViewCamera,
    view: ViewCamera,
    /// Capture camera the view sits on, if any.
    at_capture: Option<usize>,
    fov_deg: f32,
    speed: f32,
    splat_scale: f32,
    uploaded_scale: f32,
    background: [f32; 3],
    sh_degree: u32,
    texture: Option<TextureHandle>,
    last_key: Option<(Vec<u8>, u64)>,
    generation: u64,
    render_ms: f32,
    frame_ms: f32,
    last_frame: Option<Instant>,
    status: String,
    compare_source: Option<Box<dyn crate::CompareSource>>,
    compare_on: bool,
    layout: CompareLayout,
    swipe: f32,
    swipe_pair: (usize, usize),
    panels: Option<Comparison>,
    live: Option<Box<dyn crate::LiveSource>>,
    last_poll: Instant,
    screenshot: Option<Screenshot>,
    frames: u32,
    shot: Arc<Mutex<Option<Arc<ColorImage>>>>,
    shot_requested: bool,
    failure: Arc<Mutex<Option<ViewerError>>>,
    timings: Arc<Mutex<Vec<f32>>>,
}

impl Viewer {
    fn new(
        cc: &eframe::CreationContext<'_>,
        o: ViewerOptions,
        failure: Arc<Mutex<Option<ViewerError>>>,
        timings: Arc<Mutex<Vec<f32>>>,
    ) -> Result<Self, ViewerError> {
        let rs = cc
            .wgpu_render_state
            .as_ref()
            .ok_or_else(|| ViewerError::Window("the window has no wgpu renderer".into()))?;
        let info = rs.adapter.get_info();
        let ctx = GpuContext::from_parts(rs.device.clone(), rs.queue.clone(), info);
        let adapter = ctx.describe();
        let raster = GpuRasterizer::on(Arc::new(ctx));
        let scene = raster.upload_static(&o.model)?;
        let home = match &o.start {
            Start::LookAt { eye, target } => ViewCamera::looking(*eye, *target, o.fov_y),
            _ => ViewCamera::framing(&o.model.means, o.fov_y).ok_or_else(|| {
                ViewerError::Invalid("no splat has a finite position to frame".into())
            })?,
        };
        let mut viewer = Self {
            raster,
            adapter,
            sh_degree: o.model.sh_degree,
            model: o.model,
            scene,
            captures: o.captures,
            view: home.clone(),
            home,
            at_capture: None,
            fov_deg: o.fov_y.to_degrees(),
            speed: 0.5,
            splat_scale: 1.0,
            uploaded_scale: 1.0,
            background: o.background.to_array(),
            texture: None,
            last_key: None,
            generation: 0,
            render_ms: 0.0,
            frame_ms: 0.0,
            last_frame: None,
            status: String::new(),
            compare_on: o.screenshot.as_ref().is_some_and(|s| s.compare),
            compare_source: o.compare,
            layout: CompareLayout::SideBySide,
            swipe: 0.5,
            swipe_pair: (0, 1),
            panels: None,
            live: o.live,
            last_poll: Instant::now(),
            screenshot: o.screenshot,
            frames: 0,
            shot: Arc::default(),
            shot_requested: false,
            failure,
            timings,
        };
        if let Start::Capture(i) = o.start {
            viewer.go_to_capture(i);
        }
        Ok(viewer)
    }

    fn go_to_capture(&mut self, i: usize) {
        let Some(c) = self.captures.get(i) else {
            return;
        };
        self.view = ViewCamera::at_capture(&c.camera, self.home.scale.max(1e-3) * 0.5);
        self.view.scale = self.home.scale;
        self.at_capture = Some(i);
    }

    fn fail(&mut self, ctx: &egui::Context, e: ViewerError) {
        *self.failure.lock().expect("no panics hold this lock") = Some(e);
        ctx.send_viewport_cmd(egui::ViewportCommand::Close);
    }

    /// Re-uploads the model when the splat-scale slider moved or a live run sent a new one.
    fn sync_scene(&mut self) -> Result<(), ViewerError> {
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

    fn replace_model(&mut self, g: Gaussians) -> Result<(), ViewerError> {
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
        self.sync_scene()
    }

    fn settings(&self) -> RenderSettings {
        RenderSettings {
            sh_degree: self.sh_degree.min(self.model.sh_degree),
            background: Vec3::from_array(self.background),
            ..Default::default()
        }
    }

    /// Renders the view at `w`×`h` into the texture unless nothing changed since the last
    /// frame.
    fn render_view(&mut self, ctx: &egui::Context, w: u32, h: u32) -> Result<(), ViewerError> {
        let cam = self.view.camera(w, h);
        let settings = self.settings();
        let key = format!("{cam:?}{:?}{:?}", settings.sh_degree, settings.background).into_bytes();
        if self.last_key.as_ref() == Some(&(key.clone(), self.generation)) && self.texture.is_some()
        {
            return Ok(());
        }
        let start = Instant::now();
        let out = self.raster.render(&self.scene, &cam, &settings)?;
        self.render_ms = start.elapsed().as_secs_f32() * 1e3;
        self.timings
            .lock()
            .expect("no panics hold this lock")
            .push(self.render_ms);
        let image = color_image(w, h, &out.color);
        match &mut self.texture {
            Some(t) => t.set(image, egui::TextureOptions::NEAREST),
            None => {
                self.texture =
                    Some(ctx.load_texture("splats", image, egui::TextureOptions::NEAREST))
            }
        }
        self.last_key = Some((key, self.generation));
        Ok(())
    }

    /// The comparison images at the current capture camera, computed once per camera and
    /// model.
    fn comparison(&mut self, ctx: &egui::Context) -> Result<(), String> {
        let Some(i) = self.at_capture else {
            return Err("comparison needs a capture camera: pick one in the list".into());
        };
        if self
            .panels
            .as_ref()
            .is_some_and(|(v, g, _)| *v == i && *g == self.generation)
        {
            return Ok(());
        }
        if self.compare_source.is_none() {
            return Err("comparison needs a capture: open the viewer with --scene".into());
        }
        let cam = self.captures[i].camera.clone();
        let out = self
            .raster
            .render(&self.scene, &cam, &self.settings_for_compare())
            .map_err(|e| e.to_string())?;
        let source = self.compare_source.as_mut().expect("checked above");
        let panels = source.panels(i, &out.color)?;
        if panels.is_empty() {
            return Err("the capture offers nothing to compare".into());
        }
        let textures = panels
            .into_iter()
            .map(|p| {
                let t = ctx.load_texture(
                    format!("panel {}", p.name),
                    color_image(p.width, p.height, &p.pixels),
                    egui::TextureOptions::LINEAR,
                );
                (p, t)
            })
            .collect::<Vec<_>>();
        let n = textures.len();
        self.swipe_pair = (self.swipe_pair.0.min(n - 1), self.swipe_pair.1.min(n - 1));
        self.panels = Some((i, self.generation, textures));
        Ok(())
    }

    /// The comparison is against training's renders, which use the model's full SH degree and
    /// a black background, whatever the display settings are.
    fn settings_for_compare(&self) -> RenderSettings {
        RenderSettings {
            sh_degree: self.model.sh_degree,
            ..Default::default()
        }
    }

    fn handle_input(&mut self, ui: &egui::Ui, response: &egui::Response) {
        let d = response.drag_delta();
        if response.dragged_by(PointerButton::Primary) && d != Vec2::ZERO {
            self.view.orbit(-d.x * TURN_PER_PIXEL, d.y * TURN_PER_PIXEL);
            self.at_capture = None;
        }
        if (response.dragged_by(PointerButton::Secondary)
            || response.dragged_by(PointerButton::Middle))
            && d != Vec2::ZERO
        {
            let hgt = response.rect.height().max(1.0);
            self.view.pan(-d.x / hgt, -d.y / hgt);
            self.at_capture = None;
        }
        if response.hovered() {
            let scroll = ui.input(|i| i.smooth_scroll_delta.y);
            if scroll != 0.0 {
                self.view.zoom(scroll / 40.0);
                self.at_capture = None;
            }
        }
        if ui.ctx().egui_wants_keyboard_input() {
            return;
        }
        let (dt, keys) = ui.input(|i| {
            let k = |key| if i.key_down(key) { 1.0f32 } else { 0.0 };
            (
                i.stable_dt.min(0.1),
                [
                    k(Key::W) - k(Key::S),
                    k(Key::D) - k(Key::A),
                    k(Key::E) - k(Key::Q),
                ],
            )
        });
        if keys != [0.0; 3] {
            let step = self.speed * dt;
            self.view
                .fly(keys[0] * step, keys[1] * step, keys[2] * step);
            self.at_capture = None;
            ui.ctx().request_repaint();
        }
        let pressed = |key| ui.input(|i| i.key_pressed(key));
        if pressed(Key::R) {
            self.view = self.home.clone();
            self.at_capture = None;
        }
        if !self.captures.is_empty() {
            let n = self.captures.len();
            if pressed(Key::N) || pressed(Key::ArrowRight) {
                self.go_to_capture(self.at_capture.map_or(0, |i| (i + 1) % n));
            }
            if pressed(Key::P) || pressed(Key::ArrowLeft) {
                self.go_to_capture(self.at_capture.map_or(n - 1, |i| (i + n - 1) % n));
            }
            if pressed(Key::Space) {
                let cams: Vec<_> = self.captures.iter().map(|c| c.camera.clone()).collect();
                if let Some(i) = nearest_camera(&cams, self.view.eye()) {
                    self.go_to_capture(i);
                }
            }
        }
        if pressed(Key::C) && self.compare_source.is_some() {
            self.compare_on = !self.compare_on;
        }
    }

    fn side_panel(&mut self, ui: &mut egui::Ui) {
        ui.heading("metasplat");
        ui.label(format!(
            "{} splats, SH degree {}",
            self.model.len(),
            self.model.sh_degree
        ));
        ui.label(format!(
            "{:.0} fps ({:.1} ms per render)",
            1e3 / self.frame_ms.max(1e-3),
            self.render_ms
        ));
        ui.small(&self.adapter);
        ui.separator();
        if ui
            .add(egui::Slider::new(&mut self.fov_deg, 10.0..=120.0).text("field of view °"))
            .changed()
        {
            self.view.fov_y = self.fov_deg.to_radians();
            self.view.exact = None;
            self.home.fov_y = self.view.fov_y;
            self.at_capture = None;
        }
        ui.add(
            egui::Slider::new(&mut self.speed, 0.05..=5.0)
                .logarithmic(true)
                .text("fly speed"),
        );
        ui.add(
            egui::Slider::new(&mut self.splat_scale, 0.05..=2.0)
                .logarithmic(true)
                .text("splat scale"),
        );
        ui.add(egui::Slider::new(&mut self.sh_degree, 0..=self.model.sh_degree).text("SH degree"));
        ui.horizontal(|ui| {
            ui.label("background");
            ui.color_edit_button_rgb(&mut self.background);
        });
        if ui.button("reset view (R)").clicked() {
            self.view = self.home.clone();
            self.at_capture = None;
        }
        ui.small("drag: orbit · right drag: pan · wheel: zoom · WASD QE: fly");
        if !self.captures.is_empty() {
            ui.separator();
            ui.label("capture cameras (N/P: next/previous, space: nearest)");
            let mut jump = None;
            egui::ScrollArea::vertical()
                .max_height(220.0)
                .show(ui, |ui| {
                    for (i, c) in self.captures.iter().enumerate() {
                        let label = if c.held_out {
                            format!("{} (held out)", c.name)
                        } else {
                            c.name.clone()
                        };
                        if ui
                            .selectable_label(self.at_capture == Some(i), label)
                            .clicked()
                        {
                            jump = Some(i);
                        }
                    }
                });
            if let Some(i) = jump {
                self.go_to_capture(i);
            }
        }
        if self.compare_source.is_some() {
            ui.separator();
            ui.checkbox(&mut self.compare_on, "compare with the capture (C)");
            if self.compare_on {
                ui.horizontal(|ui| {
                    ui.radio_value(&mut self.layout, CompareLayout::SideBySide, "side by side");
                    ui.radio_value(&mut self.layout, CompareLayout::Swipe, "swipe");
                });
                if let Some((_, _, panels)) = &self.panels {
                    for (p, _) in panels {
                        ui.label(match p.psnr_vs_clean {
                            Some(db) => format!("{}: {db:.2} dB", p.name),
                            None => p.name.clone(),
                        });
                    }
                    if self.layout == CompareLayout::Swipe {
                        let names: Vec<String> = panels.iter().map(|p| p.0.name.clone()).collect();
                        pick(ui, "left", &names, &mut self.swipe_pair.0);
                        pick(ui, "right", &names, &mut self.swipe_pair.1);
                        ui.add(egui::Slider::new(&mut self.swipe, 0.0..=1.0).text("split"));
                    }
                }
            }
        }
        if !self.status.is_empty() {
            ui.separator();
            ui.label(&self.status);
        }
    }

    fn show_comparison(&self, ui: &mut egui::Ui, rect: Rect) {
        let Some((_, _, panels)) = &self.panels else {
            return;
        };
        let painter = ui.painter_at(rect);
        let label = |r: Rect, p: &Panel| {
            let text = match p.psnr_vs_clean {
                Some(db) => format!("{}  {db:.2} dB", p.name),
                None => p.name.clone(),
            };
            tag(
                &painter,
                r.left_top() + Vec2::splat(4.0),
                egui::Align2::LEFT_TOP,
                text,
            );
        };
        match self.layout {
            CompareLayout::SideBySide => {
                let n = panels.len();
                let aspect = panels[0].0.width as f32 / panels[0].0.height as f32;
                // The grid with the largest tiles that fit.
                let (mut best, mut best_cols) = (0.0, 1);
                for cols in 1..=n {
                    let rows = n.div_ceil(cols);
                    let tile_w =
                        (rect.width() / cols as f32).min(rect.height() / rows as f32 * aspect);
                    if tile_w > best {
                        (best, best_cols) = (tile_w, cols);
                    }
                }
                let size = Vec2::new(best, best / aspect);
                for (k, (p, t)) in panels.iter().enumerate() {
                    let (c, r) = (k % best_cols, k / best_cols);
                    let r = Rect::from_min_size(
                        rect.min + Vec2::new(c as f32 * size.x, r as f32 * size.y),
                        size,
                    );
                    painter.image(t.id(), r, unit_uv(), Color32::WHITE);
                    label(r, p);
                }
            }
            CompareLayout::Swipe => {
                let (a, b) = (&panels[self.swipe_pair.0], &panels[self.swipe_pair.1]);
                let r = fit(rect, a.0.width, a.0.height);
                painter.image(a.1.id(), r, unit_uv(), Color32::WHITE);
                let split = r.left() + self.swipe * r.width();
                let right = Rect::from_min_max(Pos2::new(split, r.top()), r.max);
                let uv = Rect::from_min_max(Pos2::new(self.swipe, 0.0), Pos2::new(1.0, 1.0));
                painter.image(b.1.id(), right, uv, Color32::WHITE);
                painter.vline(split, r.y_range(), egui::Stroke::new(2.0, Color32::WHITE));
                label(r, &a.0);
                let text = match b.0.psnr_vs_clean {
                    Some(db) => format!("{}  {db:.2} dB", b.0.name),
                    None => b.0.name.clone(),
                };
                tag(
                    &painter,
                    r.right_top() + Vec2::new(-4.0, 4.0),
                    egui::Align2::RIGHT_TOP,
                    text,
                );
            }
        }
    }

    /// Screenshot mode: after the requested number of frames, ask for the window's pixels,
    /// save them and close.
    fn screenshot_step(&mut self, ctx: &egui::Context) {
        let Some(shot) = self.screenshot.clone() else {
            return;
        };
        self.frames += 1;
        // Every frame renders, so the report measures the frame rate.
        self.last_key = None;
        ctx.request_repaint();
        if self.frames >= shot.frames && !self.shot_requested {
            let slot = self.shot.clone();
            let repaint = ctx.clone();
            ctx.request_screenshot(move |image| {
                *slot.lock().expect("no panics hold this lock") = Some(image);
                repaint.request_repaint();
            });
            self.shot_requested = true;
        }
        let image = self.shot.lock().expect("no panics hold this lock").take();
        if let Some(image) = image {
            if let Err(e) = save_png(&shot.path, &image) {
                self.fail(ctx, e);
                return;
            }
            ctx.send_viewport_cmd(egui::ViewportCommand::Close);
        }
    }
}

impl eframe::App for Viewer {
    fn ui(&mut self, ui: &mut egui::Ui, _frame: &mut eframe::Frame) {
        let ctx = ui.ctx().clone();
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
        if let Some(live) = self.live.as_mut()
            && self.last_poll.elapsed() >= LIVE_POLL
        {
            self.last_poll = Instant::now();
            match live.poll() {
                Some(Ok((g, what))) => {
                    self.status = what;
                    if let Err(e) = self.replace_model(g) {
                        self.status = format!("The new model was not shown: {e}");
                    }
                }
                Some(Err(e)) => self.status = e,
                None => {}
            }
        }
        if self.live.is_some() {
            ctx.request_repaint_after(LIVE_POLL);
        }
        if let Err(e) = self.sync_scene() {
            self.fail(&ctx, e);
            return;
        }
        let show_panel = self.screenshot.as_ref().is_none_or(|s| s.with_panel);
        if show_panel {
            egui::Panel::right("controls")
                .default_size(280.0)
                .show(ui, |ui| self.side_panel(ui));
        }
        egui::CentralPanel::no_frame().show(ui, |ui| {
            let rect = ui.max_rect();
            let response = ui.allocate_rect(rect, Sense::click_and_drag());
            self.handle_input(ui, &response);
            if self.compare_on && self.compare_source.is_some() {
                ui.painter_at(rect)
                    .rect_filled(rect, 0.0, Color32::from_gray(16));
                match self.comparison(&ctx) {
                    Ok(()) => self.show_comparison(ui, rect),
                    Err(e) => {
                        ui.painter_at(rect).text(
                            rect.center(),
                            egui::Align2::CENTER_CENTER,
                            e,
                            egui::FontId::proportional(16.0),
                            Color32::WHITE,
                        );
                    }
                }
                return;
            }
            let ppp = ctx.pixels_per_point();
            let w = ((rect.width() * ppp).round() as u32).max(1);
            let h = ((rect.height() * ppp).round() as u32).max(1);
            if let Err(e) = self.render_view(&ctx, w, h) {
                self.fail(&ctx, e);
                return;
            }
            if let Some(t) = &self.texture {
                ui.painter_at(rect)
                    .image(t.id(), rect, unit_uv(), Color32::WHITE);
            }
            if show_panel {
                tag(
                    &ui.painter_at(rect),
                    rect.left_top() + Vec2::splat(6.0),
                    egui::Align2::LEFT_TOP,
                    format!(
                        "{} splats · {:.0} fps{}",
                        self.model.len(),
                        1e3 / self.frame_ms.max(1e-3),
                        self.at_capture
                            .and_then(|i| self.captures.get(i))
                            .map(|c| format!(" · {}", c.name))
                            .unwrap_or_default()
                    ),
                );
            }
        });
        self.screenshot_step(&ctx);
    }
}

/// White text on a dark, rounded backdrop, so it reads over any image.
fn tag(painter: &egui::Painter, at: Pos2, align: egui::Align2, text: String) {
    let galley = painter.layout_no_wrap(text, egui::FontId::proportional(14.0), Color32::WHITE);
    let rect = align.anchor_size(at, galley.size());
    painter.rect_filled(rect.expand(3.0), 3.0, Color32::from_black_alpha(170));
    painter.galley(rect.min, galley, Color32::WHITE);
}

fn pick(ui: &mut egui::Ui, label: &str, names: &[String], index: &mut usize) {
    egui::ComboBox::from_label(label)
        .selected_text(names[*index].clone())
        .show_ui(ui, |ui| {
            for (i, n) in names.iter().enumerate() {
                ui.selectable_value(index, i, n);
            }
        });
}

fn unit_uv() -> Rect {
    Rect::from_min_max(Pos2::ZERO, Pos2::new(1.0, 1.0))
}

/// The largest rect of the image's aspect ratio inside `outer`, centred.
fn fit(outer: Rect, w: u32, h: u32) -> Rect {
    let aspect = w as f32 / h as f32;
    let width = outer.width().min(outer.height() * aspect);
    Rect::from_center_size(outer.center(), Vec2::new(width, width / aspect))
}

/// Linear [0, 1] RGB to 8-bit, rounded: the same quantisation `metasplat render` uses for its
/// PNGs, so a screenshot matches a headless frame.
pub(crate) fn color_image(w: u32, h: u32, pixels: &[Vec3]) -> ColorImage {
    let rgb: Vec<u8> = pixels
        .iter()
        .flat_map(|p| p.to_array())
        .map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8)
        .collect();
    ColorImage::from_rgb([w as usize, h as usize], &rgb)
}

fn save_png(path: &std::path::Path, image: &ColorImage) -> Result<(), ViewerError> {
    let err = |reason: String| ViewerError::Screenshot {
        path: path.to_path_buf(),
        reason,
    };
    let [w, h] = image.size;
    let rgb: Vec<u8> = image
        .pixels
        .iter()
        .flat_map(|c| [c.r(), c.g(), c.b()])
        .collect();
    let buf = image::RgbImage::from_raw(w as u32, h as u32, rgb)
        .ok_or_else(|| err("the screenshot has the wrong size".into()))?;
    let mut bytes = Vec::new();
    buf.write_to(
        &mut std::io::Cursor::new(&mut bytes),
        image::ImageFormat::Png,
    )
    .map_err(|e| err(e.to_string()))?;
    base::atomic::write_bytes_atomically(path, &bytes).map_err(|e| err(e.to_string()))
}
