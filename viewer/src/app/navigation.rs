//! Where the view is and how the user moves it: orbit, pan, zoom and fly from the mouse and
//! keys, the home view, and jumps to the capture's cameras.

use eframe::egui;
use egui::{Key, PointerButton, Vec2};

use crate::CaptureView;
use crate::controls::{ViewCamera, nearest_camera};

/// Radians the view turns per pixel dragged.
const TURN_PER_PIXEL: f32 = 0.006;

pub(super) struct Navigation {
    pub captures: Vec<CaptureView>,
    pub home: ViewCamera,
    pub view: ViewCamera,
    /// Capture camera the view sits on, if any.
    pub at_capture: Option<usize>,
    fov_deg: f32,
    speed: f32,
}

impl Navigation {
    pub fn new(captures: Vec<CaptureView>, home: ViewCamera) -> Self {
        Self {
            captures,
            view: home.clone(),
            fov_deg: home.fov_y.to_degrees(),
            home,
            at_capture: None,
            speed: 0.5,
        }
    }

    pub fn go_to_capture(&mut self, i: usize) {
        let Some(c) = self.captures.get(i) else {
            return;
        };
        self.view = ViewCamera::at_capture(&c.camera, self.home.scale.max(1e-3) * 0.5);
        self.view.scale = self.home.scale;
        self.at_capture = Some(i);
    }

    fn go_home(&mut self) {
        self.view = self.home.clone();
        self.at_capture = None;
    }

    /// Mouse and keys over the view; returns whether the comparison key (C) was pressed.
    pub fn handle_input(&mut self, ui: &egui::Ui, response: &egui::Response) -> bool {
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
            return false;
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
            self.go_home();
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
        pressed(Key::C)
    }

    /// The field-of-view and speed sliders (the panel's camera part).
    pub fn sliders(&mut self, ui: &mut egui::Ui) {
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
    }

    /// The reset button and the list of capture cameras.
    pub fn places(&mut self, ui: &mut egui::Ui) {
        if ui.button("reset view (R)").clicked() {
            self.go_home();
        }
        ui.small("drag: orbit · right drag: pan · wheel: zoom · WASD QE: fly");
        if self.captures.is_empty() {
            return;
        }
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

    /// The name of the capture camera the view sits on.
    pub fn capture_name(&self) -> Option<&str> {
        self.at_capture
            .and_then(|i| self.captures.get(i))
            .map(|c| c.name.as_str())
    }
}
