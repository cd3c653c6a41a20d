//! The FFT blur against a direct spatially varying convolution, its adjoint identity, and
//! hard cases.

mod reference;

use aberration::blur::layout::AxisLayout;
use aberration::{BlurMode, BlurPlan, Image, PsfGrid};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn random_image(w: usize, h: usize, seed: u64) -> Image {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut img = Image::new(w, h);
    img.data.iter_mut().for_each(|v| *v = rng.random::<f32>());
    img
}

/// A grid of random, asymmetric positive PSFs (unit sum after loading).
fn random_psf(g: usize, k: usize, seed: u64) -> PsfGrid {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let data = (0..g * g * 3 * k * k)
        .map(|_| rng.random::<f32>() + 0.01)
        .collect();
    PsfGrid::from_planar(g, k, data).unwrap()
}

fn max_abs_diff(a: &[f32], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (*x as f64 - y).abs())
        .fold(0.0, f64::max)
}

fn check_against_direct(w: usize, h: usize, g: usize, k: usize, mode: BlurMode, seed: u64) {
    let x = random_image(w, h, seed);
    let psf = random_psf(g, k, seed + 1);
    let plan = BlurPlan::new(&psf, w, h, mode).unwrap();
    let y = plan.apply(&x).unwrap();
    let reference = reference::direct(&x, &psf, mode == BlurMode::Tiled);
    let err = max_abs_diff(&y.data, &reference);
    assert!(
        err <= 1e-5,
        "{mode} {w}x{h} G={g} K={k}: max error {err:e} against the direct convolution"
    );
}

#[test]
fn blend_matches_direct_convolution() {
    check_against_direct(37, 29, 3, 7, BlurMode::Blend, 1);
    check_against_direct(45, 36, 9, 9, BlurMode::Blend, 2);
    check_against_direct(16, 24, 2, 6, BlurMode::Blend, 3); // even PSF size
}

#[test]
fn tiled_matches_direct_convolution() {
    check_against_direct(37, 29, 3, 7, BlurMode::Tiled, 4);
    check_against_direct(45, 36, 9, 9, BlurMode::Tiled, 5);
    check_against_direct(16, 24, 2, 6, BlurMode::Tiled, 6);
}

fn dot(a: &[f32], b: &[f32]) -> f64 {
    a.iter().zip(b).map(|(x, y)| *x as f64 * *y as f64).sum()
}

fn norm(a: &[f32]) -> f64 {
    dot(a, a).sqrt()
}

#[test]
fn adjoint_identity_holds_for_both_modes() {
    for (mode, w, h, g, k) in [
        (BlurMode::Blend, 41, 33, 3, 11),
        (BlurMode::Tiled, 41, 33, 3, 11),
        (BlurMode::Blend, 60, 45, 9, 15),
        (BlurMode::Tiled, 60, 45, 9, 15),
        (BlurMode::Blend, 7, 5, 3, 13), // image smaller than the PSF
        (BlurMode::Tiled, 7, 5, 3, 13),
    ] {
        let psf = random_psf(g, k, 10);
        let plan = BlurPlan::new(&psf, w, h, mode).unwrap();
        let x = random_image(w, h, 11);
        let yv = random_image(w, h, 12);
        let ax = plan.apply(&x).unwrap();
        let aty = plan.adjoint(&yv).unwrap();
        let lhs = dot(&ax.data, &yv.data);
        let rhs = dot(&x.data, &aty.data);
        let tol = 1e-5 * norm(&ax.data) * norm(&yv.data);
        assert!(
            (lhs - rhs).abs() <= tol,
            "{mode} {w}x{h}: <Ax,y> = {lhs}, <x,A'y> = {rhs}, tolerance {tol:e}"
        );
    }
}

#[test]
fn adjoint_matches_transpose_of_direct_operator() {
    // Column j of A is A e_j; row j of Aᵀ y must be ⟨A e_j, y⟩ for every j.
    let (w, h, g, k) = (9, 7, 3, 5);
    for mode in [BlurMode::Blend, BlurMode::Tiled] {
        let psf = random_psf(g, k, 20);
        let plan = BlurPlan::new(&psf, w, h, mode).unwrap();
        let yv = random_image(w, h, 21);
        let aty = plan.adjoint(&yv).unwrap();
        for j in 0..3 * w * h {
            let mut e = Image::new(w, h);
            e.data[j] = 1.0;
            let col = reference::direct(&e, &psf, mode == BlurMode::Tiled);
            let expect: f64 = col.iter().zip(&yv.data).map(|(a, b)| a * *b as f64).sum();
            assert!(
                (aty.data[j] as f64 - expect).abs() < 1e-5,
                "{mode}: adjoint entry {j} is {} but the direct transpose gives {expect}",
                aty.data[j]
            );
        }
    }
}

