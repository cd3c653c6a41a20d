//! Coarse to fine: the first steps of a run train on its views shrunk by whole factors (4,
//! then 2, …), as fast trainers do (OpenSplat's `--num-downscales`, DashGaussian), because a
//! young model has no detail a full-size render would show. Each level holds its own copy
//! of the training views, area-shrunk as LLFF's `images_N/` are, with cameras scaled
//! exactly (the remainder rows and columns are dropped, so the scale is exactly `1/n`), and
//! the lens shrunk alike ([`aberration::ImagingModel::shrunk`]) for `L_abr`. Held-out
//! evaluation, the SH-band probes and PSF refinement stay at full size.

use aberration::ImagingModel;
use glam::Vec3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::{Result, TrainError};
use crate::train::config::TrainConfig;
use crate::train::data::{Dataset, View};
use crate::train::object::ObjectTargets;

/// The smallest side a coarse level may shrink a view to: below it a level's renders hold
/// too few pixels to say where anything is, and [`Coarse::for_capture`] uses fewer levels.
pub const MIN_COARSE_SIDE: u32 = 32;

/// One coarse level: steps before `until` train on views `factor` times smaller.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct CoarseLevel {
    pub factor: u32,
    pub until: u64,
}

/// The resolution schedule: levels coarsest first, each ending where the next begins; full
/// size from the last level's end.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Coarse {
    pub levels: Vec<CoarseLevel>,
}

impl Coarse {
    /// `levels` levels of `steps` steps each, the first `2^levels` times smaller, halving the
    /// factor at each level; fewer where the capture's shorter side would fall below
    /// [`MIN_COARSE_SIDE`]. None when no level is left.
    pub fn for_capture(levels: u32, steps: u64, width: u32, height: u32) -> Option<Self> {
        let side = width.min(height);
        let fit = (0..=levels.min(8))
            .rev()
            .find(|&l| side >> l >= MIN_COARSE_SIDE)
            .unwrap_or(0);
        if fit == 0 || steps == 0 {
            return None;
        }
        Some(Coarse {
            levels: (0..fit)
                .map(|k| CoarseLevel {
                    factor: 1 << (fit - k),
                    until: steps * (k as u64 + 1),
                })
                .collect(),
        })
    }

    /// The shrink factor of step `step` (1: full size).
    pub fn factor_at(&self, step: u64) -> u32 {
        self.levels
            .iter()
            .find(|l| step < l.until)
            .map_or(1, |l| l.factor)
    }

    /// The schedule in a sentence, for views of `width × height`.
    pub fn describe(&self, width: u32, height: u32) -> String {
        let mut from = 0;
        let parts: Vec<String> = self
            .levels
            .iter()
            .map(|l| {
                let part = format!(
                    "steps {from}-{} at 1/{} size ({}x{})",
                    l.until - 1,
                    l.factor,
                    width / l.factor,
                    height / l.factor
                );
                from = l.until;
                part
            })
            .collect();
        format!(
            "Coarse to fine: {}, full size from step {from}.",
            parts.join(", ")
        )
    }

    /// The first step at full size.
    pub fn end(&self) -> u64 {
        self.levels.last().map_or(0, |l| l.until)
    }
}

/// What a coarse level trains on: the training views shrunk, the lens at their scale and,
/// in object mode, the object's targets made from them.
pub struct Level {
    pub factor: u32,
    pub width: u32,
    pub height: u32,
    pub train: Vec<View>,
    pub imaging: Option<ImagingModel>,
    pub object: Option<ObjectTargets>,
}

impl Level {
    /// The levels of `config`'s schedule for `data`, coarsest first (none without one).
    pub fn for_run(config: &TrainConfig, data: &Dataset) -> Result<Vec<Level>> {
        let Some(coarse) = &config.coarse else {
            return Ok(Vec::new());
        };
        coarse
            .levels
            .iter()
            .map(|l| Level::new(config, data, l.factor))
            .collect()
    }

    fn new(config: &TrainConfig, data: &Dataset, factor: u32) -> Result<Level> {
        let (width, height) = (data.width / factor, data.height / factor);
        if width.min(height) == 0 {
            return Err(TrainError::Invalid(format!(
                "coarse to fine: {}x{} views cannot be shrunk {factor} times",
                data.width, data.height
            )));
        }
        let train: Vec<View> = data
            .train
            .par_iter()
            .map(|v| shrink_view(v, data.width, data.height, factor))
            .collect();
        let imaging = data
            .imaging
            .as_ref()
            .map(|m| m.shrunk(factor as usize))
            .transpose()?;
        let object = ObjectTargets::build(config, &train, imaging.as_ref(), data.composited_over)?;
        Ok(Level {
            factor,
            width,
            height,
            train,
            imaging,
            object,
        })
    }
}

