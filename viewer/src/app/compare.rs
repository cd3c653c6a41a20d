//! The comparison mode: at a capture camera, the render beside what the capture adds (the
//! photo through the metalens, the blur of the render, `I_ac`, the clean photo), side by side
//! or as a swipe between two of them.

use eframe::egui;
use egui::{Color32, Pos2, Rect, TextureHandle, Vec2};

use super::draw::{color_image, fit, pick, tag, unit_uv};
use super::scene::ShownModel;
use crate::{CaptureView, CompareSource, Panel};

#[derive(Clone, Copy, PartialEq)]
pub(super) enum CompareLayout {
    SideBySide,
    Swipe,
}

/// The panels shown for one capture camera and model generation, with their textures.
struct Panels {
    capture: usize,
    generation: u64,
    shown: Vec<(Panel, TextureHandle)>,
}

pub(super) struct Compare {
    source: Option<Box<dyn CompareSource>>,
    pub on: bool,
    layout: CompareLayout,
    swipe: f32,
    swipe_pair: (usize, usize),
    panels: Option<Panels>,
}

impl Compare {
    pub fn new(source: Option<Box<dyn CompareSource>>, on: bool) -> Self {
        Self {
            source,
            on,
            layout: CompareLayout::SideBySide,
            swipe: 0.5,
            swipe_pair: (0, 1),
            panels: None,
        }
    }

    /// Whether there is a capture to compare with.
    pub fn available(&self) -> bool {
        self.source.is_some()
    }

    /// Whether the comparison takes the view.
    pub fn showing(&self) -> bool {
        self.on && self.available()
    }

    /// The comparison images at capture camera `at`, computed once per camera and model.
    pub fn update(
        &mut self,
        ctx: &egui::Context,
        shown: &ShownModel,
        captures: &[CaptureView],
        at: Option<usize>,
    ) -> Result<(), String> {
        let Some(i) = at else {
            return Err("comparison needs a capture camera: pick one in the list".into());
        };
        if self
            .panels
            .as_ref()
            .is_some_and(|p| p.capture == i && p.generation == shown.generation)
        {
            return Ok(());
        }
        let Some(source) = self.source.as_mut() else {
            return Err("comparison needs a capture: open the viewer with --scene".into());
        };
        let out = shown
            .render(&captures[i].camera, &shown.settings_for_compare())
            .map_err(|e| e.to_string())?;
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
        self.panels = Some(Panels {
            capture: i,
            generation: shown.generation,
            shown: textures,
        });
        Ok(())
    }

    /// The comparison's part of the side panel.
    pub fn controls(&mut self, ui: &mut egui::Ui) {
        if !self.available() {
            return;
        }
        ui.separator();
        ui.checkbox(&mut self.on, "compare with the capture (C)");
        if !self.on {
            return;
        }
        ui.horizontal(|ui| {
            ui.radio_value(&mut self.layout, CompareLayout::SideBySide, "side by side");
            ui.radio_value(&mut self.layout, CompareLayout::Swipe, "swipe");
        });
        if let Some(panels) = &self.panels {
            for (p, _) in &panels.shown {
                ui.label(caption(p, ": "));
            }
            if self.layout == CompareLayout::Swipe {
                let names: Vec<String> = panels.shown.iter().map(|p| p.0.name.clone()).collect();
                pick(ui, "left", &names, &mut self.swipe_pair.0);
                pick(ui, "right", &names, &mut self.swipe_pair.1);
                ui.add(egui::Slider::new(&mut self.swipe, 0.0..=1.0).text("split"));
            }
        }
    }

    pub fn show(&self, ui: &mut egui::Ui, rect: Rect) {
        let Some(panels) = &self.panels else {
            return;
        };
        let panels = &panels.shown;
        let painter = ui.painter_at(rect);
        // Each label fits its panel: the left one of a swipe its half.
        let label = |r: Rect, p: &Panel| {
            tag(
                &painter,
                r.left_top() + Vec2::splat(4.0),
                egui::Align2::LEFT_TOP,
                caption(p, "  "),
                r.width() - 14.0,
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
                tag(
                    &painter,
                    r.right_top() + Vec2::new(-4.0, 4.0),
                    egui::Align2::RIGHT_TOP,
                    caption(&b.0, "  "),
                    r.width() / 2.0 - 14.0,
                );
            }
        }
    }
}

/// A panel's name, with its PSNR against the clean photo after `gap` when it has one.
fn caption(p: &Panel, gap: &str) -> String {
    match p.psnr_vs_clean {
        Some(db) if p.on_object => format!("{}{gap}{db:.2} dB on the object", p.name),
        Some(db) => format!("{}{gap}{db:.2} dB", p.name),
        None => p.name.clone(),
    }
}
