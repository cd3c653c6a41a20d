//! Densification primitives (3DGS / gsplat "default strategy"), as plain functions the trainer
//! calls at its hooks. Each structural edit returns `sources`: for every Gaussian of the new
//! model, the index it came from or `None` for a freshly created one — feed it to
//! [`crate::optim::Adam::remap`] and [`DensifyStats::remap`].

use glam::Vec3;

use crate::cpu::project::quat_to_rotmat;
use crate::cpu::render::{Gradients, RenderOutput};
use crate::error::SplatError;
use crate::model::{Gaussians, logit, sigmoid};
use base::SplitMix64;

/// A per-Gaussian mask must have the model's length.
pub(crate) fn check_mask(g: &Gaussians, mask: &[bool]) -> Result<(), SplatError> {
    if mask.len() == g.len() {
        Ok(())
    } else {
        Err(SplatError::SizeMismatch {
            what: "densification mask",
            expected: g.len(),
            got: mask.len(),
        })
    }
}

/// 3DGS divides the scale of split children by 1.6.
pub const SPLIT_SCALE_DIVISOR: f32 = 1.6;

/// Appends a copy of every masked Gaussian (3DGS "clone"); originals keep their index.
pub fn clone_gaussians(g: &mut Gaussians, mask: &[bool]) -> Result<Vec<Option<usize>>, SplatError> {
    check_mask(g, mask)?;
    let n = g.len();
    let mut sources: Vec<Option<usize>> = (0..n).map(Some).collect();
    let src = g.clone();
    for (i, _) in mask.iter().enumerate().filter(|(_, m)| **m) {
        g.push_from(&src, i);
        sources.push(None);
    }
    Ok(sources)
}

/// Replaces every masked Gaussian by two children whose means are sampled from the parent
/// (`mean + R (s ⊙ n)`, `n ~ N(0, I)`) and whose scales are the parent's divided by 1.6.
/// Unmasked Gaussians keep their order; children are appended. Deterministic given `seed`.
pub fn split_gaussians(
    g: &mut Gaussians,
    mask: &[bool],
    seed: u64,
) -> Result<Vec<Option<usize>>, SplatError> {
    check_mask(g, mask)?;
    let mut rng = SplitMix64::new(seed);
    let src = std::mem::replace(g, Gaussians::new(g.sh_degree));
    let mut sources = Vec::with_capacity(src.len() + mask.iter().filter(|m| **m).count());
    for i in (0..src.len()).filter(|&i| !mask[i]) {
        g.push_from(&src, i);
        sources.push(Some(i));
    }
    let shrink = SPLIT_SCALE_DIVISOR.ln();
    for i in (0..src.len()).filter(|&i| mask[i]) {
        let (rot, _, _) = quat_to_rotmat(src.rotations[i]);
        let scale = src.log_scales[i].exp();
        for _ in 0..2 {
            let n = rng.normal_vec3();
            g.push(
                src.means[i] + rot * (scale * n),
                src.log_scales[i] - Vec3::splat(shrink),
                src.rotations[i],
                src.logit_opacities[i],
                src.sh_dc[i],
                src.sh_rest_of(i),
            );
            sources.push(None);
        }
    }
    Ok(sources)
}

/// Removes every masked Gaussian.
pub fn prune_gaussians(g: &mut Gaussians, mask: &[bool]) -> Result<Vec<Option<usize>>, SplatError> {
    check_mask(g, mask)?;
    let keep: Vec<usize> = (0..g.len()).filter(|&i| !mask[i]).collect();
    *g = g.gather(&keep);
    Ok(keep.into_iter().map(Some).collect())
}

/// Gaussians to prune: opacity below `min_opacity`, or largest world scale above
/// `max_world_scale`, or (with `max_screen_radius`) a largest screen radius above it.
pub fn prune_mask(
    g: &Gaussians,
    min_opacity: f32,
    max_world_scale: Option<f32>,
    max_screen_radius: Option<(&DensifyStats, f32)>,
) -> Vec<bool> {
    (0..g.len())
        .map(|i| {
            let low = sigmoid(g.logit_opacities[i]) < min_opacity;
            let big = max_world_scale.is_some_and(|m| g.log_scales[i].exp().max_element() > m);
            let wide = max_screen_radius.is_some_and(|(s, r)| s.max_radius[i] > r);
            low || big || wide || !g.means[i].is_finite()
        })
        .collect()
}

/// Caps every opacity at `max_opacity` (3DGS resets to 0.01 every 3000 steps).
pub fn reset_opacity(g: &mut Gaussians, max_opacity: f32) {
    let cap = logit(max_opacity);
    for o in &mut g.logit_opacities {
        *o = o.min(cap);
    }
}

/// Running statistics between densification steps: accumulated screen-space gradient norm,
/// the number of views each Gaussian was visible in, and its largest screen radius.
#[derive(Clone, Debug, Default)]
pub struct DensifyStats {
    pub grad_norm_sum: Vec<f32>,
    pub count: Vec<u32>,
    pub max_radius: Vec<f32>,
}

impl DensifyStats {
    pub fn new(n: usize) -> Self {
        Self {
            grad_norm_sum: vec![0.0; n],
            count: vec![0; n],
            max_radius: vec![0.0; n],
        }
    }

    /// Adds one view. As gsplat, the pixel gradient is scaled by half the image size so
    /// thresholds are resolution independent (3DGS's default threshold is 2e-4); `absgrad`
    /// uses the summed absolute per-pixel gradients instead.
    pub fn add(&mut self, grads: &Gradients, out: &RenderOutput, absgrad: bool) {
        let src = if absgrad {
            &grads.means2d_abs
        } else {
            &grads.means2d
        };
        self.add_screen(src, out);
    }

    /// [`DensifyStats::add`] from the screen-space mean gradients alone.
    pub fn add_screen(&mut self, src: &[[f32; 2]], out: &RenderOutput) {
        let (hw, hh) = (out.width as f32 * 0.5, out.height as f32 * 0.5);
        for (i, vis) in out.visible.iter().enumerate() {
            if !*vis {
                continue;
            }
            let g = glam::Vec2::new(src[i][0] * hw, src[i][1] * hh).length();
            self.grad_norm_sum[i] += g;
            self.count[i] += 1;
            let r = out.radii[i][0].max(out.radii[i][1]) as f32;
            self.max_radius[i] = self.max_radius[i].max(r);
        }
    }

    /// Average gradient norm above `threshold`: the candidates for clone or split.
    pub fn grow_mask(&self, threshold: f32) -> Vec<bool> {
        self.grad_norm_sum
            .iter()
            .zip(&self.count)
            .map(|(s, &c)| c > 0 && s / c as f32 > threshold)
            .collect()
    }

    /// Re-indexes after a structural edit (`sources` from one of this module's functions).
    pub fn remap(&mut self, sources: &[Option<usize>]) -> Result<(), SplatError> {
        let n = self.count.len();
        if let Some(bad) = sources.iter().flatten().find(|&&i| i >= n) {
            return Err(SplatError::InvalidInput(format!(
                "remap source {bad} out of range for {n} Gaussians"
            )));
        }
        let pick = |v: &Vec<f32>| sources.iter().map(|s| s.map_or(0.0, |i| v[i])).collect();
        self.grad_norm_sum = pick(&self.grad_norm_sum);
        self.max_radius = pick(&self.max_radius);
        self.count = sources
            .iter()
            .map(|s| s.map_or(0, |i| self.count[i]))
            .collect();
        Ok(())
    }
}
