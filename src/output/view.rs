//! What `metasplat view` hands the viewer: a capture's comparison images, made by the training
//! pipeline's own code, and a watch on a training run in progress.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::time::SystemTime;

use glam::Vec3;
use viewer::{CompareSource, LiveSource, Panel};

use crate::error::Result;
use crate::output::{CHECKPOINT_FILE, PLY_FILE};
use crate::settings::DataOptions;
use crate::train::data::{CaptureModel, View};

/// A capture's side of the comparison: for a view, the metalens photo, the render blurred
/// through the capture's PSF model (what aware training compares with the photo), `I_ac`
/// and the clean image, each with its PSNR against clean.
pub struct CaptureComparison {
    model: CaptureModel,
    /// Views already read and restored: restoring costs seconds per view on a CPU.
    views: HashMap<usize, (View, Option<Vec<Vec3>>)>,
    /// A run's cache of `I_ac` to read from.
    cache: Option<PathBuf>,
    /// The blur through a run's refined PSF grid (`train --refine-psf`).
    refined: Option<aberration::ImagingModel>,
}

/// Panel names, in the order they are shown.
pub const PHOTO: &str = "metalens photo";
pub const RENDER: &str = "our render";
pub const REBLURRED: &str = "render through the PSF";
pub const REFINED: &str = "render through the refined PSF";
pub const RESTORED: &str = "I_ac (restorer)";
pub const CLEAN: &str = "clean";

impl CaptureComparison {
    /// Opens the capture; `I_ac` is read from `options.iac_cache` where it holds it.
    pub fn open(dir: &Path, options: &DataOptions) -> Result<Self> {
        Ok(Self {
            model: CaptureModel::open(dir, options, true)?,
            views: HashMap::new(),
            cache: options.iac_cache.clone(),
            refined: None,
        })
    }

    /// Also shows the render through the grid a run refined (its `psf_refined.npy`, at the
    /// capture's image scale), beside the render through the capture's own.
    pub fn with_refined_psf(&mut self, path: &Path) -> Result<()> {
        let Some(model) = &self.model.imaging else {
            return Err(crate::error::TrainError::file(
                path,
                "the capture has no PSF grid to compare a refined one with",
            ));
        };
        let grid = aberration::PsfGrid::load_npy(path)?;
        let here = model.psf();
        if (grid.grid(), grid.size()) != (here.grid(), here.size()) {
            return Err(crate::error::TrainError::file(
                path,
                format!(
                    "a {g}x{g} grid of {} px PSFs; the capture's at its image size is {h}x{h} of {} px: the run was trained at another --downsample",
                    grid.size(),
                    here.size(),
                    g = grid.grid(),
                    h = here.grid()
                ),
            ));
        }
        self.refined = Some(model.with_psf(grid)?);
        Ok(())
    }

    pub fn capture(&self) -> &scenes::Capture {
        &self.model.capture
    }

    /// Which restorer makes `I_ac`, and any note about it.
    pub fn describe_restorer(&self) -> Option<String> {
        let r = self.model.restorer.as_ref()?;
        Some(match &self.model.restorer_note {
            Some(n) => format!("{} ({n})", r.describe()),
            None => r.describe(),
        })
    }

