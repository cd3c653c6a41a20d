//! PSF refinement: the penalties' gradient against float64 finite differences, recovery of a
//! known grid from blurred images, and refusals.

use aberration::refine::{PsfRefiner, RefineSettings, cell_errors, measured};
use aberration::{BlurMode, BlurPlan, PsfGrid};
use glam::Vec3;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Gaussian PSFs whose width grows over the field by `scale` (a lens a little off focus).
fn gaussian_grid(grid: usize, k: usize, scale: f32) -> PsfGrid {
    let c = (k / 2) as f32;
    let mut data = Vec::new();
    for gi in 0..grid * grid {
        let (r, col) = ((gi / grid) as f32, (gi % grid) as f32);
        for ch in 0..3 {
            let sigma = scale * (0.8 + 0.15 * ch as f32 + 0.1 * (r + col));
            for y in 0..k {
                for x in 0..k {
                    let (dy, dx) = (y as f32 - c, x as f32 - c - 0.3 * col);
                    data.push((-(dx * dx + dy * dy) / (2.0 * sigma * sigma)).exp());
                }
            }
        }
    }
    PsfGrid::from_planar(grid, k, data).unwrap()
}

fn random_pixels(n: usize, rng: &mut ChaCha8Rng) -> Vec<Vec3> {
    (0..n)
        .map(|_| Vec3::new(rng.random(), rng.random(), rng.random()))
        .collect()
}

#[test]
fn penalty_gradient_matches_finite_differences() {
    let supplied = gaussian_grid(3, 5, 1.0);
    let settings = RefineSettings {
        lr: 0.05,
        anchor: 0.7,
        smooth: 1.3,
    };
    let mut r = PsfRefiner::new(supplied.clone(), settings).unwrap();
    // Move away from the supplied grid so both penalties are non-zero.
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let g: Vec<f32> = (0..supplied.planar().len())
        .map(|_| rng.random::<f32>() - 0.5)
        .collect();
    for _ in 0..5 {
        r.step(&g).unwrap();
    }
    let (value, grad) = r.penalty();
    assert!(value > 0.0);
    // The penalty as a function of raw values, re-derived from the definition in f64.
    let h: Vec<f64> = r.current().planar().iter().map(|v| *v as f64).collect();
    let h0: Vec<f64> = supplied.planar().iter().map(|v| *v as f64).collect();
    let (grid, kk) = (3usize, 25usize);
    let kernels = grid * grid * 3;
    let energy: Vec<f64> = h0
        .chunks(kk)
        .map(|k| k.iter().map(|v| v * v).sum())
        .collect();
    let mean_e = energy.iter().sum::<f64>() / kernels as f64;
    let f = |h: &[f64]| -> f64 {
        let mut v = 0.0;
        for i in 0..kernels {
            let d: f64 = (0..kk)
                .map(|j| (h[i * kk + j] - h0[i * kk + j]).powi(2))
                .sum();
            v += 0.7 * d / energy[i] / kernels as f64;
        }
        let mut pairs = vec![];
        for a in 0..grid * grid {
            if a % grid + 1 < grid {
                pairs.push((a, a + 1));
            }
            if a / grid + 1 < grid {
                pairs.push((a, a + grid));
            }
        }
        let n = (pairs.len() * 3) as f64;
        for (a, b) in pairs {
            for ch in 0..3 {
                let (ia, ib) = ((a * 3 + ch) * kk, (b * 3 + ch) * kk);
                let d: f64 = (0..kk)
                    .map(|j| ((h[ia + j] - h0[ia + j]) - (h[ib + j] - h0[ib + j])).powi(2))
                    .sum();
                v += 1.3 * d / n / mean_e;
            }
        }
        v
    };
    assert!((f(&h) - value).abs() <= 1e-6 * value.max(1e-12));
    for idx in [0, 12, 24, 25 * 4 + 7, h.len() / 2, h.len() - 1] {
        let eps = 1e-6;
        let (mut up, mut down) = (h.clone(), h.clone());
        up[idx] += eps;
        down[idx] -= eps;
        let fd = (f(&up) - f(&down)) / (2.0 * eps);
        assert!(
            (grad[idx] as f64 - fd).abs() <= 1e-4 * fd.abs().max(1e-3),
            "value {idx}: {} vs finite difference {fd}",
            grad[idx]
        );
    }
}

