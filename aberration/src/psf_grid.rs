//! A G×G grid of per-channel PSFs over the sensor, and its file format.
//!
//! On disk the grid uses the paper's layout: a NumPy `.npy` float32 array of shape
//! `(G·G, K, K, 3)`, grid points row-major (row = image y, top first), each PSF indexed
//! `[y][x][channel]`. In memory each (grid point, channel) kernel is a contiguous `K×K`
//! block, which is what the convolutions want.

use crate::error::{AberrationError, Result};
use std::path::Path;

/// The most negative energy a PSF may hold, as a fraction of its positive energy. Measured PSFs
/// carry small negative noise after background subtraction; up to this much is clamped to
/// zero (with a warning when read from a file) before normalising, more is refused as not a
/// PSF.
pub const MAX_NEGATIVE_FRACTION: f64 = 0.01;

#[derive(Clone, Debug, PartialEq)]
pub struct PsfGrid {
    grid: usize,
    size: usize,
    /// `((g * 3 + c) * size + y) * size + x`.
    data: Vec<f32>,
}

impl PsfGrid {
    /// Builds a grid from planar kernels (`[(g*3 + c)][y][x]`), validating and normalising
    /// every kernel to unit sum. Small negative values (background-subtraction noise, see
    /// [`MAX_NEGATIVE_FRACTION`]) are clamped to zero; more is an error.
    pub fn from_planar(grid: usize, size: usize, data: Vec<f32>) -> Result<Self> {
        Self::from_planar_counting(grid, size, data).map(|(g, _)| g)
    }

    /// [`Self::from_planar`], also returning how many negative values were clamped.
    fn from_planar_counting(grid: usize, size: usize, data: Vec<f32>) -> Result<(Self, usize)> {
        if grid == 0 || size == 0 {
            return Err(AberrationError::BadPsf(format!(
                "grid {grid} and size {size} must both be positive"
            )));
        }
        if data.len() != grid * grid * 3 * size * size {
            return Err(AberrationError::BadPsf(format!(
                "{} values for a {grid}x{grid} grid of {size}x{size} RGB PSFs (expected {})",
                data.len(),
                grid * grid * 3 * size * size
            )));
        }
        let mut g = Self { grid, size, data };
        let clamped = g.normalise()?;
        Ok((g, clamped))
    }

    /// Builds a grid from the file layout `(G·G, K, K, 3)`.
    pub fn from_interleaved(grid: usize, size: usize, hwc: &[f32]) -> Result<Self> {
        Self::from_interleaved_counting(grid, size, hwc).map(|(g, _)| g)
    }

    fn from_interleaved_counting(grid: usize, size: usize, hwc: &[f32]) -> Result<(Self, usize)> {
        let kk = size * size;
        if hwc.len() != grid * grid * kk * 3 {
            return Err(AberrationError::BadPsf(format!(
                "{} values for a {grid}x{grid} grid of {size}x{size} RGB PSFs",
                hwc.len()
            )));
        }
        let mut data = vec![0.0; hwc.len()];
        for g in 0..grid * grid {
            for i in 0..kk {
                for c in 0..3 {
                    data[(g * 3 + c) * kk + i] = hwc[(g * kk + i) * 3 + c];
                }
            }
        }
        Self::from_planar_counting(grid, size, data)
    }

    /// The same PSF at every grid point (a spatially invariant blur).
    pub fn uniform(grid: usize, size: usize, kernels: [&[f32]; 3]) -> Result<Self> {
        let mut data = Vec::with_capacity(grid * grid * 3 * size * size);
        for _ in 0..grid * grid {
            for k in kernels {
                data.extend_from_slice(k);
            }
        }
        Self::from_planar(grid, size, data)
    }

    /// A grid of identity (delta) PSFs.
    pub fn delta(grid: usize, size: usize) -> Self {
        let mut k = vec![0.0; size * size];
        k[(size / 2) * size + size / 2] = 1.0;
        Self::uniform(grid, size, [&k, &k, &k]).expect("a delta is a valid PSF")
    }

