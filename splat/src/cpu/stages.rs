//! The values the CPU renderer's stages hand each other: a projected Gaussian, its
//! blend-ready splat, a tile's list and pixels, and the gradients flowing back.

use std::mem::MaybeUninit;

use glam::{Vec2, Vec3};
use rayon::prelude::*;

use crate::conventions::{ALPHA_THRESHOLD, TILE_SIZE};
use crate::cpu::tiles::TileBins;
use crate::disjoint::Disjoint;

/// What the rasterizer needs for one visible Gaussian.
#[derive(Clone, Copy, Debug, Default)]
pub struct Projected {
    pub mean2d: Vec2,
    /// Inverse screen covariance `(a, b, c)` = `[[a, b], [b, c]]`.
    pub conic: [f32; 3],
    pub depth: f32,
    /// Sigmoid opacity, times the antialiasing compensation when enabled.
    pub opacity: f32,
    pub color: Vec3,
    /// Half-size of the pixel bounding box per axis; `[0, 0]` means culled.
    pub radius: [i32; 2],
}

/// Screen-space gradients of one Gaussian, summed over all pixels.
#[derive(Clone, Copy, Debug, Default)]
pub struct ScreenGrad {
    pub mean2d: Vec2,
    pub conic: [f32; 3],
    pub color: Vec3,
    pub opacity: f32,
    /// Gradient with respect to the camera-space depth `z` used for the depth output.
    pub depth: f32,
}

/// Parameter gradients of one Gaussian (SH rest gradients are written to a slice).
#[derive(Clone, Copy, Debug, Default)]
pub struct ParamGrad {
    pub mean: Vec3,
    pub log_scale: Vec3,
    pub rotation: [f32; 4],
    pub logit_opacity: f32,
    pub sh_dc: Vec3,
}

/// Raster-ready form of a projected Gaussian, precomputed once per Gaussian so the per-tile
/// gather is a plain copy (its loads are random; keeping them free of math lets them overlap).
#[derive(Clone, Copy, Debug, Default)]
pub struct Splat {
    pub(crate) mean: Vec2,
    pub(crate) conic: [f32; 3],
    pub(crate) opacity: f32,
    pub(crate) color: Vec3,
    pub(crate) depth: f32,
    /// `σ` beyond which `α < 1/255` for certain (`ln(255 o)` plus a rounding margin); lets
    /// most far pairs skip the `exp` without changing any decision.
    pub(crate) sigma_cut: f32,
    /// Inclusive pixel range `[x0, x1] × [y0, y1]` whose centres lie within the radius box.
    pub(crate) px: [i32; 4],
}

impl Splat {
    #[inline(always)]
    pub(crate) fn mean(&self) -> Vec2 {
        self.mean
    }
    #[inline(always)]
    pub(crate) fn conic(&self) -> [f32; 3] {
        self.conic
    }
    #[inline(always)]
    pub(crate) fn opacity(&self) -> f32 {
        self.opacity
    }
    #[inline(always)]
    pub(crate) fn sigma_cut(&self) -> f32 {
        self.sigma_cut
    }
    #[inline(always)]
    pub(crate) fn color(&self) -> Vec3 {
        self.color
    }
    #[inline(always)]
    pub(crate) fn depth(&self) -> f32 {
        self.depth
    }

    #[inline]
    pub fn new(p: &Projected) -> Self {
        if p.radius == [0, 0] {
            return Self::default();
        }
        let (rx, ry) = (p.radius[0] as f32, p.radius[1] as f32);
        let to_i = |v: f32| v.clamp(-1e9, 1e9) as i32;
        Splat {
            mean: p.mean2d,
            conic: p.conic,
            opacity: p.opacity,
            color: p.color,
            depth: p.depth,
            sigma_cut: (p.opacity / ALPHA_THRESHOLD).ln() * (1.0 + 1e-4) + 1e-4,
            px: [
                to_i((p.mean2d.x - rx - 0.5).ceil()),
                to_i((p.mean2d.x + rx - 0.5).floor()),
                to_i((p.mean2d.y - ry - 0.5).ceil()),
                to_i((p.mean2d.y + ry - 0.5).floor()),
            ],
        }
    }
}

/// [`Splat::new`] of every projected Gaussian, in parallel chunks compiled for SSE4.1 and up
/// where the CPU has them (rounding is then an instruction rather than a library call; the
/// same values).
pub fn splats_of(projected: &[Projected]) -> Vec<Splat> {
    const CHUNK: usize = 4096;
    let mut out = Vec::with_capacity(projected.len());
    out.spare_capacity_mut()[..projected.len()]
        .par_chunks_mut(CHUNK)
        .zip(projected.par_chunks(CHUNK))
        .for_each(|(o, p)| splat_chunk(p, o));
    // SAFETY: the chunks cover `0 .. len` and `splat_chunk` writes every slot of each.
    unsafe { out.set_len(projected.len()) };
    out
}

base::simd_builds! {
fn splat_chunk(p: &[Projected], out: &mut [MaybeUninit<Splat>]) {
    for (o, p) in out.iter_mut().zip(p) {
        o.write(Splat::new(p));
    }
}
}

/// Tile `t`'s list of splats, front to back, copied out contiguously.
pub fn gather(bins: &TileBins, splats: &[Splat], t: usize) -> Vec<Splat> {
    let mut list = Vec::new();
    gather_into(bins, splats, t, &mut list);
    list
}

/// [`gather`] into a buffer a worker reuses from tile to tile.
pub fn gather_into(bins: &TileBins, splats: &[Splat], t: usize, list: &mut Vec<Splat>) {
    list.clear();
    list.extend(bins.ids[bins.range(t)].iter().map(|&g| splats[g as usize]));
}

