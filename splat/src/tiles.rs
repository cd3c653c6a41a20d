//! Binning of projected Gaussians into 16×16 pixel tiles and the per-tile depth sort.
//!
//! Tile `t = ty * tiles_x + tx` covers pixels `[16 tx, 16 tx + 16) × [16 ty, 16 ty + 16)`.
//! A Gaussian with centre `m` and radius `r` is listed in tiles
//! `floor((m − r) / 16) ..< ceil((m + r) / 16)` per axis, clamped to the grid (gsplat's rule).
//! Within a tile Gaussians are ordered by the sort key `(depth, gaussian index)` ascending —
//! the index breaks ties so the order, and hence the image, is fully deterministic.

use rayon::prelude::*;

use crate::conventions::TILE_SIZE;
use crate::project::Projected;

/// Tile lists: tile `t` holds `ids[offsets[t] .. offsets[t + 1]]`, front to back.
#[derive(Clone, Debug, Default)]
pub struct TileBins {
    pub tiles_x: u32,
    pub tiles_y: u32,
    pub offsets: Vec<usize>,
    pub ids: Vec<u32>,
}

impl TileBins {
    pub fn num_tiles(&self) -> usize {
        (self.tiles_x * self.tiles_y) as usize
    }

    pub fn range(&self, t: usize) -> std::ops::Range<usize> {
        self.offsets[t]..self.offsets[t + 1]
    }
}

/// Tile rectangle `[x0, x1) × [y0, y1)` touched by a projected Gaussian (empty when culled).
#[inline]
pub fn tile_rect(p: &Projected, tiles_x: u32, tiles_y: u32) -> [u32; 4] {
    if p.radius[0] <= 0 && p.radius[1] <= 0 {
        return [0; 4];
    }
    let ts = TILE_SIZE as f32;
    let (rx, ry) = (p.radius[0] as f32, p.radius[1] as f32);
    let clampf = |v: f32, hi: u32| v.clamp(0.0, hi as f32) as u32;
    [
        clampf(((p.mean2d.x - rx) / ts).floor(), tiles_x),
        clampf(((p.mean2d.x + rx) / ts).ceil(), tiles_x),
        clampf(((p.mean2d.y - ry) / ts).floor(), tiles_y),
        clampf(((p.mean2d.y + ry) / ts).ceil(), tiles_y),
    ]
}

pub fn bin(projected: &[Projected], width: u32, height: u32) -> TileBins {
    let tiles_x = width.div_ceil(TILE_SIZE);
    let tiles_y = height.div_ceil(TILE_SIZE);
    let num_tiles = (tiles_x * tiles_y) as usize;
    let rects: Vec<[u32; 4]> = projected
        .par_iter()
        .map(|p| tile_rect(p, tiles_x, tiles_y))
        .collect();

    // Counting sort by tile, then a per-tile sort of the keys.
    let mut counts = vec![0usize; num_tiles + 1];
    for r in &rects {
        for ty in r[2]..r[3] {
            for tx in r[0]..r[1] {
                counts[(ty * tiles_x + tx) as usize + 1] += 1;
            }
        }
    }
    for t in 0..num_tiles {
        counts[t + 1] += counts[t];
    }
    let offsets = counts;
    // Sort key per entry: depth bits in the high word (depths are ≥ near > 0, where the IEEE
    // bit pattern orders like the value), Gaussian index in the low word as the tie-break.
    let mut cursor = offsets.clone();
    let mut keys = vec![0u64; offsets[num_tiles]];
    for (g, r) in rects.iter().enumerate() {
        let key = ((projected[g].depth.to_bits() as u64) << 32) | g as u64;
        for ty in r[2]..r[3] {
            for tx in r[0]..r[1] {
                let t = (ty * tiles_x + tx) as usize;
                keys[cursor[t]] = key;
                cursor[t] += 1;
            }
        }
    }
    let mut bins = TileBins {
        tiles_x,
        tiles_y,
        offsets,
        ids: Vec::new(),
    };
    let mut ids = vec![0u32; keys.len()];
    split_per_tile(&bins, &mut keys)
        .into_par_iter()
        .zip(split_per_tile(&bins, &mut ids))
        .for_each(|(k, out)| {
            k.sort_unstable();
            for (o, key) in out.iter_mut().zip(k.iter()) {
                *o = *key as u32;
            }
        });
    bins.ids = ids;
    bins
}

/// Splits `buf` into one mutable slice per tile following `bins.offsets`.
pub fn split_per_tile<'a, T>(bins: &TileBins, buf: &'a mut [T]) -> Vec<&'a mut [T]> {
    let mut out = Vec::with_capacity(bins.num_tiles());
    let mut rest = buf;
    for t in 0..bins.num_tiles() {
        let (head, tail) = rest.split_at_mut(bins.offsets[t + 1] - bins.offsets[t]);
        out.push(head);
        rest = tail;
    }
    out
}
