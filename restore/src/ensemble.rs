//! Self-ensemble: the network run on the Wiener bank mirrored and turned, each answer turned
//! back and the answers averaged. A metalens is rotationally symmetric, so a mirrored or
//! turned photo is one the same lens could have taken; the network is not exactly equivariant,
//! and the mean of its answers has less error than any one (the "+" figures of restoration
//! papers). It costs one network pass per member.

use aberration::Image;

/// One of the square's eight symmetries: transpose (swap x and y) first, then mirror
/// left-right and/or top-bottom.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Symmetry {
    pub transpose: bool,
    pub mirror_x: bool,
    pub mirror_y: bool,
}

/// The members of an ensemble of `n` (1, 2, 4 or 8), in the order they are added: the
/// identity, the left-right mirror, the half turn, the top-bottom mirror, then the four that
/// transpose. Two and four members keep the photo's orientation (no tile shape changes).
pub fn members(n: usize) -> &'static [Symmetry] {
    const fn s(transpose: bool, mirror_x: bool, mirror_y: bool) -> Symmetry {
        Symmetry {
            transpose,
            mirror_x,
            mirror_y,
        }
    }
    const ALL: [Symmetry; 8] = [
        s(false, false, false),
        s(false, true, false),
        s(false, true, true),
        s(false, false, true),
        s(true, false, false),
        s(true, true, false),
        s(true, true, true),
        s(true, false, true),
    ];
    &ALL[..n.clamp(1, 8)]
}

/// The ensemble sizes [`members`] serves.
pub const SIZES: [usize; 4] = [1, 2, 4, 8];

impl Symmetry {
    /// Where pixel (x, y) of a `w`×`h` image goes, and the transformed image's size.
    fn map(&self, x: usize, y: usize, w: usize, h: usize) -> (usize, usize, usize, usize) {
        let (mut u, mut v, tw, th) = if self.transpose {
            (y, x, h, w)
        } else {
            (x, y, w, h)
        };
        if self.mirror_x {
            u = tw - 1 - u;
        }
        if self.mirror_y {
            v = th - 1 - v;
        }
        (u, v, tw, th)
    }

    /// For each pixel of a `w`×`h` image, its index there and in the transformed image
    /// (the same within every colour plane).
    fn index_pairs(&self, w: usize, h: usize) -> impl Iterator<Item = (usize, usize)> + '_ {
        (0..h).flat_map(move |y| {
            (0..w).map(move |x| {
                let (u, v, tw, _) = self.map(x, y, w, h);
                (y * w + x, v * tw + u)
            })
        })
    }

    /// `img` transformed.
    pub fn apply(&self, img: &Image) -> Image {
        let (w, h) = (img.width, img.height);
        let (_, _, tw, th) = self.map(0, 0, w, h);
        let mut out = Image::new(tw, th);
        for (dst, src) in out
            .data
            .chunks_exact_mut(w * h)
            .zip(img.data.chunks_exact(w * h))
        {
            for (a, b) in self.index_pairs(w, h) {
                dst[b] = src[a];
            }
        }
        out
    }

    /// The inverse of [`Self::apply`]: `img` is a transformed `w`×`h` image.
    pub fn undo(&self, img: &Image, w: usize, h: usize) -> Image {
        let mut out = Image::new(w, h);
        for (dst, src) in out
            .data
            .chunks_exact_mut(w * h)
            .zip(img.data.chunks_exact(w * h))
        {
            for (a, b) in self.index_pairs(w, h) {
                dst[a] = src[b];
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ramp(w: usize, h: usize) -> Image {
        Image::from_fn(w, h, |x, y| {
            [x as f32, y as f32 * 100.0, (x * 7 + y * 13) as f32]
        })
    }

    #[test]
    fn every_symmetry_is_undone_and_the_eight_are_distinct() {
        let img = ramp(5, 3);
        let mut seen: Vec<Vec<f32>> = Vec::new();
        for s in members(8) {
            let t = s.apply(&img);
            let turned = s.transpose;
            assert_eq!((t.width, t.height), if turned { (3, 5) } else { (5, 3) });
            assert_eq!(s.undo(&t, 5, 3).data, img.data);
            assert!(!seen.contains(&t.data), "{s:?} repeats another member");
            seen.push(t.data);
        }
    }

    #[test]
    fn the_mirrors_and_transpose_move_pixels_where_they_say() {
        let img = ramp(4, 2);
        let m = members(8);
        // Left-right mirror: (0, 0) takes (3, 0).
        assert_eq!(m[1].apply(&img).get(0, 0, 0), 3.0);
        // Half turn: (0, 0) takes (3, 1).
        let h = m[2].apply(&img);
        assert_eq!((h.get(0, 0, 0), h.get(0, 0, 1)), (3.0, 100.0));
        // Transpose: (1, 3) takes (3, 1).
        let t = m[4].apply(&img);
        assert_eq!((t.get(1, 3, 0), t.get(1, 3, 1)), (3.0, 100.0));
        assert_eq!(members(0).len(), 1);
        assert_eq!(members(4).len(), 4);
        assert!(members(4).iter().all(|s| !s.transpose));
    }
}
