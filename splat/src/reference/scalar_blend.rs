//! Per-tile alpha blending (forward) and its backward pass, one pixel at a time with branches:
//! the rule [`crate::cpu::blend`]'s lane kernels compute, kept as their reference.
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

use crate::conventions::{ALPHA_THRESHOLD, MAX_ALPHA, TRANSMITTANCE_MIN};
use crate::cpu::stages::{IsectGrad, PixelGrads, Splat, gather, local_box, tile_pixels};
use crate::cpu::tiles::TileBins;

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
