//! Steadying a restored clip over time. Each frame is restored alone, so where the network is
//! unsure (noise, weak texture) consecutive frames can differ where the scene does not. A
//! steadied frame is the restored one blended with the previous steadied frame, warped along
//! the motion between the two, wherever the warped frame agrees with the restored one: a
//! recursive filter that follows the motion and stops at occlusions, new content and cuts.
//!
//! Motion is block matching on luma (sum of absolute differences, sub-pixel by a parabola
//! through the best cost and its neighbours, a 3×3 median over the blocks), interpolated
//! between block centres; the warp is bilinear. No optical-flow crate in the registry serves
//! plain `f32` planes without pulling in an image stack of its own.

use aberration::Image;
use rayon::prelude::*;

use crate::error::{RestoreError, Result};

/// How a clip is steadied. `strength` 0 leaves every frame as restored.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Steady {
    /// Weight of the warped previous frame where it agrees with the restored one, in [0, 1).
    pub strength: f32,
    /// Disagreement (mean absolute difference over RGB and a 3×3 neighbourhood, [0, 1] units)
    /// at which the previous frame's weight has fallen to zero.
    pub tolerance: f32,
    /// Side of the blocks whose motion is estimated (px).
    pub block: usize,
    /// Largest motion searched between two frames (px, each axis).
    pub search: usize,
}

impl Steady {
    /// The defaults with this strength: tolerance 0.04, 16 px blocks, motion up to 12 px.
    pub fn new(strength: f32) -> Self {
        Self {
            strength,
            tolerance: 0.04,
            block: 16,
            search: 12,
        }
    }

    /// Refuses a strength outside [0, 1), a tolerance that is not positive, an empty block.
    pub fn validate(&self) -> Result<()> {
        if !(self.strength.is_finite() && (0.0..1.0).contains(&self.strength)) {
            return Err(RestoreError::BadInput(format!(
                "steadying strength {} is outside [0, 1): 0 is off, 0.5 averages about three frames",
                self.strength
            )));
        }
        if !(self.tolerance.is_finite() && self.tolerance > 0.0) || self.block == 0 {
            return Err(RestoreError::BadInput(format!(
                "steadying tolerance {} and block {} must be positive",
                self.tolerance, self.block
            )));
        }
        Ok(())
    }
}

/// Where each block's content was in the previous frame: a displacement per block, to be
/// added to a pixel's position in the current frame.
#[derive(Clone, Debug)]
pub struct Flow {
    /// Block centres along x and y (px, pixel centres at integers).
    cx: Vec<f32>,
    cy: Vec<f32>,
    /// Displacement per block, row-major (`cy.len()` rows of `cx.len()`).
    pub dx: Vec<f32>,
    pub dy: Vec<f32>,
}

impl Flow {
    /// The displacement at a pixel, bilinear between block centres (constant past the outer
    /// centres).
    pub fn at(&self, x: f32, y: f32) -> (f32, f32) {
        let (ix, fx) = locate(&self.cx, x);
        let (iy, fy) = locate(&self.cy, y);
        let n = self.cx.len();
        let (ix1, iy1) = ((ix + 1).min(n - 1), (iy + 1).min(self.cy.len() - 1));
        let lerp2 = |v: &[f32]| {
            let top = v[iy * n + ix] * (1.0 - fx) + v[iy * n + ix1] * fx;
            let bottom = v[iy1 * n + ix] * (1.0 - fx) + v[iy1 * n + ix1] * fx;
            top * (1.0 - fy) + bottom * fy
        };
        (lerp2(&self.dx), lerp2(&self.dy))
    }
}

/// Index of the centre at or left of `v` and the fraction towards the next (0 outside).
fn locate(centres: &[f32], v: f32) -> (usize, f32) {
    if v <= centres[0] {
        return (0, 0.0);
    }
    let last = centres.len() - 1;
    if v >= centres[last] {
        return (last, 0.0);
    }
    let i = centres.partition_point(|&c| c <= v) - 1;
    (i, (v - centres[i]) / (centres[i + 1] - centres[i]))
}

fn luma(im: &Image) -> Vec<f32> {
    let (r, g, b) = (im.channel(0), im.channel(1), im.channel(2));
    (0..im.plane_len())
        .map(|i| 0.299 * r[i] + 0.587 * g[i] + 0.114 * b[i])
        .collect()
}

