//! Per-tile alpha blending (forward) and its backward pass.
//!
//! For pixel centre `q = (i + 0.5, j + 0.5)` and a Gaussian with screen mean `m`, conic
//! `(a, b, c)` and opacity `o`: `d = m − q`, `σ = ½(a dx² + c dy²) + b dx dy`,
//! `α = min(0.99, o e^(−σ))`. Gaussians are blended front to back; one with `α < 1/255` (or
//! `σ < 0`) is skipped; when the transmittance after a Gaussian would drop to `≤ 1e-4` the
//! pixel stops *before* blending it (gsplat's rule). Colour is
//! `Σ cᵢ αᵢ Tᵢ + T_final · background`, alpha is `1 − T_final`, depth is
//! `Σ zᵢ αᵢ Tᵢ / (1 − T_final)` (expected depth; 0 where nothing was blended).

use std::mem::MaybeUninit;

use glam::{Vec2, Vec3};
use rayon::prelude::*;

use crate::conventions::{ALPHA_THRESHOLD, MAX_ALPHA, TILE_SIZE, TRANSMITTANCE_MIN};
use crate::disjoint::Disjoint;
use crate::project::Projected;
use crate::tiles::TileBins;

/// Raster-ready form of a projected Gaussian, precomputed once per Gaussian so the per-tile
/// gather is a plain copy (its loads are random; keeping them free of math lets them overlap).
#[derive(Clone, Copy, Debug, Default)]
pub struct Splat {
    mean: Vec2,
    conic: [f32; 3],
    opacity: f32,
    color: Vec3,
    depth: f32,
    /// `σ` beyond which `α < 1/255` for certain (`ln(255 o)` plus a rounding margin); lets
    /// most far pairs skip the `exp` without changing any decision.
    sigma_cut: f32,
    /// Inclusive pixel range `[x0, x1] × [y0, y1]` whose centres lie within the radius box.
    px: [i32; 4],
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

#[inline]
fn sigma_of(s: &Splat, q: Vec2) -> (f32, Vec2) {
    let d = s.mean - q;
    let [a, b, c] = s.conic;
    (0.5 * (a * d.x * d.x + c * d.y * d.y) + b * d.x * d.y, d)
}

/// Forward result of one tile, pixels in tile-local row-major order.
pub struct TileForward {
    pub color: Vec<Vec3>,
    pub alpha: Vec<f32>,
    pub depth: Vec<f32>,
    pub final_t: Vec<f32>,
    /// Number of list entries up to and including the last one blended into the pixel.
    pub n_contrib: Vec<u32>,
    /// Number of (pixel, Gaussian) pairs blended in this tile.
    pub blended: u64,
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

/// Blends one tile. Splats are visited front to back and each updates only the pixels of its
/// radius box; every pixel still sees its Gaussians in list order with exactly the
/// per-pixel arithmetic of the rule above, so the result equals a pixel-by-pixel loop.
pub fn forward_tile(
    bins: &TileBins,
    splats: &[Splat],
    t: usize,
    width: u32,
    height: u32,
    background: Vec3,
) -> TileForward {
    let splats = gather(bins, splats, t);
    let (x0, y0, w, h) = tile_pixels(bins, t, width, height);
    let n = (w * h) as usize;
    let mut tr = vec![1.0f32; n];
    let mut color = vec![Vec3::ZERO; n];
    let mut depth = vec![0.0f32; n];
    let mut last = vec![0u32; n];
    let mut done = vec![false; n];
    let mut n_done = 0;
    let mut blended = 0u64;
    for (k, s) in splats.iter().enumerate() {
        if n_done == n {
            break;
        }
        let Some([lx0, lx1, ly0, ly1]) = local_box(s, x0, y0, w, h) else {
            continue;
        };
        for ly in ly0..=ly1 {
            let qy = (y0 as usize + ly) as f32 + 0.5;
            // Every pixel of the box row gets the exact test: a per-row span of the quadratic
            // costs more than the pixels it spares.
            let (sx0, sx1) = (lx0, lx1);
            for lx in sx0..=sx1 {
                let li = ly * w as usize + lx;
                if done[li] {
                    continue;
                }
                let q = Vec2::new((x0 as usize + lx) as f32 + 0.5, qy);
                let (sigma, _) = sigma_of(s, q);
                if !(0.0..=s.sigma_cut).contains(&sigma) {
                    continue;
                }
                let alpha = MAX_ALPHA.min(s.opacity * (-sigma).exp());
                if alpha < ALPHA_THRESHOLD {
                    continue;
                }
                let next_t = tr[li] * (1.0 - alpha);
                if next_t <= TRANSMITTANCE_MIN {
                    done[li] = true;
                    n_done += 1;
                    continue;
                }
                let wgt = alpha * tr[li];
                color[li] += s.color * wgt;
                depth[li] += s.depth * wgt;
                tr[li] = next_t;
                last[li] = k as u32 + 1;
                blended += 1;
            }
        }
    }
    let alpha: Vec<f32> = tr.iter().map(|t| 1.0 - t).collect();
    TileForward {
        color: color
            .iter()
            .zip(&tr)
            .map(|(c, t)| *c + background * *t)
            .collect(),
        depth: depth
            .iter()
            .zip(&alpha)
            .map(|(d, a)| if *a > 0.0 { d / a } else { 0.0 })
            .collect(),
        alpha,
        final_t: tr,
        n_contrib: last,
        blended,
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

/// Backward of [`forward_tile`]: splats are visited back to front, each pixel of a splat's box
/// undoes its blending step (recovering `T` by division, as gsplat) and contributes to the
/// splat's gradient; pixels are summed in row-major order, so results are deterministic.
/// Every slot of `out` is written (zero for splats behind every pixel's last contributor).
#[allow(clippy::too_many_arguments)]
pub fn backward_tile(
    bins: &TileBins,
    splats: &[Splat],
    t: usize,
    width: u32,
    height: u32,
    background: Vec3,
    pix: &PixelGrads,
    out: &mut [MaybeUninit<IsectGrad>],
) {
    let splats = gather(bins, splats, t);
    let (x0, y0, w, h) = tile_pixels(bins, t, width, height);
    let n = (w * h) as usize;
    let mut tr = vec![0.0f32; n];
    let mut last = vec![0usize; n];
    let mut v_c = vec![Vec3::ZERO; n];
    // Expected depth d = D / A (D = Σ zᵢαᵢTᵢ, A = 1 − T_final) acts like a colour channel
    // with weight u = v_depth / A and no background, plus an alpha term with weight −u·d.
    let mut v_dsum = vec![0.0f32; n];
    // ∂/∂αₖ of the background, alpha and depth-normalisation terms share the factor
    // T_final / (1 − αₖ); this is T_final times (v_alpha − background · v_color − u·d).
    let mut v_final = vec![0.0f32; n];
    let mut behind = vec![Vec3::ZERO; n];
    let mut behind_z = vec![0.0f32; n];
    let mut max_last = 0;
    for ly in 0..h as usize {
        for lx in 0..w as usize {
            let li = ly * w as usize + lx;
            let idx = (y0 as usize + ly) * width as usize + x0 as usize + lx;
            tr[li] = pix.final_t[idx];
            last[li] = pix.n_contrib[idx] as usize;
            max_last = max_last.max(last[li]);
            v_c[li] = pix.v_color[idx];
            (v_dsum[li], v_final[li]) = pix.depth_and_final(idx, background);
        }
    }
    // One write per slot, back to front, whatever the splat contributes: the caller relies on
    // every slot being written.
    for (k, slot) in out.iter_mut().enumerate().rev() {
        let mut splat_grad = || {
            let s = &splats[k];
            let mut g = IsectGrad::default();
            let Some([lx0, lx1, ly0, ly1]) = local_box(s, x0, y0, w, h) else {
                return g;
            };
            for ly in ly0..=ly1 {
                let qy = (y0 as usize + ly) as f32 + 0.5;
                // Every pixel of the box row gets the exact test: a per-row span of the quadratic
                // costs more than the pixels it spares.
                let (sx0, sx1) = (lx0, lx1);
                for lx in sx0..=sx1 {
                    let li = ly * w as usize + lx;
                    if k >= last[li] {
                        continue;
                    }
                    let q = Vec2::new((x0 as usize + lx) as f32 + 0.5, qy);
                    let (sigma, d) = sigma_of(s, q);
                    if !(0.0..=s.sigma_cut).contains(&sigma) {
                        continue;
                    }
                    let vis = (-sigma).exp();
                    let raw = s.opacity * vis;
                    let alpha = MAX_ALPHA.min(raw);
                    if alpha < ALPHA_THRESHOLD {
                        continue;
                    }
                    let ra = 1.0 / (1.0 - alpha);
                    tr[li] *= ra;
                    let fac = alpha * tr[li];
                    g.color += v_c[li] * fac;
                    g.depth += v_dsum[li] * fac;
                    let v_alpha = (s.color * tr[li] - behind[li] * ra).dot(v_c[li])
                        + (s.depth * tr[li] - behind_z[li] * ra) * v_dsum[li]
                        + ra * v_final[li];
                    behind[li] += s.color * fac;
                    behind_z[li] += s.depth * fac;
                    if raw <= MAX_ALPHA {
                        let v_sigma = -raw * v_alpha;
                        let [a, b, c] = s.conic;
                        g.conic[0] += 0.5 * v_sigma * d.x * d.x;
                        g.conic[1] += v_sigma * d.x * d.y;
                        g.conic[2] += 0.5 * v_sigma * d.y * d.y;
                        let vm =
                            Vec2::new(v_sigma * (a * d.x + b * d.y), v_sigma * (b * d.x + c * d.y));
                        g.mean2d += vm;
                        g.mean2d_abs += vm.abs();
                        g.opacity += vis * v_alpha;
                    }
                }
            }
            g
        };
        slot.write(if k < max_last {
            splat_grad()
        } else {
            IsectGrad::default()
        });
    }
}