/// Images blurred by a true grid; refining a wrong one (PSFs 25 % too narrow) from the
/// blurred images and the sharp ones brings it closer to the truth, keeping every kernel
/// non-negative and unit-sum.
#[test]
fn refinement_recovers_a_known_grid_from_blurred_images() {
    let (w, h, grid, k) = (48, 40, 3, 9);
    let truth = gaussian_grid(grid, k, 1.0);
    let wrong = gaussian_grid(grid, k, 0.75);
    for mode in [BlurMode::Tiled, BlurMode::Blend] {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let sharp: Vec<Vec<Vec3>> = (0..4).map(|_| random_pixels(w * h, &mut rng)).collect();
        let true_plan = BlurPlan::new(&truth, w, h, mode).unwrap();
        let observed: Vec<Vec<Vec3>> = sharp
            .iter()
            .map(|x| true_plan.apply_pixels(x).unwrap())
            .collect();
        let settings = RefineSettings {
            lr: 0.05,
            anchor: 1e-4,
            smooth: 1e-4,
        };
        let mut refiner = PsfRefiner::new(wrong.clone(), settings).unwrap();
        let mut plan = BlurPlan::new(&wrong, w, h, mode).unwrap();
        let loss = |plan: &BlurPlan| -> f64 {
            sharp
                .iter()
                .zip(&observed)
                .map(|(x, y)| {
                    let b = plan.apply_pixels(x).unwrap();
                    b.iter()
                        .zip(y)
                        .map(|(a, b)| (*a - *b).length_squared() as f64)
                        .sum::<f64>()
                })
                .sum()
        };
        let before = loss(&plan);
        for step in 0..150 {
            let i = step % sharp.len();
            let blurred = plan.apply_pixels(&sharp[i]).unwrap();
            let residual: Vec<Vec3> = blurred
                .iter()
                .zip(&observed[i])
                .map(|(a, b)| (*a - *b) * (2.0 / (w * h) as f32))
                .collect();
            let grad = plan.psf_gradient_pixels(&sharp[i], &residual).unwrap();
            refiner.step(&grad).unwrap();
            plan.set_psf(refiner.current()).unwrap();
        }
        let after = loss(&plan);
        let e0 = mean(&cell_errors(&wrong, &truth).unwrap());
        let e1 = mean(&cell_errors(refiner.current(), &truth).unwrap());
        assert!(
            e1 < 0.5 * e0,
            "{mode}: refined grid is {e1:.4} from the truth, the supplied one {e0:.4}"
        );
        assert!(after < 0.2 * before, "{mode}: loss {before} -> {after}");
        let kk = k * k;
        for kernel in refiner.current().planar().chunks(kk) {
            assert!(kernel.iter().all(|v| *v >= 0.0 && v.is_finite()));
            let sum: f64 = kernel.iter().map(|v| *v as f64).sum();
            assert!((sum - 1.0).abs() < 1e-5, "kernel sums to {sum}");
        }
        eprintln!("{mode}: cell error {e0:.4} -> {e1:.4}, loss {before:.4e} -> {after:.4e}");
    }
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len() as f64
}

#[test]
fn a_strong_anchor_keeps_the_supplied_grid() {
    let supplied = gaussian_grid(3, 7, 1.0);
    let free = RefineSettings {
        lr: 0.05,
        anchor: 0.0,
        smooth: 0.0,
    };
    let held = RefineSettings {
        anchor: 1e3,
        ..free
    };
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let g: Vec<f32> = (0..supplied.planar().len())
        .map(|_| (rng.random::<f32>() - 0.5) * 1e-3)
        .collect();
    let run = |s: RefineSettings| {
        let mut r = PsfRefiner::new(supplied.clone(), s).unwrap();
        for _ in 0..50 {
            r.step(&g).unwrap();
        }
        mean(&cell_errors(r.current(), &supplied).unwrap())
    };
    let (moved, kept) = (run(free), run(held));
    assert!(kept < 0.2 * moved, "anchored {kept} vs free {moved}");
}