/// Motion from `prev` to `cur` by block matching on luma: for each `block`² block of `cur`,
/// the shift within ±`search` px whose window of `prev` differs least (mean absolute
/// difference over the pixels inside both frames, with a slight preference for small shifts
/// so a flat block stays put), refined to sub-pixel by a parabola, then a 3×3 median over
/// the blocks to drop lone mismatches.
pub fn motion(prev: &Image, cur: &Image, block: usize, search: usize) -> Flow {
    let (w, h) = (cur.width, cur.height);
    let (lp, lc) = (luma(prev), luma(cur));
    let spans = |len: usize| -> Vec<(usize, usize)> {
        (0..len.div_ceil(block))
            .map(|b| (b * block, ((b + 1) * block).min(len)))
            .collect()
    };
    let (xs, ys) = (spans(w), spans(h));
    let s = search as i64;
    let side = 2 * search + 1;
    let cost = |(x0, x1): (usize, usize), (y0, y1): (usize, usize), dx: i64, dy: i64| {
        let (mut sum, mut count) = (0.0f32, 0usize);
        for y in y0..y1 {
            let py = y as i64 + dy;
            if py < 0 || py >= h as i64 {
                continue;
            }
            let xa = (x0 as i64).max(-dx) as usize;
            let xb = (x1 as i64).min(w as i64 - dx).max(xa as i64) as usize;
            let row_c = &lc[y * w..];
            let row_p = &lp[py as usize * w..];
            for x in xa..xb {
                sum += (row_c[x] - row_p[(x as i64 + dx) as usize]).abs();
            }
            count += xb - xa;
        }
        let area = (x1 - x0) * (y1 - y0);
        if count * 2 < area {
            f32::INFINITY
        } else {
            sum / count as f32 + 1e-4 * (dx.abs() + dy.abs()) as f32
        }
    };
    let vectors: Vec<(f32, f32)> = ys
        .par_iter()
        .flat_map_iter(|&yr| {
            xs.iter()
                .map(move |&xr| {
                    let costs: Vec<f32> = (0..side * side)
                        .map(|k| cost(xr, yr, (k % side) as i64 - s, (k / side) as i64 - s))
                        .collect();
                    let best = (0..costs.len())
                        .min_by(|&a, &b| costs[a].total_cmp(&costs[b]))
                        .unwrap_or(0);
                    if !costs[best].is_finite() {
                        return (0.0, 0.0);
                    }
                    let (bx, by) = (best % side, best / side);
                    let refine = |lo: Option<usize>, hi: Option<usize>| match (lo, hi) {
                        (Some(l), Some(r)) => parabola(costs[l], costs[best], costs[r]),
                        _ => 0.0,
                    };
                    let fx = refine(
                        (bx > 0).then(|| best - 1),
                        (bx + 1 < side).then_some(best + 1),
                    );
                    let fy = refine(
                        (by > 0).then(|| best - side),
                        (by + 1 < side).then_some(best + side),
                    );
                    (bx as f32 - s as f32 + fx, by as f32 - s as f32 + fy)
                })
                .collect::<Vec<_>>()
        })
        .collect();
    let (nx, ny) = (xs.len(), ys.len());
    let median = |pick: fn(&(f32, f32)) -> f32| -> Vec<f32> {
        (0..nx * ny)
            .map(|i| {
                let (bx, by) = (i % nx, i / nx);
                let mut v: Vec<f32> = (by.saturating_sub(1)..(by + 2).min(ny))
                    .flat_map(|y| (bx.saturating_sub(1)..(bx + 2).min(nx)).map(move |x| (x, y)))
                    .map(|(x, y)| pick(&vectors[y * nx + x]))
                    .collect();
                v.sort_by(f32::total_cmp);
                v[v.len() / 2]
            })
            .collect()
    };
    let centre = |(a, b): &(usize, usize)| (a + b - 1) as f32 / 2.0;
    Flow {
        cx: xs.iter().map(centre).collect(),
        cy: ys.iter().map(centre).collect(),
        dx: median(|v| v.0),
        dy: median(|v| v.1),
    }
}

/// Offset of a parabola's minimum through costs at −1, 0, +1 (0 where they are not convex).
fn parabola(l: f32, c: f32, r: f32) -> f32 {
    let d = l - 2.0 * c + r;
    if !(l.is_finite() && r.is_finite()) || d <= 1e-12 {
        return 0.0;
    }
    (0.5 * (l - r) / d).clamp(-0.5, 0.5)
}

