//! Two-dimensional real FFTs in f32 on top of realfft/rustfft, for the convolutions of the
//! blur and the Wiener filters.
//!
//! The spectrum is stored transposed, `spec[k * rows + r]` with `k` the column frequency
//! (`cols / 2 + 1` of them), because the column pass then runs on contiguous memory.

use realfft::{ComplexToReal, RealFftPlanner, RealToComplex};
use rustfft::num_complex::Complex32;
use rustfft::{Fft, FftPlanner};
use std::ops::Range;
use std::sync::Arc;

/// Smallest even length >= `n` whose prime factors are all in {2, 3, 5, 7}: the lengths
/// rustfft handles with its fast butterflies, and even so realfft takes its fast path.
pub fn fast_len(n: usize) -> usize {
    let mut m = n.max(2);
    loop {
        if m.is_multiple_of(2) {
            let mut r = m;
            for p in [2, 3, 5, 7] {
                while r.is_multiple_of(p) {
                    r /= p;
                }
            }
            if r == 1 {
                return m;
            }
        }
        m += 1;
    }
}

/// A planned 2-D real transform of a `rows x cols` buffer.
pub struct RealFft2 {
    pub rows: usize,
    pub cols: usize,
    r2c: Arc<dyn RealToComplex<f32>>,
    c2r: Arc<dyn ComplexToReal<f32>>,
    col_fwd: Arc<dyn Fft<f32>>,
    col_inv: Arc<dyn Fft<f32>>,
}

/// Per-thread working memory for [`RealFft2`].
pub struct Fft2Scratch {
    row_in: Vec<f32>,
    row_spec: Vec<Complex32>,
    r2c: Vec<Complex32>,
    c2r: Vec<Complex32>,
    col: Vec<Complex32>,
}

impl RealFft2 {
    pub fn new(rows: usize, cols: usize) -> Self {
        let mut rp = RealFftPlanner::<f32>::new();
        let mut cp = FftPlanner::<f32>::new();
        Self {
            rows,
            cols,
            r2c: rp.plan_fft_forward(cols),
            c2r: rp.plan_fft_inverse(cols),
            col_fwd: cp.plan_fft_forward(rows),
            col_inv: cp.plan_fft_inverse(rows),
        }
    }

    /// Number of column frequencies kept by the real transform.
    pub fn freq_cols(&self) -> usize {
        self.cols / 2 + 1
    }

    pub fn spectrum_len(&self) -> usize {
        self.freq_cols() * self.rows
    }

    pub fn scratch(&self) -> Fft2Scratch {
        Fft2Scratch {
            row_in: vec![0.0; self.cols],
            row_spec: vec![Complex32::ZERO; self.freq_cols()],
            r2c: vec![Complex32::ZERO; self.r2c.get_scratch_len()],
            c2r: vec![Complex32::ZERO; self.c2r.get_scratch_len()],
            col: vec![
                Complex32::ZERO;
                self.col_fwd
                    .get_inplace_scratch_len()
                    .max(self.col_inv.get_inplace_scratch_len())
            ],
        }
    }

    /// Forward transform. `input(r, row)` fills row `r` (length `cols`) for the rows in
    /// `nonzero`; all other rows are known to be zero and cost nothing.
    pub fn forward(
        &self,
        nonzero: Range<usize>,
        mut input: impl FnMut(usize, &mut [f32]),
        spec: &mut [Complex32],
        s: &mut Fft2Scratch,
    ) {
        let nc = self.freq_cols();
        let rows = self.rows;
        debug_assert_eq!(spec.len(), nc * rows);
        spec.fill(Complex32::ZERO);
        for r in nonzero {
            input(r, &mut s.row_in);
            let out = &mut s.row_spec[..nc];
            self.r2c
                .process_with_scratch(&mut s.row_in, out, &mut s.r2c)
                .expect("realfft forward lengths are fixed by the plan");
            for (k, v) in out.iter().enumerate() {
                spec[k * rows + r] = *v;
            }
        }
        self.col_fwd.process_with_scratch(spec, &mut s.col);
    }

    /// Inverse transform (unnormalised: the caller folds `1 / (rows * cols)` into its
    /// kernel). `output(r, row)` receives each row in `needed`; the others are not computed.
    /// `spec` is used as working memory.
    pub fn inverse(
        &self,
        spec: &mut [Complex32],
        needed: Range<usize>,
        mut output: impl FnMut(usize, &[f32]),
        s: &mut Fft2Scratch,
    ) {
        let nc = self.freq_cols();
        let rows = self.rows;
        self.col_inv.process_with_scratch(spec, &mut s.col);
        for r in needed {
            let row = &mut s.row_spec[..nc];
            for (k, v) in row.iter_mut().enumerate() {
                *v = spec[k * rows + r];
            }
            // The product of two real signals' spectra is Hermitian; roundoff leaves a tiny
            // imaginary part on the self-conjugate bins that realfft rejects.
            row[0].im = 0.0;
            if self.cols.is_multiple_of(2) {
                row[nc - 1].im = 0.0;
            }
            self.c2r
                .process_with_scratch(row, &mut s.row_in, &mut s.c2r)
                .expect("imaginary parts of self-conjugate bins were zeroed");
            output(r, &s.row_in);
        }
    }

    /// Spectrum of a `k x k` kernel, scaled by `1 / (rows * cols)` so that
    /// `inverse(forward(x) * spectrum)` is a plain circular convolution. With `centred`, the
    /// kernel's centre pixel `(k / 2, k / 2)` goes to index (0, 0) (ifftshift), otherwise its
    /// first pixel does.
    pub fn kernel_spectrum(&self, kernel: &[f32], k: usize, centred: bool) -> Vec<Complex32> {
        let mut spec = vec![Complex32::ZERO; self.spectrum_len()];
        let mut s = self.scratch();
        let shift = if centred { k / 2 } else { 0 };
        let (rows, cols) = (self.rows, self.cols);
        let scale = 1.0 / (rows * cols) as f32;
        // Wrap-accumulate, so a kernel larger than the buffer aliases instead of being cut.
        let mut dense = vec![0.0f32; rows * cols];
        for ky in 0..k {
            let r = (ky + rows * k - shift) % rows;
            for kx in 0..k {
                let c = (kx + cols * k - shift) % cols;
                dense[r * cols + c] += kernel[ky * k + kx] * scale;
            }
        }
        self.forward(
            0..rows,
            |r, row| row.copy_from_slice(&dense[r * cols..(r + 1) * cols]),
            &mut spec,
            &mut s,
        );
        spec
    }
}
