//! The coarse levels of a run ([`crate::train::coarse`]'s schedule made concrete): each
//! level's own copy of the training views, area-shrunk as LLFF's `images_N/` are, with
//! cameras scaled exactly, the lens shrunk alike and, in object mode, the object's targets
//! made from them.

use aberration::ImagingModel;
use glam::Vec3;
use rayon::prelude::*;

use crate::error::{Result, TrainError};
use crate::train::config::TrainConfig;
use crate::train::data::{Dataset, View};
use crate::train::object::ObjectTargets;

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
    fn shrinking_takes_block_means_and_drops_the_remainder() {
        // 5x3 with values x + 10y: 2x smaller is 2x1, the last column and row dropped.
        let px: Vec<Vec3> = (0..15)
            .map(|i| Vec3::splat((i % 5) as f32 + 10.0 * (i / 5) as f32))
            .collect();
        let s = shrink_pixels(&px, 5, 3, 2);
        assert_eq!(s, vec![Vec3::splat(5.5), Vec3::splat(7.5)]);
    }
}
