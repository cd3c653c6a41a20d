//! Screenshot mode: after the requested number of frames, the window's pixels are saved to a
//! PNG (written to a temporary name and renamed) and the window closes.

use std::sync::{Arc, Mutex};

use eframe::egui;
use egui::ColorImage;

use crate::{Screenshot, ViewerError};

pub(super) struct ShotState {
    pub asked: Option<Screenshot>,
    frames: u32,
    image: Arc<Mutex<Option<Arc<ColorImage>>>>,
    requested: bool,
}

impl ShotState {
    pub fn new(asked: Option<Screenshot>) -> Self {
        Self {
            asked,
            frames: 0,
            image: Arc::default(),
            requested: false,
        }
    }

    /// Whether the side panel is drawn (a screenshot may leave it out).
    pub fn with_panel(&self) -> bool {
        self.asked.as_ref().is_none_or(|s| s.with_panel)
    }

    /// One frame of screenshot mode (nothing without a screenshot asked for): counts it, asks
    /// for the pixels once enough frames were drawn, and saves them when they come.
    pub fn step(&mut self, ctx: &egui::Context) -> Result<(), ViewerError> {
        let Some(shot) = self.asked.clone() else {
            return Ok(());
        };
        self.frames += 1;
        ctx.request_repaint();
        if self.frames >= shot.frames && !self.requested {
            let slot = self.image.clone();
            let repaint = ctx.clone();
            ctx.request_screenshot(move |image| {
                *slot.lock().expect("no panics hold this lock") = Some(image);
                repaint.request_repaint();
            });
            self.requested = true;
        }
        let image = self.image.lock().expect("no panics hold this lock").take();
        if let Some(image) = image {
            save_png(&shot.path, &image)?;
            ctx.send_viewport_cmd(egui::ViewportCommand::Close);
        }
        Ok(())
    }
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