#[test]
fn delta_psf_is_identity_and_constants_are_preserved() {
    for mode in [BlurMode::Blend, BlurMode::Tiled] {
        let x = random_image(31, 22, 30);
        let plan = BlurPlan::new(&PsfGrid::delta(3, 9), 31, 22, mode).unwrap();
        let y = plan.apply(&x).unwrap();
        let err = max_abs_diff(
            &y.data,
            &x.data.iter().map(|v| *v as f64).collect::<Vec<_>>(),
        );
        assert!(err < 1e-6, "{mode}: delta PSF changed the image by {err:e}");
        // Unit-sum PSFs with reflective borders keep white white and black black. Blend
        // spreads each input pixel with its interpolated PSF (energy-conserving), so it keeps
        // constants only where neighbouring PSFs agree: give it one PSF everywhere.
        let psf = match mode {
            BlurMode::Tiled => random_psf(3, 9, 31),
            BlurMode::Blend => {
                let one = random_psf(1, 9, 31);
                PsfGrid::uniform(3, 9, [one.kernel(0, 0), one.kernel(0, 1), one.kernel(0, 2)])
                    .unwrap()
            }
        };
        let plan = BlurPlan::new(&psf, 31, 22, mode).unwrap();
        for level in [0.0f32, 1.0] {
            let y = plan.apply(&Image::filled(31, 22, [level; 3])).unwrap();
            let err = y.data.iter().map(|v| (v - level).abs()).fold(0.0, f32::max);
            assert!(
                err < 1e-5,
                "{mode}: constant {level} image drifted by {err:e}"
            );
        }
    }
}

#[test]
fn tiny_and_odd_images_stay_finite_and_exact() {
    for (w, h) in [(1, 1), (1, 7), (6, 1), (3, 2), (13, 4)] {
        for mode in [BlurMode::Blend, BlurMode::Tiled] {
            let x = random_image(w, h, 40);
            let psf = random_psf(9, 15, 41);
            let plan = BlurPlan::new(&psf, w, h, mode).unwrap();
            let y = plan.apply(&x).unwrap();
            assert!(y.is_finite(), "{mode} {w}x{h}: non-finite output");
            let reference = reference::direct(&x, &psf, mode == BlurMode::Tiled);
            let err = max_abs_diff(&y.data, &reference);
            assert!(err < 1e-5, "{mode} {w}x{h}: error {err:e} against direct");
            assert!(plan.adjoint(&y).unwrap().is_finite());
        }
    }
}

#[test]
fn wrong_size_and_empty_images_are_errors() {
    let psf = random_psf(3, 5, 50);
    let plan = BlurPlan::new(&psf, 10, 8, BlurMode::Blend).unwrap();
    let err = plan.apply(&Image::new(8, 10)).unwrap_err().to_string();
    assert!(
        err.contains("8x10") && err.contains("10x8"),
        "unhelpful error: {err}"
    );
    assert!(BlurPlan::new(&psf, 0, 8, BlurMode::Tiled).is_err());
}

#[test]
fn tiles_partition_each_axis_like_the_reference() {
    for n in [1, 2, 5, 9, 10, 42, 56, 378, 504] {
        for g in [1, 2, 3, 9] {
            let axis = AxisLayout { n, g };
            let mut covered = 0;
            for i in 0..g {
                for p in axis.tile(i) {
                    assert_eq!(axis.tile_of(p), i, "n={n} g={g} p={p}");
                    assert_eq!(reference::tile(p, n, g), i, "n={n} g={g} p={p}");
                    covered += 1;
                }
            }
            assert_eq!(covered, n, "tiles of n={n} g={g} do not cover the axis");
        }
    }
}

#[test]
fn result_is_bit_identical_for_any_thread_count() {
    let x = random_image(64, 48, 60);
    let psf = random_psf(3, 9, 61);
    for mode in [BlurMode::Blend, BlurMode::Tiled] {
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| {
                let plan = BlurPlan::new(&psf, 64, 48, mode).unwrap();
                (plan.apply(&x).unwrap(), plan.adjoint(&x).unwrap())
            })
        };
        let (a1, b1) = run(1);
        let (a3, b3) = run(3);
        assert!(
            a1.data
                .iter()
                .zip(&a3.data)
                .all(|(p, q)| p.to_bits() == q.to_bits())
        );
        assert!(
            b1.data
                .iter()
                .zip(&b3.data)
                .all(|(p, q)| p.to_bits() == q.to_bits())
        );
    }
}

