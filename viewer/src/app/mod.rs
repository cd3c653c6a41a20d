//! The window: eframe (winit + wgpu) with an egui side panel. The splats are rendered by
//! `splat`'s GPU rasterizer on the window's own device and shown as a texture. The window's
//! state is kept by concern: the model as shown and the last render ([`scene`]), where the
//! view is ([`navigation`]), the comparison mode ([`compare`]), screenshots ([`screenshot`]).

mod compare;
mod draw;
mod navigation;
mod scene;
mod screenshot;

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use eframe::egui;
use egui::{Color32, Sense, Vec2};
use splat::gpu::{GpuContext, GpuRasterizer};

use crate::controls::ViewCamera;
use crate::{Start, ViewerError, ViewerOptions, ViewerReport};
use compare::Compare;
use draw::{tag, unit_uv};
use navigation::Navigation;
use scene::{ShownModel, ViewImage};
use screenshot::ShotState;

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

/// A live run and when it was last asked for a newer model.
struct Live {
    source: Box<dyn crate::LiveSource>,
    last_poll: Instant,
}

struct Viewer {
    shown: ShownModel,
    image: ViewImage,
    nav: Navigation,
    compare: Compare,
    live: Option<Live>,
    shot: ShotState,
    /// A line for the panel: what a live run last said.
    status: String,
    failure: Arc<Mutex<Option<ViewerError>>>,
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
        let home = match &o.start {
            Start::LookAt { eye, target } => ViewCamera::looking(*eye, *target, o.fov_y),
            _ => ViewCamera::framing(&o.model.means, o.fov_y).ok_or_else(|| {
                ViewerError::Invalid("no splat has a finite position to frame".into())
            })?,
        };
        let compare_on = o.screenshot.as_ref().is_some_and(|s| s.compare);
        let mut viewer = Self {
            shown: ShownModel::new(raster, adapter, o.model, o.background)?,
            image: ViewImage::new(timings),
            nav: Navigation::new(o.captures, home),
            compare: Compare::new(o.compare, compare_on),
            live: o.live.map(|source| Live {
                source,
                last_poll: Instant::now(),
            }),
            shot: ShotState::new(o.screenshot),
            status: String::new(),
            failure,
        };
        if let Start::Capture(i) = o.start {
            viewer.nav.go_to_capture(i);
        }
        Ok(viewer)
    }

    fn fail(&mut self, ctx: &egui::Context, e: ViewerError) {
        *self.failure.lock().expect("no panics hold this lock") = Some(e);
        ctx.send_viewport_cmd(egui::ViewportCommand::Close);
    }

    /// Takes a newer model from a live run, at most once per poll interval.
    fn poll_live(&mut self, ctx: &egui::Context) {
        let Some(live) = self.live.as_mut() else {
            return;
        };
        if live.last_poll.elapsed() >= LIVE_POLL {
            live.last_poll = Instant::now();
            match live.source.poll() {
                Some(Ok((g, what))) => {
                    self.status = what;
                    if let Err(e) = self.shown.replace(g) {
                        self.status = format!("The new model was not shown: {e}");
                    }
                }
                Some(Err(e)) => self.status = e,
                None => {}
            }
        }
        ctx.request_repaint_after(LIVE_POLL);
    }

    fn side_panel(&mut self, ui: &mut egui::Ui) {
        let shown = &mut self.shown;
        ui.heading("metasplat");
        ui.label(format!(
            "{} splats, SH degree {}",
            shown.model.len(),
            shown.model.sh_degree
        ));
        ui.label(format!(
            "{:.0} fps ({:.1} ms per render)",
            1e3 / self.image.frame_ms.max(1e-3),
            self.image.render_ms
        ));
        ui.small(&shown.adapter);
        ui.separator();
        self.nav.sliders(ui);
        ui.add(
            egui::Slider::new(&mut shown.splat_scale, 0.05..=2.0)
                .logarithmic(true)
                .text("splat scale"),
        );
        ui.add(
            egui::Slider::new(&mut shown.sh_degree, 0..=shown.model.sh_degree).text("SH degree"),
        );
        ui.horizontal(|ui| {
            ui.label("background");
            ui.color_edit_button_rgb(&mut shown.background);
        });
        self.nav.places(ui);
        self.compare.controls(ui);
        if !self.status.is_empty() {
            ui.separator();
            ui.label(&self.status);
        }
    }
}

impl eframe::App for Viewer {
    fn ui(&mut self, ui: &mut egui::Ui, _frame: &mut eframe::Frame) {
        let ctx = ui.ctx().clone();
        self.image.tick();
        self.poll_live(&ctx);
        if let Err(e) = self.shown.sync() {
            self.fail(&ctx, e);
            return;
        }
        let show_panel = self.shot.with_panel();
        if show_panel {
            egui::Panel::right("controls")
                .default_size(280.0)
                .show(ui, |ui| self.side_panel(ui));
        }
        egui::CentralPanel::no_frame().show(ui, |ui| {
            let rect = ui.max_rect();
            let response = ui.allocate_rect(rect, Sense::click_and_drag());
            if self.nav.handle_input(ui, &response) && self.compare.available() {
                self.compare.on = !self.compare.on;
            }
            if self.compare.showing() {
                ui.painter_at(rect)
                    .rect_filled(rect, 0.0, Color32::from_gray(16));
                match self.compare.update(
                    &ctx,
                    &self.shown,
                    &self.nav.captures,
                    self.nav.at_capture,
                ) {
                    Ok(()) => self.compare.show(ui, rect),
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
            if let Err(e) = self
                .image
                .update(&ctx, &self.shown, self.nav.view.camera(w, h))
            {
                self.fail(&ctx, e);
                return;
            }
            if let Some(t) = &self.image.texture {
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
                        self.shown.model.len(),
                        1e3 / self.image.frame_ms.max(1e-3),
                        self.nav
                            .capture_name()
                            .map(|n| format!(" · {n}"))
                            .unwrap_or_default()
                    ),
                    rect.width() - 20.0,
                );
            }
        });
        if self.shot.asked.is_some() {
            // Every frame renders, so the report measures the frame rate.
            self.image.invalidate();
        }
        if let Err(e) = self.shot.step(&ctx) {
            self.fail(&ctx, e);
        }
    }
}
