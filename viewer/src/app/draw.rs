//! Small drawing helpers shared by the view, the comparison and the panel.

use eframe::egui;
use egui::{Color32, ColorImage, Pos2, Rect, Vec2};
use glam::Vec3;

/// White text on a dark, rounded backdrop, so it reads over any image, wrapped onto more
/// lines when it is wider than `max_width` (a comparison panel at capture size), so it is
/// never cut.
pub(super) fn tag(
    painter: &egui::Painter,
    at: Pos2,
    align: egui::Align2,
    text: String,
    max_width: f32,
) {
    let galley = tag_galley(painter, text, max_width);
    let rect = align.anchor_size(at, galley.size());
    painter.rect_filled(rect.expand(3.0), 3.0, Color32::from_black_alpha(170));
    painter.galley(rect.min, galley, Color32::WHITE);
}

/// The laid-out text of [`tag`]: whole, in lines no wider than `max_width` (but for a word
/// wider than it).
fn tag_galley(
    painter: &egui::Painter,
    text: String,
    max_width: f32,
) -> std::sync::Arc<egui::Galley> {
    painter.layout(
        text,
        egui::FontId::proportional(14.0),
        Color32::WHITE,
        max_width.max(40.0),
    )
}

/// A drop-down choosing one of `names`.
pub(super) fn pick(ui: &mut egui::Ui, label: &str, names: &[String], index: &mut usize) {
    egui::ComboBox::from_label(label)
        .selected_text(names[*index].clone())
        .show_ui(ui, |ui| {
            for (i, n) in names.iter().enumerate() {
                ui.selectable_value(index, i, n);
            }
        });
}

pub(super) fn unit_uv() -> Rect {
    Rect::from_min_max(Pos2::ZERO, Pos2::new(1.0, 1.0))
}

/// The largest rect of the image's aspect ratio inside `outer`, centred.
pub(super) fn fit(outer: Rect, w: u32, h: u32) -> Rect {
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

#[cfg(test)]
mod tests {
    use eframe::egui;

    #[test]
    fn a_label_wider_than_its_panel_wraps_whole_instead_of_being_cut() {
        let ctx = egui::Context::default();
        let text = "render through the refined PSF  27.70 dB";
        let mut checked = false;
        let _ = ctx.run_ui(egui::RawInput::default(), |ui| {
            let painter = ui.painter();
            let wide = super::tag_galley(painter, text.into(), 1000.0);
            let narrow = super::tag_galley(painter, text.into(), 120.0);
            assert_eq!(wide.rows.len(), 1);
            assert!(narrow.rows.len() > 1, "not wrapped");
            assert!(narrow.size().x <= 120.5, "{} wide", narrow.size().x);
            assert_eq!(narrow.text(), text);
            checked = true;
        });
        assert!(checked);
    }
}