    /// The comparison panels of view `i` for a render from exactly its camera.
    pub fn panels_for(&mut self, i: usize, render: &[Vec3]) -> Result<Vec<Panel>> {
        let (w, h) = (self.model.width, self.model.height);
        if render.len() != w as usize * h as usize {
            return Err(crate::error::TrainError::Invalid(format!(
                "the render has {} pixels; the capture's images are {w}x{h}",
                render.len()
            )));
        }
        if !self.views.contains_key(&i) {
            let view = self.model.view(i)?;
            let restored = match self.model.cached(&view.observed, self.cache.as_deref()) {
                Some(img) => Some(img),
                None => self.model.restore(&view.observed)?,
            };
            self.views.insert(i, (view, restored));
        }
        let (view, restored) = &self.views[&i];
        // A copy composited over a colour outside its masks before the blur was made from
        // `m·clean + (1 − m)·c₀`: the render goes through the lens the same way, so what it
        // shows outside the mask (which nothing in training constrains) does not bleed into
        // the panel, as training's own re-blur does.
        let through_lens = crate::train::object::lens_input(
            render,
            view.mask.as_deref(),
            self.model.composited_over.map(Vec3::from_array),
        );
        let reblurred = match &self.model.imaging {
            Some(m) => Some(m.blur_pixels(&through_lens)?),
            None => None,
        };
        let refined = match &self.refined {
            Some(m) => Some(m.blur_pixels(&through_lens)?),
            None => None,
        };
        let mut images: Vec<(&str, &[Vec3])> = vec![(PHOTO, &view.observed), (RENDER, render)];
        if let Some(b) = &reblurred {
            images.push((REBLURRED, b));
        }
        if let Some(b) = &refined {
            images.push((REFINED, b));
        }
        if let Some(r) = restored {
            images.push((RESTORED, r));
        }
        if let Some(c) = &view.clean {
            images.push((CLEAN, c));
        }
        // On a capture with an object's masks, what matters is the object: each panel is
        // scored inside the view's mask, as a run's held-out views are beside their composite.
        let object = view
            .mask
            .as_deref()
            .filter(|_| self.model.capture.has_own_masks() && !self.model.masks_from_undistortion);
        images
            .into_iter()
            .map(|(name, pixels)| {
                let psnr_vs_clean = match (&view.clean, name, object) {
                    (Some(_), CLEAN, _) | (None, ..) => None,
                    (Some(c), _, Some(m)) => crate::train::object::psnr_in_mask(pixels, c, m),
                    (Some(c), _, None) => Some(base::psnr_rgb(pixels, c)?),
                };
                Ok(Panel {
                    name: name.to_string(),
                    width: w,
                    height: h,
                    pixels: pixels.to_vec(),
                    psnr_vs_clean,
                    on_object: object.is_some(),
                })
            })
            .collect()
    }
}

impl CompareSource for CaptureComparison {
    fn panels(&mut self, view: usize, render: &[Vec3]) -> std::result::Result<Vec<Panel>, String> {
        self.panels_for(view, render).map_err(|e| e.to_string())
    }
}

/// Watches a run folder for a newer checkpoint or final PLY.
pub struct RunWatch {
    dir: PathBuf,
    seen: Option<(SystemTime, u64)>,
}

impl RunWatch {
    pub fn new(dir: &Path) -> Self {
        Self {
            dir: dir.to_path_buf(),
            seen: None,
        }
    }

    /// The newest model file of the run and its stamp.
    fn newest(&self) -> Option<(PathBuf, (SystemTime, u64))> {
        [PLY_FILE, CHECKPOINT_FILE]
            .iter()
            .filter_map(|f| {
                let p = self.dir.join(f);
                let m = std::fs::metadata(&p).ok()?;
                Some((p, (m.modified().ok()?, m.len())))
            })
            .max_by_key(|(_, stamp)| stamp.0)
    }

    /// The run's newest model, if it changed since the last call.
    pub fn check(&mut self) -> Option<std::result::Result<(splat::Gaussians, String), String>> {
        let (path, stamp) = self.newest()?;
        if self.seen == Some(stamp) {
            return None;
        }
        self.seen = Some(stamp);
        // Both files are written to a temporary name and renamed, so a file seen is complete.
        let loaded = if path.ends_with(CHECKPOINT_FILE) {
            crate::train::checkpoint::load(&path)
                .map(|s| {
                    let what = format!(
                        "Showing step {} of the run ({} splats) from {}.",
                        s.progress.step,
                        s.model.len(),
                        path.display()
                    );
                    (s.model, what)
                })
                .map_err(|e| e.to_string())
        } else {
            splat::formats::files::read_splats(&path)
                .map(|g| {
                    let what = format!(
                        "Showing the finished run ({} splats) from {}.",
                        g.len(),
                        path.display()
                    );
                    (g, what)
                })
                .map_err(|e| format!("{}: {e}", path.display()))
        };
        Some(loaded)
    }
}

impl LiveSource for RunWatch {
    fn poll(&mut self) -> Option<std::result::Result<(splat::Gaussians, String), String>> {
        self.check()
    }
}

/// What the run in `dir` decided for its capture and why, as its `config.json` records them
/// ([`crate::train::decisions`]); none when it has no such record.
pub fn decisions(dir: &Path) -> Vec<crate::train::config::Decision> {
    let Ok(bytes) = base::input::read(&dir.join(crate::output::CONFIG_FILE)) else {
        return Vec::new();
    };
    serde_json::from_slice::<serde_json::Value>(&bytes)
        .ok()
        .and_then(|v| serde_json::from_value(v.get("decisions")?.clone()).ok())
        .unwrap_or_default()
}