    /// Checks and normalises every kernel; returns how many negative values were clamped.
    fn normalise(&mut self) -> Result<usize> {
        let kk = self.size * self.size;
        let mut clamped = 0;
        for (i, kernel) in self.data.chunks_mut(kk).enumerate() {
            let (g, c) = (i / 3, i % 3);
            if let Some(bad) = kernel.iter().find(|v| !v.is_finite()) {
                return Err(AberrationError::BadPsf(format!(
                    "PSF {g} channel {c} contains a non-finite value ({bad})"
                )));
            }
            let positive: f64 = kernel.iter().map(|v| v.max(0.0) as f64).sum();
            let negative: f64 = kernel.iter().map(|v| v.min(0.0) as f64).sum();
            if positive <= 0.0 {
                return Err(AberrationError::BadPsf(format!(
                    "PSF {g} channel {c} sums to {}; a PSF must have positive total energy",
                    positive + negative
                )));
            }
            if -negative > MAX_NEGATIVE_FRACTION * positive {
                return Err(AberrationError::BadPsf(format!(
                    "PSF {g} channel {c} has negative values summing to {:.3}% of its positive \
                     energy; at most {}% (background-subtraction noise) is accepted",
                    -negative / positive * 100.0,
                    MAX_NEGATIVE_FRACTION * 100.0
                )));
            }
            for v in kernel.iter_mut().filter(|v| **v < 0.0) {
                *v = 0.0;
                clamped += 1;
            }
            let sum = positive;
            // Already-normalised kernels are left bit-exact, so a file round trip is too.
            if (sum - 1.0).abs() > 1e-6 {
                let inv = (1.0 / sum) as f32;
                kernel.iter_mut().for_each(|v| *v *= inv);
            }
        }
        Ok(clamped)
    }

    pub fn grid(&self) -> usize {
        self.grid
    }

    /// PSF side length K in pixels.
    pub fn size(&self) -> usize {
        self.size
    }

    /// The sensor this grid is defined for: `G·K` pixels square (the paper: 9·135 = 1215),
    /// i.e. each grid cell is exactly one PSF wide at native resolution.
    pub fn native_sensor_px(&self) -> usize {
        self.grid * self.size
    }

    /// Kernel of grid point `g` (row-major) and channel `c`, `K×K` row-major.
    pub fn kernel(&self, g: usize, c: usize) -> &[f32] {
        let kk = self.size * self.size;
        &self.data[(g * 3 + c) * kk..(g * 3 + c + 1) * kk]
    }

    pub fn planar(&self) -> &[f32] {
        &self.data
    }

    /// The file layout `(G·G, K, K, 3)`.
    pub fn to_interleaved(&self) -> Vec<f32> {
        let kk = self.size * self.size;
        let mut out = vec![0.0; self.data.len()];
        for g in 0..self.grid * self.grid {
            for c in 0..3 {
                let k = self.kernel(g, c);
                for i in 0..kk {
                    out[(g * kk + i) * 3 + c] = k[i];
                }
            }
        }
        out
    }

    /// Reads the paper's `psf.npy` layout. float32 and float64 are accepted; anything else,
    /// a shape that is not `(G·G, K, K, 3)`, a shape whose data exceeds
    /// [`base::limits::MAX_NPY_BYTES`] or the bytes the file holds, non-finite values or a
    /// zero-sum PSF is an error naming the file. Sizes are checked before anything is
    /// allocated (see [`base::npy`]).
    pub fn load_npy(path: &Path) -> Result<Self> {
        let bad = |problem: String| AberrationError::BadPsfFile {
            path: path.to_path_buf(),
            problem,
        };
        let npy = base::npy::read_f32(path).map_err(|e| match e {
            base::npy::NpyError::Io { path, source } => AberrationError::Io { path, source },
            other => AberrationError::BadNpy(other),
        })?;
        let shape = &npy.shape;
        if npy.fortran {
            return Err(bad("Fortran-ordered arrays are not supported".into()));
        }
        if shape.len() != 4 || shape[3] != 3 || shape[1] != shape[2] || shape[1] == 0 {
            return Err(bad(format!(
                "shape {shape:?}; expected (G*G, K, K, 3) with square K x K PSFs"
            )));
        }
        // The data size was checked against the file, so these fit in memory already.
        let gg = shape[0] as usize;
        let grid = gg.isqrt();
        if grid == 0 || grid * grid != gg {
            return Err(bad(format!(
                "{gg} PSFs do not form a square grid (first axis must be G*G)"
            )));
        }
        let size = shape[1] as usize;
        let (psf, clamped) = Self::from_interleaved_counting(grid, size, &npy.values)
            .map_err(|e| bad(e.to_string()))?;
        if clamped > 0 {
            eprintln!(
                "warning: {}: {clamped} small negative PSF values (within {}% of each PSF's \
                 energy) clamped to zero",
                path.display(),
                MAX_NEGATIVE_FRACTION * 100.0
            );
        }
        Ok(psf)
    }

    /// Writes the paper's layout atomically (temporary file renamed into place).
    pub fn save_npy(&self, path: &Path) -> Result<()> {
        use npyz::WriterBuilder;
        let shape = [
            (self.grid * self.grid) as u64,
            self.size as u64,
            self.size as u64,
            3,
        ];
        let values = self.to_interleaved();
        base::write_atomically(path, |buf| {
            let mut w = npyz::WriteOptions::new()
                .default_dtype()
                .shape(&shape)
                .writer(buf)
                .begin_nd()?;
            w.extend(values.iter().copied())?;
            w.finish()
        })
        .map_err(|e| AberrationError::io(path, e))
    }
}