/// `prev` resampled along `flow` (bilinear): pixel (x, y) takes `prev` at (x, y) + flow. The
/// second image is 1 where the sample lay inside `prev` and 0 where it did not.
pub fn warp(prev: &Image, flow: &Flow) -> (Image, Vec<f32>) {
    let (w, h) = (prev.width, prev.height);
    let plane = prev.plane_len();
    let mut out = Image::new(w, h);
    let mut inside = vec![0.0f32; plane];
    for y in 0..h {
        for x in 0..w {
            let (dx, dy) = flow.at(x as f32, y as f32);
            let (sx, sy) = (x as f32 + dx, y as f32 + dy);
            if !(sx >= 0.0 && sy >= 0.0 && sx <= (w - 1) as f32 && sy <= (h - 1) as f32) {
                continue;
            }
            let (x0, y0) = (sx.floor() as usize, sy.floor() as usize);
            let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
            let (fx, fy) = (sx - x0 as f32, sy - y0 as f32);
            let i = y * w + x;
            inside[i] = 1.0;
            for c in 0..3 {
                let p = prev.channel(c);
                let top = p[y0 * w + x0] * (1.0 - fx) + p[y0 * w + x1] * fx;
                let bottom = p[y1 * w + x0] * (1.0 - fx) + p[y1 * w + x1] * fx;
                out.data[c * plane + i] = top * (1.0 - fy) + bottom * fy;
            }
        }
    }
    (out, inside)
}

/// Mean of a plane over each pixel's 3×3 neighbourhood (clipped at the borders).
fn box3(v: &[f32], w: usize, h: usize) -> Vec<f32> {
    let mut out = vec![0.0; v.len()];
    for y in 0..h {
        for x in 0..w {
            let (mut sum, mut n) = (0.0, 0.0);
            for yy in y.saturating_sub(1)..(y + 2).min(h) {
                for xx in x.saturating_sub(1)..(x + 2).min(w) {
                    sum += v[yy * w + xx];
                    n += 1.0;
                }
            }
            out[y * w + x] = sum / n;
        }
    }
    out
}

