//! `∂⟨g, A x⟩/∂PSF` against float64 central differences of the direct convolution, for both
//! blur modes, at kernels of corner, edge and centre grid points, and at kernel values whose
//! input reaches past the image border (where the reflection padding acts).

mod reference;

use aberration::{BlurMode, BlurPlan, Image, PsfGrid};
use glam::Vec3;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn random_image(w: usize, h: usize, rng: &mut ChaCha8Rng) -> Image {
    let mut img = Image::new(w, h);
    img.data.iter_mut().for_each(|v| *v = rng.random::<f32>());
    img
}

fn pixels(img: &Image) -> Vec<Vec3> {
    let n = img.plane_len();
    (0..n)
        .map(|i| Vec3::new(img.data[i], img.data[n + i], img.data[2 * n + i]))
        .collect()
}

/// `⟨g, A(h) x⟩` in f64 for the raw kernel values `h` (planar layout).
fn loss(x: &Image, g: &Image, h: &[f64], grid: usize, k: usize, tiled: bool, ch: usize) -> f64 {
    let kernel = |gi: usize, c: usize, i: usize| h[(gi * 3 + c) * k * k + i];
    let (w, hh) = (x.width, x.height);
    let mut sum = 0.0;
    for py in 0..hh {
        for px in 0..w {
            let y = reference::direct_pixel_with(x, &kernel, grid, k, tiled, py, px, ch);
            sum += y * g.get(px, py, ch) as f64;
        }
    }
    sum
}

fn check(w: usize, h: usize, grid: usize, k: usize, mode: BlurMode, seed: u64) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let x = random_image(w, h, &mut rng);
    // A signed gradient, as a loss gives.
    let mut g = random_image(w, h, &mut rng);
    g.data.iter_mut().for_each(|v| *v = *v * 2.0 - 1.0);
    let data: Vec<f32> = (0..grid * grid * 3 * k * k)
        .map(|_| rng.random::<f32>() + 0.01)
        .collect();
    let psf = PsfGrid::from_planar(grid, k, data).unwrap();
    let plan = BlurPlan::new(&psf, w, h, mode).unwrap();
    let grad = plan.psf_gradient_pixels(&pixels(&x), &pixels(&g)).unwrap();
    assert_eq!(grad.len(), psf.planar().len());
    assert!(grad.iter().all(|v| v.is_finite()));
    let h0: Vec<f64> = psf.planar().iter().map(|v| *v as f64).collect();
    let tiled = mode == BlurMode::Tiled;
    let kk = k * k;
    let centre = (grid / 2) * grid + grid / 2;
    let edge = grid / 2; // top row, middle column
    let last = grid * grid - 1;
    let mut checked = 0;
    let mut worst: f64 = 0.0;
    for gi in [0, edge, centre, last] {
        for ch in 0..3 {
            // Kernel corners reach the image border's reflection; the centre does not.
            for i in [
                0,
                k - 1,
                kk / 2,
                kk - k,
                kk - 1,
                (seed as usize * 7 + gi) % kk,
            ] {
                let idx = (gi * 3 + ch) * kk + i;
                let eps = 1e-3;
                let (mut up, mut down) = (h0.clone(), h0.clone());
                up[idx] += eps;
                down[idx] -= eps;
                let fd = (loss(&x, &g, &up, grid, k, tiled, ch)
                    - loss(&x, &g, &down, grid, k, tiled, ch))
                    / (2.0 * eps);
                let err = (grad[idx] as f64 - fd).abs();
                // f32 FFT rounding grows with the sum's length (pixels of the term).
                let tol = 1e-4 * (1.0 + fd.abs()) + 2e-6 * (w * h) as f64 / (grid * grid) as f64;
                assert!(
                    err <= tol,
                    "{mode} {w}x{h} G={grid} K={k}: PSF {gi} channel {ch} value {i}: {} vs finite difference {fd} (error {err:e})",
                    grad[idx]
                );
                worst = worst.max(err);
                checked += 1;
            }
        }
    }
    assert_eq!(checked, 4 * 3 * 6);
    eprintln!("{mode} {w}x{h} G={grid} K={k}: {checked} values, worst error {worst:e}");
}

#[test]
fn tiled_psf_gradient_matches_finite_differences() {
    check(23, 19, 3, 7, BlurMode::Tiled, 1);
    check(30, 26, 3, 6, BlurMode::Tiled, 2); // even PSF size
    check(8, 9, 3, 5, BlurMode::Tiled, 3); // tiles narrower than the PSF
}

#[test]
fn blend_psf_gradient_matches_finite_differences() {
    check(23, 19, 3, 7, BlurMode::Blend, 4);
    check(30, 26, 3, 6, BlurMode::Blend, 5);
    check(8, 9, 3, 5, BlurMode::Blend, 6);
}

/// The gradient of every value at once, through linearity: `⟨∂/∂h, δ⟩` equals
/// `⟨g, A(h + δ) x⟩ − ⟨g, A(h) x⟩` for any change `δ` of all kernels together, computed by the
/// plan itself, so each grid point's kernel lands where [`PsfGrid::planar`] keeps it.
#[test]
fn psf_gradient_is_the_directional_derivative_of_the_plan() {
    for (mode, seed) in [(BlurMode::Tiled, 10), (BlurMode::Blend, 11)] {
        let (w, h, grid, k) = (40, 33, 4, 9);
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let x = random_image(w, h, &mut rng);
        let mut g = random_image(w, h, &mut rng);
        g.data.iter_mut().for_each(|v| *v -= 0.5);
        let a: Vec<f32> = (0..grid * grid * 3 * k * k)
            .map(|_| rng.random::<f32>() + 0.01)
            .collect();
        let b: Vec<f32> = (0..a.len()).map(|_| rng.random::<f32>() + 0.01).collect();
        let (pa, pb) = (
            PsfGrid::from_planar(grid, k, a).unwrap(),
            PsfGrid::from_planar(grid, k, b).unwrap(),
        );
        let mut plan = BlurPlan::new(&pa, w, h, mode).unwrap();
        let grad = plan.psf_gradient_pixels(&pixels(&x), &pixels(&g)).unwrap();
        let dot = |img: &[Vec3]| -> f64 {
            img.iter()
                .zip(pixels(&g))
                .map(|(a, b)| a.as_dvec3().dot(b.as_dvec3()))
                .sum()
        };
        let ya = dot(&plan.apply_pixels(&pixels(&x)).unwrap());
        plan.set_psf(&pb).unwrap();
        let yb = dot(&plan.apply_pixels(&pixels(&x)).unwrap());
        let predicted: f64 = grad
            .iter()
            .zip(pa.planar().iter().zip(pb.planar()))
            .map(|(d, (a, b))| *d as f64 * (*b as f64 - *a as f64))
            .sum();
        let err = (predicted - (yb - ya)).abs();
        assert!(
            err <= 1e-3 * (yb - ya).abs().max(1e-2),
            "{mode}: gradient predicts a change of {predicted}, the plan gives {}",
            yb - ya
        );
        // And set_psf blurs exactly as a plan made for the new grid.
        let fresh = BlurPlan::new(&pb, w, h, mode).unwrap();
        assert_eq!(
            plan.apply_pixels(&pixels(&x)).unwrap(),
            fresh.apply_pixels(&pixels(&x)).unwrap()
        );
        assert!(plan.set_psf(&PsfGrid::delta(grid + 1, k)).is_err());
        assert!(plan.set_psf(&PsfGrid::delta(grid, k + 2)).is_err());
    }
}