/// `view` (images `width × height`) `n` times smaller on each side: the images training reads
/// area-shrunk,
/// the camera's intrinsics divided by `n` (pixel edges at integer coordinates, so no
/// half-pixel shift).
pub fn shrink_view(view: &View, width: u32, height: u32, n: u32) -> View {
    let shrink = |px: &Vec<Vec3>| shrink_pixels(px, width, height, n);
    let mut camera = view.camera.clone();
    let k = n as f32;
    (camera.fx, camera.fy, camera.cx, camera.cy) =
        (camera.fx / k, camera.fy / k, camera.cx / k, camera.cy / k);
    (camera.width, camera.height) = (width / n, height / n);
    View {
        name: view.name.clone(),
        camera,
        observed: shrink(&view.observed),
        restored: view.restored.as_ref().map(shrink),
        // Training never reads a training view's clean image (held-out views are scored at
        // full size), so levels do not keep one.
        clean: None,
        mask: view.mask.as_ref().map(|m| {
            let wide: Vec<Vec3> = m.iter().map(|&v| Vec3::splat(v)).collect();
            shrink_pixels(&wide, width, height, n)
                .iter()
                .map(|p| p.x)
                .collect()
        }),
    }
}

/// Row-major pixels of a `width × height` image `n` times smaller by the area rule, the
/// remainder dropped; sums in f64 so that a level's images do not depend on summation order.
pub fn shrink_pixels(px: &[Vec3], width: u32, height: u32, n: u32) -> Vec<Vec3> {
    let (w, h, n) = (width as usize, height as usize, n.max(1) as usize);
    let (sw, sh) = (w / n, h / n);
    let scale = 1.0 / (n * n) as f64;
    let mut out = Vec::with_capacity(sw * sh);
    for y in 0..sh {
        for x in 0..sw {
            let mut sum = glam::DVec3::ZERO;
            for dy in 0..n {
                let row = (y * n + dy) * w + x * n;
                for p in &px[row..row + n] {
                    sum += p.as_dvec3();
                }
            }
            out.push((sum * scale).as_vec3());
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn schedule_halves_the_factor_and_fits_the_capture() {
        let c = Coarse::for_capture(2, 700, 504, 378).unwrap();
        assert_eq!(
            c.levels,
            vec![
                CoarseLevel {
                    factor: 4,
                    until: 700
                },
                CoarseLevel {
                    factor: 2,
                    until: 1400
                }
            ]
        );
        assert_eq!(
            [0, 699, 700, 1399, 1400, 7000].map(|s| c.factor_at(s)),
            [4, 4, 2, 2, 1, 1]
        );
        assert_eq!(c.end(), 1400);
        // 120 px: a 4x level would be 30 px, under the floor; one 2x level is left.
        let small = Coarse::for_capture(2, 100, 160, 120).unwrap();
        assert_eq!(
            small.levels,
            vec![CoarseLevel {
                factor: 2,
                until: 100
            }]
        );
        assert_eq!(Coarse::for_capture(2, 100, 60, 40), None);
        assert_eq!(Coarse::for_capture(0, 100, 600, 400), None);
        assert_eq!(Coarse::for_capture(2, 0, 600, 400), None);
    }

    #[test]
    fn the_splat_budget_follows_the_pixel_count() {
        let b = crate::train::densify::Budget {
            max: 95_000,
            coarse: Coarse::for_capture(2, 700, 504, 378),
        };
        assert_eq!(
            [0, 699, 700, 1399, 1400].map(|s| b.at(s)),
            [5937, 5937, 23_750, 23_750, 95_000]
        );
        assert_eq!(crate::train::densify::Budget::fixed(7).at(0), 7);
    }

    #[test]
    fn shrinking_takes_block_means_and_drops_the_remainder() {
        // 5x3 with values x + 10y: 2x smaller is 2x1, the last column and row dropped.
        let px: Vec<Vec3> = (0..15)
            .map(|i| Vec3::splat((i % 5) as f32 + 10.0 * (i / 5) as f32))
            .collect();
        let s = shrink_pixels(&px, 5, 3, 2);
        assert_eq!(s, vec![Vec3::splat(5.5), Vec3::splat(7.5)]);
    }
}