/// The steadied frame: `restored` blended with `previous` (the last steadied frame) warped
/// along the motion between them, with weight `strength · max(0, 1 − d / tolerance)` where
/// `d` is their disagreement; `restored` itself for the first frame, at strength 0, or where
/// the warp left the previous frame. Frames of another size than the previous are refused.
pub fn steady_frame(previous: Option<&Image>, restored: Image, s: &Steady) -> Result<Image> {
    s.validate()?;
    let Some(prev) = previous.filter(|_| s.strength > 0.0) else {
        return Ok(restored);
    };
    if (prev.width, prev.height) != (restored.width, restored.height) {
        return Err(RestoreError::BadInput(format!(
            "a frame is {}x{} and the one before it {}x{}: a clip's frames are of one size",
            restored.width, restored.height, prev.width, prev.height
        )));
    }
    let flow = motion(prev, &restored, s.block, s.search);
    let (warped, inside) = warp(prev, &flow);
    let (w, h, plane) = (restored.width, restored.height, restored.plane_len());
    let disagreement: Vec<f32> = (0..plane)
        .map(|i| {
            (0..3)
                .map(|c| (warped.data[c * plane + i] - restored.data[c * plane + i]).abs())
                .sum::<f32>()
                / 3.0
        })
        .collect();
    let d = box3(&disagreement, w, h);
    let mut out = restored;
    for i in 0..plane {
        let weight = s.strength * (1.0 - d[i] / s.tolerance).max(0.0) * inside[i];
        if weight > 0.0 && weight.is_finite() {
            for c in 0..3 {
                let k = c * plane + i;
                out.data[k] += weight * (warped.data[k] - out.data[k]);
            }
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::video::temporal_error;
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// A smooth random texture (sums of sines) seen through a window moved by `(ox, oy)`.
    fn texture(w: usize, h: usize, ox: f32, oy: f32) -> Image {
        Image::from_fn(w, h, |x, y| {
            let (u, v) = (x as f32 + ox, y as f32 + oy);
            let t = 0.5
                + 0.2 * (0.31 * u + 0.17 * v).sin()
                + 0.15 * (0.11 * u - 0.37 * v).cos()
                + 0.1 * (0.53 * u + 0.05 * v * v * 0.01).sin();
            [t, 0.8 * t + 0.1, 1.0 - t]
        })
    }

    fn noisy(im: &Image, sigma: f32, seed: u64) -> Image {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut out = im.clone();
        for v in &mut out.data {
            *v += sigma * (rng.random::<f32>() * 2.0 - 1.0) * 1.732;
        }
        out
    }

    fn steady_clip(frames: &[Image], s: &Steady) -> Vec<Image> {
        let mut out: Vec<Image> = Vec::new();
        for f in frames {
            let next = steady_frame(out.last(), f.clone(), s).unwrap();
            out.push(next);
        }
        out
    }

    fn mean_psnr(a: &[Image], b: &[Image]) -> f64 {
        a.iter()
            .zip(b)
            .map(|(x, y)| aberration::psnr(x, y).unwrap())
            .sum::<f64>()
            / a.len() as f64
    }

    #[test]
    fn block_matching_finds_a_whole_and_a_half_pixel_shift() {
        let prev = texture(96, 64, 0.0, 0.0);
        // The current frame sees the texture 3 px right and 2 px up: its pixel (x, y) was at
        // (x + 3, y - 2) in the previous frame.
        let cur = texture(96, 64, 3.0, -2.0);
        let f = motion(&prev, &cur, 16, 6);
        for (dx, dy) in f.dx.iter().zip(&f.dy) {
            assert!(
                (dx - 3.0).abs() < 0.05 && (dy + 2.0).abs() < 0.05,
                "{dx} {dy}"
            );
        }
        let (warped, inside) = warp(&prev, &f);
        let plane = cur.plane_len();
        let mut worst = 0.0f32;
        for (i, _) in inside.iter().enumerate().filter(|(_, v)| **v > 0.0) {
            for c in 0..3 {
                worst = worst.max((warped.data[c * plane + i] - cur.data[c * plane + i]).abs());
            }
        }
        assert!(worst < 0.01, "warp error {worst}");
        // Half a pixel: the parabola lands within a tenth of it.
        let half = texture(96, 64, 1.5, 0.0);
        let f = motion(&prev, &half, 16, 6);
        let mean = f.dx.iter().sum::<f32>() / f.dx.len() as f32;
        assert!((mean - 1.5).abs() < 0.1, "{mean}");
    }

    #[test]
    fn strength_zero_and_the_first_frame_are_left_as_restored() {
        let a = noisy(&texture(40, 30, 0.0, 0.0), 0.02, 1);
        let b = noisy(&texture(40, 30, 1.0, 0.0), 0.02, 2);
        let off = steady_frame(Some(&a), b.clone(), &Steady::new(0.0)).unwrap();
        assert_eq!(off.data, b.data);
        let first = steady_frame(None, b.clone(), &Steady::new(0.6)).unwrap();
        assert_eq!(first.data, b.data);
        let on = steady_frame(Some(&a), b.clone(), &Steady::new(0.6)).unwrap();
        assert_ne!(on.data, b.data);
    }

    #[test]
    fn a_still_and_a_moving_noisy_clip_get_steadier_and_closer_to_the_clean_one() {
        for step in [0.0f32, 2.0] {
            let clean: Vec<Image> = (0..8)
                .map(|t| texture(64, 48, step * t as f32, 0.5 * step * t as f32))
                .collect();
            let restored: Vec<Image> = clean
                .iter()
                .enumerate()
                .map(|(t, c)| noisy(c, 0.01, 10 + t as u64))
                .collect();
            let steadied = steady_clip(&restored, &Steady::new(0.6));
            let (e0, e1) = (
                temporal_error(&restored, &clean).unwrap(),
                temporal_error(&steadied, &clean).unwrap(),
            );
            let (p0, p1) = (mean_psnr(&restored, &clean), mean_psnr(&steadied, &clean));
            assert!(e1 < 0.8 * e0, "motion {step}: temporal error {e0} -> {e1}");
            assert!(p1 > p0 + 1.0, "motion {step}: PSNR {p0} -> {p1}");
            assert!(steadied.iter().all(Image::is_finite));
        }
    }

    #[test]
    fn a_cut_is_not_blended_into() {
        let a = texture(64, 48, 0.0, 0.0);
        // Another scene: the texture's colours swapped and shifted far beyond the search.
        let b = Image::from_fn(64, 48, |x, y| {
            let v = a.get(63 - x, 47 - y, 0);
            [1.0 - v, v, 0.3]
        });
        let out = steady_frame(Some(&a), b.clone(), &Steady::new(0.9)).unwrap();
        let worst = out
            .data
            .iter()
            .zip(&b.data)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0f32, f32::max);
        assert!(worst < 0.03, "the cut leaked {worst} of the previous frame");
    }

    #[test]
    fn bad_settings_and_mismatched_frames_are_refused() {
        let a = texture(32, 24, 0.0, 0.0);
        for s in [1.0, -0.1, f32::NAN] {
            let e = steady_frame(Some(&a), a.clone(), &Steady::new(s)).unwrap_err();
            assert!(e.to_string().contains("outside [0, 1)"), "{e}");
        }
        let small = texture(16, 24, 0.0, 0.0);
        let e = steady_frame(Some(&a), small, &Steady::new(0.5)).unwrap_err();
        assert!(e.to_string().contains("16x24"), "{e}");
    }
}
