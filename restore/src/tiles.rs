//! Planar images padded for the network and restored in overlapping tiles, so memory stays
//! bounded on large images. Tiles are blended with weights that ramp over the overlap.

use aberration::blur::layout::reflect;

/// `c` planes of `h × w`, channel-major.
#[derive(Clone, Debug, PartialEq)]
pub struct Planes {
    pub c: usize,
    pub h: usize,
    pub w: usize,
    pub data: Vec<f32>,
}

impl Planes {
    /// Mirror-pads (half-sample symmetric, as the Wiener bank pads; any size) at the
    /// bottom and right to `h2 × w2`.
    pub fn padded(&self, h2: usize, w2: usize) -> Planes {
        let mut data = Vec::with_capacity(self.c * h2 * w2);
        for p in 0..self.c {
            let plane = &self.data[p * self.h * self.w..(p + 1) * self.h * self.w];
            for y in 0..h2 {
                let sy = reflect(y as isize, self.h);
                data.extend((0..w2).map(|x| plane[sy * self.w + reflect(x as isize, self.w)]));
            }
        }
        Planes {
            c: self.c,
            h: h2,
            w: w2,
            data,
        }
    }

    /// The `th × tw` window at `(y0, x0)`.
    pub fn window(&self, y0: usize, x0: usize, th: usize, tw: usize) -> Planes {
        let mut data = Vec::with_capacity(self.c * th * tw);
        for p in 0..self.c {
            for y in y0..y0 + th {
                let row = (p * self.h + y) * self.w;
                data.extend_from_slice(&self.data[row + x0..row + x0 + tw]);
            }
        }
        Planes {
            c: self.c,
            h: th,
            w: tw,
            data,
        }
    }

    /// The top-left `h2 × w2` corner.
    pub fn cropped(&self, h2: usize, w2: usize) -> Planes {
        self.window(0, 0, h2, w2)
    }
}

/// Rounds up to a multiple of `m`.
pub fn round_up(n: usize, m: usize) -> usize {
    n.div_ceil(m) * m
}

/// Tile starts along an axis of length `n`: tiles of `t` overlapping by at least `overlap`,
/// the last one flush with the end.
pub fn starts(n: usize, t: usize, overlap: usize) -> Vec<usize> {
    if n <= t {
        return vec![0];
    }
    let step = (t - overlap).max(1);
    let mut v: Vec<usize> = (0..).map(|i| i * step).take_while(|&s| s + t < n).collect();
    v.push(n - t);
    v
}

/// Blend weight along one axis of a tile at `start` of size `t` in an axis of length `n`:
/// a linear ramp over `overlap` pixels on sides shared with another tile, 1 elsewhere.
fn ramp(i: usize, start: usize, t: usize, n: usize, overlap: usize) -> f32 {
    let mut w = 1.0f32;
    if overlap > 0 {
        if start > 0 {
            w = w.min((i as f32 + 0.5) / overlap as f32);
        }
        if start + t < n {
            w = w.min(((t - i) as f32 - 0.5) / overlap as f32);
        }
    }
    w.clamp(1e-3, 1.0)
}

/// Applies `f` (planes of a tile → 3 planes of the same size) to `x` in tiles of at most
/// `tile × tile` overlapping by `overlap`, blending the results. `x.h`, `x.w` and `tile`
/// must be multiples of what `f` needs.
pub fn tiled<E>(
    x: &Planes,
    tile: usize,
    overlap: usize,
    mut f: impl FnMut(&Planes) -> Result<Planes, E>,
) -> Result<Planes, E> {
    let (th, tw) = (tile.min(x.h), tile.min(x.w));
    if th == x.h && tw == x.w {
        return f(x);
    }
    let (h, w) = (x.h, x.w);
    let mut acc = vec![0.0f32; 3 * h * w];
    let mut wsum = vec![0.0f32; h * w];
    for &y0 in &starts(h, th, overlap) {
        for &x0 in &starts(w, tw, overlap) {
            let out = f(&x.window(y0, x0, th, tw))?;
            for y in 0..th {
                let wy = ramp(y, y0, th, h, overlap);
                for xx in 0..tw {
                    let wt = wy * ramp(xx, x0, tw, w, overlap);
                    let dst = (y0 + y) * w + x0 + xx;
                    wsum[dst] += wt;
                    for c in 0..3 {
                        acc[c * h * w + dst] += wt * out.data[(c * th + y) * tw + xx];
                    }
                }
            }
        }
    }
    for c in 0..3 {
        for (a, s) in acc[c * h * w..(c + 1) * h * w].iter_mut().zip(&wsum) {
            *a /= s;
        }
    }
    Ok(Planes {
        c: 3,
        h,
        w,
        data: acc,
    })
}