#[test]
fn pixel_layout_gives_the_planar_results_bit_for_bit() {
    use glam::Vec3;
    let (w, h) = (45, 31);
    let psf = random_psf(3, 7, 11);
    let to_pixels = |img: &Image| -> Vec<Vec3> {
        (0..w * h)
            .map(|i| {
                Vec3::new(
                    img.get(i % w, i / w, 0),
                    img.get(i % w, i / w, 1),
                    img.get(i % w, i / w, 2),
                )
            })
            .collect()
    };
    for mode in [BlurMode::Tiled, BlurMode::Blend] {
        let plan = BlurPlan::new(&psf, w, h, mode).unwrap();
        let x = random_image(w, h, 5);
        let y = random_image(w, h, 6);
        assert_eq!(
            plan.apply_pixels(&to_pixels(&x)).unwrap(),
            to_pixels(&plan.apply(&x).unwrap())
        );
        assert_eq!(
            plan.adjoint_pixels(&to_pixels(&y)).unwrap(),
            to_pixels(&plan.adjoint(&y).unwrap())
        );
        assert!(plan.apply_pixels(&to_pixels(&x)[1..]).is_err());
    }
}

/// `n` times smaller by the area rule, planar, a remainder dropped.
fn area_shrunk(img: &Image, n: usize) -> Image {
    let (w, h) = (img.width / n, img.height / n);
    let mut out = Image::new(w, h);
    for c in 0..3 {
        for y in 0..h {
            for x in 0..w {
                let mut sum = 0.0f64;
                for dy in 0..n {
                    for dx in 0..n {
                        let (sx, sy) = (x * n + dx, y * n + dy);
                        sum += img.data[c * img.width * img.height + sy * img.width + sx] as f64;
                    }
                }
                out.data[c * w * h + y * w + x] = (sum / (n * n) as f64) as f32;
            }
        }
    }
    out
}

/// Coarse-to-fine training blurs shrunk renders through [`ImagingModel::shrunk`]: on a smooth
/// scene that must approximate shrinking the full-size blur, far closer than the full-size
/// PSFs applied to the shrunk image (the wrong scale, which the check would accept if
/// `shrunk` forgot to resample).
#[test]
fn shrunk_model_blurs_as_the_shrunk_blur() {
    use aberration::{ImagingModel, NoiseModel};
    // Gaussian PSFs whose width varies over the field and by colour.
    let (g, k) = (3, 21);
    let mut data = Vec::with_capacity(g * g * 3 * k * k);
    for cell in 0..g * g {
        for c in 0..3 {
            let sigma = 1.5 + 0.4 * cell as f64 / 2.0 + 0.6 * c as f64;
            for y in 0..k {
                for x in 0..k {
                    let (dx, dy) = (x as f64 - 10.0, y as f64 - 10.0);
                    data.push((-(dx * dx + dy * dy) / (2.0 * sigma * sigma)).exp() as f32);
                }
            }
        }
    }
    let psf = PsfGrid::from_planar(g, k, data).unwrap();
    let (w, h) = (98, 75);
    let scene = Image::from_fn(w, h, |x, y| {
        let (u, v) = (x as f32 / w as f32, y as f32 / h as f32);
        [
            0.5 + 0.4 * (6.0 * u + 2.0 * v).sin(),
            0.5 + 0.3 * (5.0 * v).cos() * (3.0 * u).sin(),
            0.4 + 0.3 * u * v,
        ]
    });
    for mode in [BlurMode::Tiled, BlurMode::Blend] {
        let full = ImagingModel::new(&psf, w, h, mode, Some(w), NoiseModel::default()).unwrap();
        for n in [2, 4] {
            let small = full.shrunk(n).unwrap();
            assert_eq!(
                (small.plan().width(), small.plan().height()),
                (w / n, h / n)
            );
            let expected = area_shrunk(&full.blur(&scene).unwrap(), n);
            let shrunk_scene = area_shrunk(&scene, n);
            let got = small.blur(&shrunk_scene).unwrap();
            let wrong = BlurPlan::new(full.psf(), w / n, h / n, mode)
                .unwrap()
                .apply(&shrunk_scene)
                .unwrap();
            let rms = |a: &Image| {
                let s: f64 = a
                    .data
                    .iter()
                    .zip(&expected.data)
                    .map(|(x, y)| ((x - y) as f64).powi(2))
                    .sum();
                (s / a.data.len() as f64).sqrt()
            };
            let (err, wrong_err) = (rms(&got), rms(&wrong));
            assert!(
                err < 0.005 && err * 4.0 < wrong_err,
                "{mode} 1/{n}: RMS {err:.5} against the shrunk blur ({wrong_err:.5} at the full-size PSFs)"
            );
        }
    }
    assert!(
        ImagingModel::new(&psf, w, h, BlurMode::Tiled, Some(w), NoiseModel::default())
            .unwrap()
            .shrunk(0)
            .is_err()
    );
}
