//! Sensor noise: Poisson shot noise plus Gaussian read noise, seeded and reproducible.

use crate::image::Image;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Poisson, StandardNormal};
use rayon::prelude::*;

/// `y = a·Poisson(x / a) + σ_g·N(0, 1)`, clipped to [0, 1]: the variance is `a·x + σ_g²`,
/// the heteroscedastic model of Tseng et al. with the paper's `a = σ_p = 4e-5` and
/// `σ_g = 1e-5`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NoiseModel {
    pub gaussian_sigma: f32,
    pub poisson_scale: f32,
}

impl Default for NoiseModel {
    fn default() -> Self {
        Self {
            gaussian_sigma: 1e-5,
            poisson_scale: 4e-5,
        }
    }
}

impl NoiseModel {
    pub fn none() -> Self {
        Self {
            gaussian_sigma: 0.0,
            poisson_scale: 0.0,
        }
    }

    /// Noisy copy of `img`. Each (channel, row) draws from its own ChaCha stream of `seed`,
    /// so the result is identical for any thread count.
    pub fn apply(&self, img: &Image, seed: u64) -> Image {
        let mut out = img.clone();
        let (w, h) = (img.width, img.height);
        let a = self.poisson_scale as f64;
        let sg = self.gaussian_sigma as f64;
        out.data
            .par_chunks_mut(w)
            .enumerate()
            .for_each(|(row, values)| {
                let mut rng = ChaCha8Rng::seed_from_u64(seed);
                rng.set_stream(row as u64);
                for v in values.iter_mut() {
                    let x = if v.is_finite() {
                        (*v as f64).max(0.0)
                    } else {
                        0.0
                    };
                    let mut y = x;
                    if a > 0.0 && x > 0.0 {
                        let lambda = x / a;
                        y = match Poisson::new(lambda) {
                            Ok(p) => a * p.sample(&mut rng),
                            // Beyond rand_distr's limit the Gaussian limit is exact enough.
                            Err(_) => {
                                let n: f64 = StandardNormal.sample(&mut rng);
                                x + (a * x).sqrt() * n
                            }
                        };
                    }
                    if sg > 0.0 {
                        let n: f64 = StandardNormal.sample(&mut rng);
                        y += sg * n;
                    }
                    *v = y.clamp(0.0, 1.0) as f32;
                }
            });
        debug_assert_eq!(out.data.len(), 3 * w * h);
        out
    }
}
