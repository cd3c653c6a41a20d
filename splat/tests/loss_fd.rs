//! L1 / SSIM against an independent float64 brute-force SSIM (direct 2D window) and finite
//! differences.

use base::SplitMix64;
use glam::Vec3;
use splat::loss::{l1, photometric_loss, ssim};

fn random_image(seed: u64, n: usize) -> Vec<Vec3> {
    SplitMix64::new(seed).uniform_rgb(n)
}

/// Brute-force SSIM in f64: direct 11×11 window sums with zero padding.
fn ssim_ref(x: &[f64], y: &[f64], w: usize, h: usize) -> f64 {
    let g: Vec<f64> = (0..11)
        .map(|k| (-((k as f64 - 5.0).powi(2)) / 4.5).exp())
        .collect();
    let sum: f64 = g.iter().sum();
    let g: Vec<f64> = g.iter().map(|v| v / sum).collect();
    let (c1, c2) = (1e-4, 9e-4);
    let mut total = 0.0;
    for ch in 0..3 {
        for py in 0..h as i64 {
            for px in 0..w as i64 {
                let (mut mx, mut my, mut xx, mut yy, mut xy) = (0.0, 0.0, 0.0, 0.0, 0.0);
                for dy in -5..=5i64 {
                    for dx in -5..=5i64 {
                        let (qx, qy) = (px + dx, py + dy);
                        if qx < 0 || qy < 0 || qx >= w as i64 || qy >= h as i64 {
                            continue;
                        }
                        let wt = g[(dx + 5) as usize] * g[(dy + 5) as usize];
                        let i = (qy as usize * w + qx as usize) * 3 + ch;
                        mx += wt * x[i];
                        my += wt * y[i];
                        xx += wt * x[i] * x[i];
                        yy += wt * y[i] * y[i];
                        xy += wt * x[i] * y[i];
                    }
                }
                let (vx, vy, cxy) = (xx - mx * mx, yy - my * my, xy - mx * my);
                total += (2.0 * mx * my + c1) * (2.0 * cxy + c2)
                    / ((mx * mx + my * my + c1) * (vx + vy + c2));
            }
        }
    }
    total / (3 * w * h) as f64
}

fn flat(img: &[Vec3]) -> Vec<f64> {
    img.iter()
        .flat_map(|v| v.to_array())
        .map(f64::from)
        .collect()
}

#[test]
fn ssim_value_and_gradient_match_float64_reference() {
    let (w, h) = (14usize, 12usize);
    for seed in 0..3 {
        let x = random_image(seed, w * h);
        let mut y = random_image(seed + 100, w * h);
        // Correlate the target with the render so SSIM is far from 0.
        for (yi, xi) in y.iter_mut().zip(&x) {
            *yi = *xi * 0.7 + *yi * 0.3;
        }
        let s = ssim(&x, &y, w as u32, h as u32).unwrap();
        let (xf, yf) = (flat(&x), flat(&y));
        let r = ssim_ref(&xf, &yf, w, h);
        assert!(
            (s.value as f64 - r).abs() < 1e-5,
            "value {} vs {r}",
            s.value
        );
        assert!(r > 0.3 && r < 0.99);
        let eps = 1e-6;
        let mut max_g = 0.0f64;
        for k in 0..xf.len() {
            let mut p = xf.clone();
            p[k] += eps;
            let up = ssim_ref(&p, &yf, w, h);
            p[k] -= 2.0 * eps;
            let down = ssim_ref(&p, &yf, w, h);
            let fd = (up - down) / (2.0 * eps);
            let an = s.grad[k / 3][k % 3] as f64;
            max_g = max_g.max(fd.abs());
            assert!(
                (an - fd).abs() <= 1e-3 * fd.abs() + 1e-7,
                "seed {seed} element {k}: analytic {an} fd {fd}"
            );
        }
        assert!(max_g > 1e-4);
    }
}

#[test]
fn ssim_of_identical_images_is_one() {
    let x = random_image(9, 20 * 9);
    let s = ssim(&x, &x, 20, 9).unwrap();
    assert!((s.value - 1.0).abs() < 1e-5);
    assert!(s.grad.iter().all(|g| g.abs().max_element() < 1e-4));
}

#[test]
fn l1_and_photometric_gradients_match_finite_differences() {
    let (w, h) = (9u32, 7u32);
    let x = random_image(1, 63);
    let y = random_image(2, 63);
    let l = l1(&x, &y, w, h).unwrap();
    let direct: f64 = x
        .iter()
        .zip(&y)
        .map(|(a, b)| (*a - *b).abs().element_sum() as f64)
        .sum::<f64>()
        / 189.0;
    assert!((l.value as f64 - direct).abs() < 1e-6);
    let p = photometric_loss(&x, &y, w, h, 0.2).unwrap();
    assert!((p.value - (0.8 * p.l1 + 0.2 * (1.0 - p.ssim))).abs() < 1e-6);
    // Its gradient is the two gradients mixed, to the bit.
    let s = ssim(&x, &y, w, h).unwrap();
    let mixed: Vec<Vec3> = l
        .grad
        .iter()
        .zip(&s.grad)
        .map(|(a, b)| *a * 0.8 - *b * 0.2)
        .collect();
    assert_eq!(p.grad, mixed);
    assert_eq!(p.l1, l.value);
    let (xf, yf) = (flat(&x), flat(&y));
    let loss = |v: &[f64]| {
        let l1: f64 = v.iter().zip(&yf).map(|(a, b)| (a - b).abs()).sum::<f64>() / 189.0;
        0.8 * l1 + 0.2 * (1.0 - ssim_ref(v, &yf, w as usize, h as usize))
    };
    for k in 0..xf.len() {
        let eps = 1e-6;
        let mut v = xf.clone();
        v[k] += eps;
        let up = loss(&v);
        v[k] -= 2.0 * eps;
        let fd = (up - loss(&v)) / (2.0 * eps);
        let an = p.grad[k / 3][k % 3] as f64;
        assert!(
            (an - fd).abs() < 1e-3 * fd.abs() + 1e-6,
            "{k}: {an} vs {fd}"
        );
    }
}

#[test]
fn loss_size_mismatch_is_an_error() {
    let x = random_image(1, 10);
    assert!(ssim(&x, &x, 3, 3).is_err());
    assert!(l1(&x, &x[..9], 3, 3).is_err());
}

/// The loss value and gradient do not depend on the thread count, and the value is the plain
/// float64 mean absolute difference.
#[test]
fn l1_is_the_same_for_any_thread_count() {
    let (w, h) = (150, 97);
    let (a, b) = (random_image(11, w * h), random_image(12, w * h));
    let run = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| photometric_loss(&a, &b, w as u32, h as u32, 0.2).unwrap())
    };
    let one = run(1);
    for threads in [2, 3] {
        let other = run(threads);
        assert_eq!(
            one.value.to_bits(),
            other.value.to_bits(),
            "{threads} threads"
        );
        assert_eq!(one.l1.to_bits(), other.l1.to_bits(), "{threads} threads");
        assert!(one.grad == other.grad, "{threads} threads");
    }
    let exact = flat(&a)
        .iter()
        .zip(flat(&b))
        .map(|(x, y)| (x - y).abs())
        .sum::<f64>()
        / (3 * w * h) as f64;
    assert!(
        ((one.l1 as f64 - exact) / exact).abs() < 1e-6,
        "{} vs {exact}",
        one.l1
    );
}
