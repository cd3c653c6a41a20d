//! Wiener deconvolution: recovery on a well-posed case, the bank's constants, and the
//! K → 0 / spectral-zero hard cases.

use aberration::wiener::{BANK_MEDIAN, BANK_SIZE, K_FLOOR, bank_constants, deconvolve_many};
use aberration::{BlurMode, BlurPlan, Image, PsfGrid, Regularizer, deconvolve, psnr, wiener_bank};
use std::f32::consts::TAU;

/// A smooth, band-limited image: a few low-frequency sinusoids per channel, in [0.1, 0.9].
fn band_limited(w: usize, h: usize) -> Image {
    Image::from_fn(w, h, |x, y| {
        let (x, y) = (x as f32, y as f32);
        std::array::from_fn(|c| {
            let c = c as f32;
            let v = (TAU * (0.031 * x + 0.017 * y) + c).sin()
                + 0.6 * (TAU * (0.052 * x - 0.043 * y) + 2.0 * c).cos()
                + 0.4 * (TAU * 0.07 * y + 0.5 * c).sin();
            0.5 + 0.2 * v
        })
    })
}

fn gaussian_kernel(k: usize, sigma: f32) -> Vec<f32> {
    let c = (k / 2) as f32;
    let mut v: Vec<f32> = (0..k * k)
        .map(|i| {
            let (y, x) = ((i / k) as f32 - c, (i % k) as f32 - c);
            (-(x * x + y * y) / (2.0 * sigma * sigma)).exp()
        })
        .collect();
    let s: f32 = v.iter().sum();
    v.iter_mut().for_each(|a| *a /= s);
    v
}

#[test]
fn tiny_k_recovers_a_band_limited_image() {
    let (w, h) = (96, 72);
    let x = band_limited(w, h);
    let k = gaussian_kernel(9, 0.6);
    let psf = PsfGrid::uniform(3, 9, [&k, &k, &k]).unwrap();
    let y = BlurPlan::new(&psf, w, h, BlurMode::Tiled)
        .unwrap()
        .apply(&x)
        .unwrap();
    let blurred_db = psnr(&y, &x).unwrap();
    let restored = deconvolve(&y, &psf, Regularizer::Fixed(1e-7)).unwrap();
    let restored_db = psnr(&restored, &x).unwrap();
    assert!(
        restored_db >= 40.0,
        "Wiener recovered only {restored_db:.1} dB (blurred {blurred_db:.1} dB)"
    );
}

#[test]
fn bank_constants_are_log_spaced_with_median_at_index_6() {
    let k = bank_constants();
    assert_eq!(k.len(), BANK_SIZE);
    assert!((k[0] - 1e-2).abs() < 1e-8 && (k[12] - 1e-5).abs() < 1e-10);
    assert!((k[BANK_MEDIAN] / 3.1623e-4 - 1.0).abs() < 1e-3);
    for m in 1..BANK_SIZE {
        assert!((k[m - 1] / k[m] - 10f32.powf(0.25)).abs() < 1e-4);
    }
}

#[test]
fn adaptive_k_follows_tile_intensity() {
    // A dark and a bright tile under the same noise: the adaptive filter regularises the
    // dark one more, which matches a fixed filter with K = k·(1 − mean) on each.
    let (w, h) = (40, 20);
    let x = Image::from_fn(w, h, |px, py| {
        let base = if px < 20 { 0.2 } else { 0.8 };
        [base + 0.05 * ((px * 7 + py * 3) % 5) as f32; 3]
    });
    let k = gaussian_kernel(7, 1.0);
    let psf = PsfGrid::uniform(1, 7, [&k, &k, &k]).unwrap();
    let y = BlurPlan::new(&psf, w, h, BlurMode::Tiled)
        .unwrap()
        .apply(&x)
        .unwrap();
    let mean = y.channel(0).iter().map(|v| *v as f64).sum::<f64>() / (w * h) as f64;
    let out = deconvolve_many(
        &y,
        &psf,
        &[
            Regularizer::Adaptive(1e-3),
            Regularizer::Fixed(1e-3 * (1.0 - mean as f32)),
        ],
    )
    .unwrap();
    let diff = out[0]
        .data
        .iter()
        .zip(&out[1].data)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f32::max);
    assert!(diff < 1e-5, "adaptive K does not equal k(1 - c_I): {diff}");
}

#[test]
fn hard_cases_never_produce_nan_or_inf() {
    // A PSF with spectral zeros: a 2-pixel box vanishes at the Nyquist frequency.
    let mut boxk = vec![0.0f32; 25];
    boxk[12] = 0.5;
    boxk[13] = 0.5;
    let box_psf = PsfGrid::uniform(3, 5, [&boxk, &boxk, &boxk]).unwrap();
    let delta = PsfGrid::delta(3, 5);
    let images = [
        Image::filled(24, 18, [0.0; 3]),
        Image::filled(24, 18, [1.0; 3]), // c_I = 1: adaptive K would be 0
        band_limited(24, 18),
        Image::filled(1, 1, [0.5; 3]),
        band_limited(3, 11),
    ];
    for psf in [&box_psf, &delta] {
        for img in &images {
            let bank = wiener_bank(img, psf).unwrap();
            assert_eq!(bank.images.len(), BANK_SIZE);
            for (m, out) in bank.images.iter().enumerate() {
                assert!(
                    out.is_finite(),
                    "bank filter {m} produced non-finite values"
                );
                assert!(
                    out.data.iter().all(|v| (0.0..=1.0).contains(v)),
                    "filter {m} not clamped"
                );
            }
            for kk in [0.0, K_FLOOR / 10.0] {
                assert!(
                    deconvolve(img, psf, Regularizer::Fixed(kk))
                        .unwrap()
                        .is_finite()
                );
            }
        }
    }
    // An image smaller than its PSF.
    let g = gaussian_kernel(15, 2.0);
    let big = PsfGrid::uniform(1, 15, [&g, &g, &g]).unwrap();
    assert!(
        wiener_bank(&band_limited(4, 3), &big)
            .unwrap()
            .median()
            .is_finite()
    );
    // White stays white under a delta PSF even with K at its floor.
    let white = Image::filled(10, 10, [1.0; 3]);
    let out = deconvolve(&white, &delta, Regularizer::Adaptive(1e-3)).unwrap();
    assert!(out.data.iter().all(|v| (v - 1.0).abs() < 1e-4));
}

#[test]
fn negative_or_nan_constants_are_rejected() {
    let img = Image::filled(8, 8, [0.5; 3]);
    let psf = PsfGrid::delta(1, 3);
    assert!(deconvolve(&img, &psf, Regularizer::Fixed(-1.0)).is_err());
    assert!(deconvolve(&img, &psf, Regularizer::Fixed(f32::NAN)).is_err());
}