#[test]
fn bad_gradients_settings_and_states_are_refused() {
    let supplied = gaussian_grid(2, 5, 1.0);
    let ok = RefineSettings {
        lr: 0.01,
        anchor: 1.0,
        smooth: 1.0,
    };
    for bad in [
        RefineSettings { lr: 0.0, ..ok },
        RefineSettings { lr: f32::NAN, ..ok },
        RefineSettings { anchor: -1.0, ..ok },
        RefineSettings {
            smooth: f32::INFINITY,
            ..ok
        },
    ] {
        assert!(PsfRefiner::new(supplied.clone(), bad).is_err(), "{bad:?}");
    }
    let mut r = PsfRefiner::new(supplied.clone(), ok).unwrap();
    let before = r.current().clone();
    let mut g = vec![0.0f32; supplied.planar().len()];
    g[3] = f32::NAN;
    assert!(r.step(&g).is_err());
    assert!(r.step(&g[..10]).is_err());
    assert_eq!(r.current(), &before, "a refused step changed the grid");
    let mut state = r.state().clone();
    state.v[0] = f32::INFINITY;
    assert!(PsfRefiner::resume(supplied.clone(), ok, state).is_err());
    // A gradient whose square overflows is refused and changes nothing; a large one that
    // does not moves the logits by at most about the learning rate (Adam).
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    let signs: Vec<f32> = (0..supplied.planar().len())
        .map(|_| if rng.random::<bool>() { 1.0 } else { -1.0 })
        .collect();
    let huge: Vec<f32> = signs.iter().map(|s| s * 1e30).collect();
    assert!(r.step(&huge).is_err());
    assert_eq!(r.current(), &before, "a refused step changed the grid");
    let large: Vec<f32> = signs.iter().map(|s| s * 1e15).collect();
    let logits = r.state().logits.clone();
    r.step(&large).unwrap();
    assert!(r.current().planar().iter().all(|v| v.is_finite()));
    let moved = r
        .state()
        .logits
        .iter()
        .zip(&logits)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f32, f32::max);
    assert!(moved <= 1.01 * ok.lr, "a logit moved {moved}");
    // Resuming from a saved state gives the same grid, bit for bit.
    let again = PsfRefiner::resume(supplied.clone(), ok, r.state().clone()).unwrap();
    assert_eq!(again.current(), r.current());
    assert!(cell_errors(&supplied, &gaussian_grid(3, 5, 1.0)).is_err());
}

#[test]
fn measured_grids_are_noisy_but_valid_and_seeded() {
    let g = gaussian_grid(3, 9, 1.0);
    let a = measured(&g, 0.02, 0.05, 1).unwrap();
    let b = measured(&g, 0.02, 0.05, 1).unwrap();
    let c = measured(&g, 0.02, 0.05, 2).unwrap();
    assert_eq!(a, b);
    assert_ne!(a, c);
    let e = mean(&cell_errors(&a, &g).unwrap());
    assert!(e > 0.01 && e < 0.5, "error {e}");
    assert!(a.planar().iter().all(|v| *v >= 0.0));
    assert_eq!(measured(&g, 0.0, 0.0, 0).unwrap(), g);
    assert!(measured(&g, -1.0, 0.0, 0).is_err());
    assert!(measured(&g, 0.0, 1.0, 0).is_err());
}

mod warp {
    use super::*;
    use aberration::refine::warp::{PARAMS, WarpRefiner, warp_grid};

    #[test]
    fn the_identity_warp_keeps_the_grid_and_a_quarter_turn_rotates_pixels() {
        let g = gaussian_grid(3, 9, 1.0);
        let same = warp_grid(&g, &[0.0; PARAMS]).unwrap();
        let worst = same
            .planar()
            .iter()
            .zip(g.planar())
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        assert!(worst < 1e-6, "identity warp moved a value by {worst}");
        // A quarter turn moves pixel (y, x) to (x, k − 1 − y) or (k − 1 − x, y): either way each
        // kernel becomes one of its own exact pixel rotations.
        let k = 9;
        let mut p = [0.0; PARAMS];
        p[6] = std::f64::consts::FRAC_PI_2;
        let turned = warp_grid(&g, &p).unwrap();
        for i in 0..27 {
            let (src, dst) = (
                &g.planar()[i * k * k..(i + 1) * k * k],
                &turned.planar()[i * k * k..(i + 1) * k * k],
            );
            let rot = |f: &dyn Fn(usize, usize) -> usize| -> f32 {
                (0..k * k)
                    .map(|j| (dst[j] - src[f(j / k, j % k)]).abs())
                    .fold(0.0, f32::max)
            };
            let a = rot(&|y, x| x * k + (k - 1 - y));
            let b = rot(&|y, x| (k - 1 - x) * k + y);
            assert!(a.min(b) < 1e-5, "kernel {i}: quarter turn off by {a} / {b}");
        }
        // A larger scale widens every kernel: its second moment grows by about the scale²
        // (bilinear resampling adds about a sixth of a pixel² per axis, small beside these).
        let k = 21;
        let g = gaussian_grid(3, k, 2.5);
        let mut wide = [0.0; PARAMS];
        wide[..3].fill(0.1f64);
        let w = warp_grid(&g, &wide).unwrap();
        let moment = |kern: &[f32]| -> f64 {
            let c = (k / 2) as f64;
            kern.iter()
                .enumerate()
                .map(|(j, v)| {
                    *v as f64 * (((j / k) as f64 - c).powi(2) + ((j % k) as f64 - c).powi(2))
                })
                .sum()
        };
        let ratio = moment(&w.planar()[..k * k]) / moment(&g.planar()[..k * k]);
        assert!(
            (ratio - (0.2f64).exp()).abs() < 0.08,
            "second moment grew {ratio}x"
        );
        assert!(warp_grid(&g, &[0.0; 3]).is_err());
        assert!(warp_grid(&g, &[f64::NAN; PARAMS]).is_err());
    }

