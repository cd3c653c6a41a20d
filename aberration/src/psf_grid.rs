//! A G×G grid of per-channel PSFs over the sensor, and its file format.
//!
//! On disk the grid uses the paper's layout: a NumPy `.npy` float32 array of shape
//! `(G·G, K, K, 3)`, grid points row-major (row = image y, top first), each PSF indexed
//! `[y][x][channel]`. In memory each (grid point, channel) kernel is a contiguous `K×K`
//! block, which is what the convolutions want.

use crate::error::{AberrationError, Result};
use std::path::Path;

#[derive(Clone, Debug, PartialEq)]
pub struct PsfGrid {
    grid: usize,
    size: usize,
    /// `((g * 3 + c) * size + y) * size + x`.
    data: Vec<f32>,
}

impl PsfGrid {
    /// Builds a grid from planar kernels (`[(g*3 + c)][y][x]`), validating and normalising
    /// every kernel to unit sum.
    pub fn from_planar(grid: usize, size: usize, data: Vec<f32>) -> Result<Self> {
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
        g.normalise()?;
        Ok(g)
    }

    /// Builds a grid from the file layout `(G·G, K, K, 3)`.
    pub fn from_interleaved(grid: usize, size: usize, hwc: &[f32]) -> Result<Self> {
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
        Self::from_planar(grid, size, data)
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

    fn normalise(&mut self) -> Result<()> {
        let kk = self.size * self.size;
        for (i, kernel) in self.data.chunks_mut(kk).enumerate() {
            let (g, c) = (i / 3, i % 3);
            if let Some(bad) = kernel.iter().find(|v| !v.is_finite()) {
                return Err(AberrationError::BadPsf(format!(
                    "PSF {g} channel {c} contains a non-finite value ({bad})"
                )));
            }
            let sum: f64 = kernel.iter().map(|v| *v as f64).sum();
            if sum.is_nan() || sum <= 0.0 {
                return Err(AberrationError::BadPsf(format!(
                    "PSF {g} channel {c} sums to {sum}; a PSF must have positive total energy"
                )));
            }
            // Already-normalised kernels are left bit-exact, so a file round trip is too.
            if (sum - 1.0).abs() > 1e-6 {
                let inv = (1.0 / sum) as f32;
                kernel.iter_mut().for_each(|v| *v *= inv);
            }
        }
        Ok(())
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
    /// a shape that is not `(G·G, K, K, 3)`, non-finite values or a zero-sum PSF is an error
    /// naming the file.
    pub fn load_npy(path: &Path) -> Result<Self> {
        let bad = |problem: String| AberrationError::BadPsfFile {
            path: path.to_path_buf(),
            problem,
        };
        let file = std::fs::File::open(path).map_err(|e| AberrationError::io(path, e))?;
        let npy = npyz::NpyFile::new(std::io::BufReader::new(file))
            .map_err(|e| bad(format!("not a readable .npy file ({e})")))?;
        let shape = npy.shape().to_vec();
        if npy.order() != npyz::Order::C {
            return Err(bad("Fortran-ordered arrays are not supported".into()));
        }
        if shape.len() != 4 || shape[3] != 3 || shape[1] != shape[2] || shape[1] == 0 {
            return Err(bad(format!(
                "shape {shape:?}; expected (G*G, K, K, 3) with square K x K PSFs"
            )));
        }
        let gg = shape[0] as usize;
        let grid = (gg as f64).sqrt().round() as usize;
        if grid == 0 || grid * grid != gg {
            return Err(bad(format!(
                "{gg} PSFs do not form a square grid (first axis must be G*G)"
            )));
        }
        let size = shape[1] as usize;
        let dtype = npy.dtype();
        let descr = dtype.descr();
        let values: Vec<f32> = match descr.as_str() {
            "'<f4'" | "'>f4'" => npy
                .into_vec::<f32>()
                .map_err(|e| bad(format!("truncated or unreadable data ({e})")))?,
            "'<f8'" | "'>f8'" => npy
                .into_vec::<f64>()
                .map_err(|e| bad(format!("truncated or unreadable data ({e})")))?
                .into_iter()
                .map(|v| v as f32)
                .collect(),
            other => {
                return Err(bad(format!("dtype {other}; expected float32 (or float64)")));
            }
        };
        Self::from_interleaved(grid, size, &values).map_err(|e| bad(e.to_string()))
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