/// Pixel rectangle of tile `t`, clipped to the image: `(x0, y0, w, h)`.
pub fn tile_pixels(bins: &TileBins, t: usize, width: u32, height: u32) -> (u32, u32, u32, u32) {
    let tx = t as u32 % bins.tiles_x;
    let ty = t as u32 / bins.tiles_x;
    let (x0, y0) = (tx * TILE_SIZE, ty * TILE_SIZE);
    (
        x0,
        y0,
        TILE_SIZE.min(width - x0),
        TILE_SIZE.min(height - y0),
    )
}

/// The splat's pixel box intersected with the tile, in tile-local coordinates; `None` if empty.
#[inline]
pub(crate) fn local_box(s: &Splat, x0: u32, y0: u32, w: u32, h: u32) -> Option<[usize; 4]> {
    let lx0 = (s.px[0] - x0 as i32).max(0);
    let lx1 = (s.px[1] - x0 as i32).min(w as i32 - 1);
    let ly0 = (s.px[2] - y0 as i32).max(0);
    let ly1 = (s.px[3] - y0 as i32).min(h as i32 - 1);
    (lx0 <= lx1 && ly0 <= ly1).then_some([lx0 as usize, lx1 as usize, ly0 as usize, ly1 as usize])
}

/// The forward's output images, which every tile writes its own pixels of, in parallel.
pub struct TileSink<'a> {
    width: usize,
    color: Disjoint<'a, Vec3>,
    alpha: Disjoint<'a, f32>,
    depth: Disjoint<'a, f32>,
    /// What the backward keeps (absent for a plain render).
    kept: Option<(Disjoint<'a, f32>, Disjoint<'a, u32>)>,
}

/// One finished pixel of a tile.
pub struct PixelOut {
    pub color: Vec3,
    pub alpha: f32,
    pub depth: f32,
    pub final_t: f32,
    pub n_contrib: u32,
}

impl<'a> TileSink<'a> {
    /// Row-major images of `width` pixels per row; `kept`: the final transmittance and the
    /// contributor count per pixel, for a backward pass.
    pub fn new(
        width: u32,
        color: &'a mut [Vec3],
        alpha: &'a mut [f32],
        depth: &'a mut [f32],
        kept: Option<(&'a mut [f32], &'a mut [u32])>,
    ) -> Self {
        Self {
            width: width as usize,
            color: Disjoint::new(color),
            alpha: Disjoint::new(alpha),
            depth: Disjoint::new(depth),
            kept: kept.map(|(t, n)| (Disjoint::new(t), Disjoint::new(n))),
        }
    }

    /// Writes the pixels of the tile rectangle `(x0, y0, w, h)`, `pixel(lx, ly)` each.
    ///
    /// # Safety
    /// No other call writes an overlapping rectangle at the same time (tiles do not overlap,
    /// so one call per tile is safe).
    pub unsafe fn write_tile(
        &self,
        (x0, y0, w, h): (u32, u32, u32, u32),
        mut pixel: impl FnMut(usize, usize) -> PixelOut,
    ) {
        let w = w as usize;
        for ly in 0..h as usize {
            let start = (y0 as usize + ly) * self.width + x0 as usize;
            // SAFETY: the row of this tile: the caller's promise covers it.
            let (color, alpha, depth) = unsafe {
                (
                    self.color.part(start, w),
                    self.alpha.part(start, w),
                    self.depth.part(start, w),
                )
            };
            // SAFETY: as above.
            let mut kept = self
                .kept
                .as_ref()
                .map(|(t, n)| unsafe { (t.part(start, w), n.part(start, w)) });
            for lx in 0..w {
                let p = pixel(lx, ly);
                color[lx] = p.color;
                alpha[lx] = p.alpha;
                depth[lx] = p.depth;
                if let Some((t, n)) = kept.as_mut() {
                    t[lx] = p.final_t;
                    n[lx] = p.n_contrib;
                }
            }
        }
    }
}

/// Screen-space gradient of one (tile, Gaussian) pair, summed over the tile's pixels.
#[derive(Clone, Copy, Debug, Default)]
pub struct IsectGrad {
    pub mean2d: Vec2,
    /// Sum over pixels of `|∂L/∂mean2d|` per component (densification's "absgrad").
    pub mean2d_abs: Vec2,
    pub conic: [f32; 3],
    pub color: Vec3,
    pub opacity: f32,
    /// Gradient with respect to the Gaussian's camera-space depth (from the depth output).
    pub depth: f32,
}

/// Inputs of the backward tile kernel for the whole image (row-major, `width * height`).
pub struct PixelGrads<'a> {
    pub v_color: &'a [Vec3],
    pub v_alpha: Option<&'a [f32]>,
    pub v_depth: Option<&'a [f32]>,
    /// The forward's expected depth per pixel.
    pub depth: &'a [f32],
    pub final_t: &'a [f32],
    pub n_contrib: &'a [u32],
}

impl PixelGrads<'_> {
    /// The two per-pixel weights the backward starts from at pixel `idx` (row-major in the
    /// image): `u = v_depth / A` (the depth output's weight, as a colour channel) and
    /// `T_final · (v_alpha − background · v_color − u·d)` (the factor the background, alpha
    /// and depth-normalisation terms share).
    #[inline]
    pub(crate) fn depth_and_final(&self, idx: usize, background: Vec3) -> (f32, f32) {
        let tr = self.final_t[idx];
        let v_a = self.v_alpha.map_or(0.0, |a| a[idx]);
        let a_out = 1.0 - tr;
        let u = match self.v_depth {
            Some(v) if a_out > 0.0 => v[idx] / a_out,
            _ => 0.0,
        };
        (
            u,
            tr * (v_a - background.dot(self.v_color[idx]) - u * self.depth[idx]),
        )
    }
}