    /// The one-pass gradient against central differences through the warp, away from the
    /// identity (where bilinear sampling is smooth almost everywhere).
    #[test]
    fn the_warp_gradient_matches_differences_through_the_warp() {
        let supplied = gaussian_grid(3, 15, 1.8);
        let mut rng = ChaCha8Rng::seed_from_u64(12);
        let g: Vec<f32> = (0..supplied.planar().len())
            .map(|_| rng.random::<f32>() - 0.5)
            .collect();
        let mut r = WarpRefiner::new(supplied, 0.05, 0.0).unwrap();
        for _ in 0..4 {
            r.step(&g).unwrap();
        }
        assert!(
            r.params().iter().all(|p| p.abs() > 0.05),
            "{:?}",
            r.params()
        );
        let analytic = r.param_gradient(&g).unwrap();
        let numeric = r.param_gradient_by_differences(&g).unwrap();
        for (i, (a, n)) in analytic.iter().zip(&numeric).enumerate() {
            assert!(
                (a - n).abs() <= 0.02 * n.abs().max(1e-3),
                "parameter {i}: {a} vs central difference {n}"
            );
        }
    }

    /// Images blurred through a grid scaled 8 % wider in red and turned 3°: refining the warp
    /// from the supplied grid finds both, and the grid comes closer to the truth.
    #[test]
    fn warp_refinement_recovers_a_scale_and_a_rotation() {
        let (w, h, grid, k) = (48, 40, 3, 11);
        let supplied = gaussian_grid(grid, k, 1.0);
        let mut truth_p = [0.0; PARAMS];
        truth_p[0] = 0.08f64.ln_1p();
        truth_p[6] = 3f64.to_radians();
        let truth = warp_grid(&supplied, &truth_p).unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let sharp: Vec<Vec<Vec3>> = (0..4).map(|_| random_pixels(w * h, &mut rng)).collect();
        let true_plan = BlurPlan::new(&truth, w, h, BlurMode::Blend).unwrap();
        let observed: Vec<Vec<Vec3>> = sharp
            .iter()
            .map(|x| true_plan.apply_pixels(x).unwrap())
            .collect();
        let mut r = WarpRefiner::new(supplied.clone(), 3e-3, 0.0).unwrap();
        let mut plan = BlurPlan::new(&supplied, w, h, BlurMode::Blend).unwrap();
        for step in 0..300 {
            let i = step % sharp.len();
            let blurred = plan.apply_pixels(&sharp[i]).unwrap();
            let residual: Vec<Vec3> = blurred
                .iter()
                .zip(&observed[i])
                .map(|(a, b)| (*a - *b) * (2.0 / (w * h) as f32))
                .collect();
            let grad = plan.psf_gradient_pixels(&sharp[i], &residual).unwrap();
            r.step(&grad).unwrap();
            plan.set_psf(r.current()).unwrap();
        }
        let p = r.params();
        assert!(
            (p[0] - truth_p[0]).abs() < 0.02,
            "red log-scale {} vs {}",
            p[0],
            truth_p[0]
        );
        assert!(
            (p[6] - truth_p[6]).abs() < 0.01,
            "angle {} vs {}",
            p[6],
            truth_p[6]
        );
        let e0 = mean(&cell_errors(&supplied, &truth).unwrap());
        let e1 = mean(&cell_errors(r.current(), &truth).unwrap());
        assert!(e1 < 0.3 * e0, "grid error {e0:.4} -> {e1:.4}");
        // The state resumes to the same grid.
        let again = WarpRefiner::resume(supplied.clone(), 3e-3, 0.0, r.state().clone()).unwrap();
        assert_eq!(again.current(), r.current());
        let mut bad = r.state().clone();
        bad.logits.pop();
        assert!(WarpRefiner::resume(supplied.clone(), 3e-3, 0.0, bad).is_err());
        assert!(WarpRefiner::new(supplied, 0.0, 0.0).is_err());
    }
}
