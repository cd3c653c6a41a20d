//! Binning of projected Gaussians into 16×16 pixel tiles and the per-tile depth sort.
//!
//! Tile `t = ty * tiles_x + tx` covers pixels `[16 tx, 16 tx + 16) × [16 ty, 16 ty + 16)`.
//! A Gaussian with centre `m` and radius `r` is listed in tiles
//! `floor((m − r) / 16) ..< ceil((m + r) / 16)` per axis, clamped to the grid (gsplat's rule).
//! Within a tile Gaussians are ordered by the sort key `(depth, gaussian index)` ascending —
//! the index breaks ties so the order, and hence the image, is fully deterministic.

use rayon::prelude::*;

use crate::conventions::TILE_SIZE;
use crate::cpu::stages::Projected;
use crate::disjoint::Disjoint;

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

base::simd_builds! {
/// [`tile_rect`] of each of `projected`, compiled for each [`base::isa::Isa`] (in the AVX2 and
/// AVX-512 builds floor and ceil are instructions rather than library calls; the same values).
fn tile_rects(projected: &[Projected], tiles_x: u32, tiles_y: u32, out: &mut [[u32; 4]]) {
    for (o, p) in out.iter_mut().zip(projected) {
        *o = tile_rect(p, tiles_x, tiles_y);
    }
}
}

pub fn bin(projected: &[Projected], width: u32, height: u32) -> TileBins {
    let tiles_x = width.div_ceil(TILE_SIZE);
    let tiles_y = height.div_ceil(TILE_SIZE);
    let num_tiles = (tiles_x * tiles_y) as usize;
    let mut rects = vec![[0u32; 4]; projected.len()];
    rects
        .par_chunks_mut(4096)
        .zip(projected.par_chunks(4096))
        .for_each(|(r, p)| tile_rects(p, tiles_x, tiles_y, r));

    // Counting sort by tile, then a per-tile sort of the keys. The counting runs in chunks of
    // Gaussians in parallel: each chunk counts its entries per tile, a prefix sum over (tile,
    // chunk) gives every chunk its own slots in each tile, and the chunks scatter into them at
    // once. The order of keys within a tile before their sort depends on the chunking, the
    // sorted order does not (keys are unique: the Gaussian index is part of each).
    let chunk = rects
        .len()
        .div_ceil(4 * rayon::current_num_threads())
        .max(4096);
    let mut cursors: Vec<Vec<usize>> = rects
        .par_chunks(chunk)
        .map(|rs| {
            let mut counts = vec![0usize; num_tiles];
            for r in rs {
                for ty in r[2]..r[3] {
                    for tx in r[0]..r[1] {
                        counts[(ty * tiles_x + tx) as usize] += 1;
                    }
                }
            }
            counts
        })
        .collect();
    let mut offsets = vec![0usize; num_tiles + 1];
    let mut total = 0;
    for t in 0..num_tiles {
        offsets[t] = total;
        for c in cursors.iter_mut() {
            let n = c[t];
            c[t] = total;
            total += n;
        }
    }
    offsets[num_tiles] = total;
    // Sort key per entry: depth bits in the high word (depths are ≥ near > 0, where the IEEE
    // bit pattern orders like the value), Gaussian index in the low word as the tie-break.
    let mut keys = vec![0u64; total];
    {
        let out = Disjoint::new(&mut keys);
        rects
            .par_chunks(chunk)
            .zip(cursors.par_iter_mut())
            .enumerate()
            .for_each(|(c, (rs, cursor))| {
                for (j, r) in rs.iter().enumerate() {
                    let g = c * chunk + j;
                    let key = ((projected[g].depth.to_bits() as u64) << 32) | g as u64;
                    for ty in r[2]..r[3] {
                        for tx in r[0]..r[1] {
                            let t = (ty * tiles_x + tx) as usize;
                            // SAFETY: the prefix sum gave this chunk the slots
                            // `cursor[t] ..` of tile t up to its own count, which no other
                            // chunk's range overlaps.
                            unsafe { out.write(cursor[t], key) };
                            cursor[t] += 1;
                        }
                    }
                }
            });
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The chunked parallel binning against the obvious one: every (tile, key) pair of every
    /// Gaussian's rectangle, sorted.
    #[test]
    fn binning_equals_a_plain_sort_of_every_pair() {
        let g = crate::synthetic::random_box_scene(3, 30_000, 0);
        let cam = crate::synthetic::benchmark_camera().resized(300, 200);
        let pos = cam.position();
        let projected: Vec<Projected> = (0..g.len())
            .map(|i| {
                crate::reference::scalar_project::project_one(&g, i, &cam, 0, false, pos)
                    .unwrap_or_default()
            })
            .collect();
        let bins = bin(&projected, cam.width, cam.height);
        let mut pairs = Vec::new();
        for (i, p) in projected.iter().enumerate() {
            let r = tile_rect(p, bins.tiles_x, bins.tiles_y);
            for ty in r[2]..r[3] {
                for tx in r[0]..r[1] {
                    pairs.push((ty * bins.tiles_x + tx, p.depth.to_bits(), i as u32));
                }
            }
        }
        pairs.sort_unstable();
        assert!(pairs.len() > 30_000, "too few pairs to span several chunks");
        assert_eq!(bins.ids.len(), pairs.len());
        for t in 0..bins.num_tiles() {
            let want: Vec<u32> = pairs
                .iter()
                .filter(|p| p.0 as usize == t)
                .map(|p| p.2)
                .collect();
            assert_eq!(&bins.ids[bins.range(t)], &want[..], "tile {t}");
        }
    }
}
