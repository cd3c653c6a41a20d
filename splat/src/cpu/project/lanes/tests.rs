use super::*;
use crate::reference;
use crate::reference::scalar_project::project_one;

/// Every Gaussian of random scenes (SH 0–3, with and without antialiasing, needles, huge
/// and tiny scales, non-finite parameters, a last block shorter than eight) against the
/// scalar projection: the same ones culled, radii within a pixel, means, depths and
/// colours within float32 rounding, and footprints no further from the float64 one.
#[test]
fn lanes_match_the_scalar_projection() {
    let cam = crate::synthetic::benchmark_camera().resized(200, 150);
    let pos = cam.position();
    let mut compared = 0;
    for (seed, deg, aa) in [(1, 0, false), (2, 1, true), (3, 2, false), (4, 3, true)] {
        let mut g = crate::synthetic::random_box_scene(seed, 3_001, deg);
        for i in (0..g.len()).step_by(7) {
            g.log_scales[i].x += 3.0;
            g.log_scales[i].y -= 4.0;
        }
        g.log_scales[5] = Vec3::splat(-30.0);
        g.log_scales[6] = Vec3::splat(12.0);
        g.means[8].x = f32::NAN;
        g.rotations[9] = [0.0; 4];
        g.rotations[10] = [f32::INFINITY, 0.0, 0.0, 0.0];
        g.logit_opacities[11] = f32::NAN;
        g.logit_opacities[12] = -30.0;
        g.logit_opacities[13] = 40.0;
        if deg > 0 {
            let rc = g.rest_count();
            g.sh_rest[14 * rc] = Vec3::splat(f32::INFINITY);
        }
        let params = reference::flatten(&g);
        let ppg = reference::params_per_gaussian(g.sh_degree);
        let ref_cam = reference::RefCamera::from(&cam);
        for first in (0..g.len()).step_by(LANES) {
            let count = LANES.min(g.len() - first);
            let at = Block {
                g: &g,
                first,
                cam: &cam,
                sh_degree: deg,
                antialiased: aa,
            };
            let got = project_lanes(&at, count);
            for l in 0..count {
                let i = first + l;
                let want = project_one(&g, i, &cam, deg, aa, pos);
                let got = got[l];
                let Some(want) = want else {
                    assert_eq!(got.radius, [0, 0], "Gaussian {i} should be culled");
                    continue;
                };
                assert!(
                    (got.radius[0] - want.radius[0]).abs() <= 1
                        && (got.radius[1] - want.radius[1]).abs() <= 1
                        && got.radius != [0, 0],
                    "Gaussian {i}: radius {:?} vs {:?}",
                    got.radius,
                    want.radius
                );
                let close = |a: f32, b: f32| (a - b).abs() <= 2e-5 * b.abs().max(1.0);
                // The conic is compared through what it does, the footprint's α over its
                // box, against the float64 footprint: a needle's conic inverts a nearly
                // singular covariance and amplifies its entries' rounding, differently in
                // the two float32 paths; the lanes may not err more than the scalar path
                // (with a little room) or 1e-5.
                let truth = reference::project_ref(
                    &params[i * ppg..(i + 1) * ppg],
                    g.sh_degree,
                    &ref_cam,
                    deg,
                    aa,
                )
                .expect("float64 culls a Gaussian float32 keeps by depth");
                let (truth, truth_opacity) = (truth.conic, truth.opacity);
                let alpha = |conic: [f64; 3], o: f64, dx: f64, dy: f64| {
                    let [a, b, c] = conic;
                    let sigma = 0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy;
                    (o * (-sigma).exp()).min(0.99)
                };
                let steps = [-1.0, -0.5, -0.25, -0.1, 0.0, 0.1, 0.25, 0.5, 1.0];
                let (mut err_lanes, mut err_scalar) = (0.0f64, 0.0f64);
                for u in steps {
                    for v in steps {
                        let dx = u * want.radius[0] as f64;
                        let dy = v * want.radius[1] as f64;
                        let t = alpha(truth, truth_opacity, dx, dy);
                        let a =
                            |p: &Projected| alpha(p.conic.map(f64::from), p.opacity as f64, dx, dy);
                        err_lanes = err_lanes.max((a(&got) - t).abs());
                        err_scalar = err_scalar.max((a(&want) - t).abs());
                    }
                }
                let footprint = err_lanes <= (4.0 * err_scalar).max(1e-5);
                let ok = close(got.mean2d.x, want.mean2d.x)
                    && close(got.mean2d.y, want.mean2d.y)
                    && footprint
                    && close(got.depth, want.depth)
                    && (got.color - want.color).abs().max_element() <= 2e-5;
                assert!(
                    ok,
                    "Gaussian {i}: {got:?} vs {want:?}; α error {err_lanes:e} (scalar {err_scalar:e})"
                );
                compared += 1;
            }
        }
    }
    assert!(
        compared > 8_000,
        "only {compared} visible Gaussians compared"
    );
}

/// The AVX2 build and the portable one give the same bits.
#[test]
#[cfg(target_arch = "x86_64")]
fn avx2_and_portable_builds_agree_bit_for_bit() {
    if !crate::cpu::blend::Isa::available().contains(&crate::cpu::blend::Isa::Avx2) {
        eprintln!("SKIP: this CPU has no AVX2");
        return;
    }
    let cam = crate::synthetic::benchmark_camera().resized(200, 150);
    let g = crate::synthetic::random_box_scene(9, 1_000, 3);
    let bits = |p: &Projected| {
        let mut v = vec![p.mean2d.x, p.mean2d.y, p.depth, p.opacity];
        v.extend(p.conic);
        v.extend(p.color.to_array());
        (v.iter().map(|x| x.to_bits()).collect::<Vec<_>>(), p.radius)
    };
    for first in (0..g.len()).step_by(LANES) {
        let mut a = [Projected::default(); LANES];
        let mut b = [Projected::default(); LANES];
        let at = Block {
            g: &g,
            first,
            cam: &cam,
            sh_degree: 3,
            antialiased: true,
        };
        // SAFETY: checked above.
        unsafe { project_avx2(&at, &mut a) };
        project_body(&at, &mut b);
        for l in 0..LANES {
            assert_eq!(bits(&a[l]), bits(&b[l]), "Gaussian {}", first + l);
        }
    }
}

/// The backward of every Gaussian of random scenes (SH 0–3, with and without
/// antialiasing, needles, non-finite parameters, untouched lanes, a short last block)
/// against the scalar `project_backward_one` with random screen-space gradients: the same
/// Gaussians get zeros, and every gradient group agrees within 1e-6 relative in norm (the
/// exponentials differ in rounding only).
#[test]
fn backward_lanes_match_the_scalar_backward() {
    use crate::reference::scalar_project::project_backward_one;
    let avx2 = crate::cpu::blend::Isa::available().contains(&crate::cpu::blend::Isa::Avx2);
    if !avx2 {
        eprintln!("SKIP (in part): this CPU has no AVX2 to compare with the portable build");
    }
    let cam = crate::synthetic::benchmark_camera().resized(200, 150);
    let pos = cam.position();
    let mut rng = base::SplitMix64::new(7);
    for (seed, deg, aa) in [
        (1, 0, true),
        (2, 1, false),
        (3, 2, true),
        (4, 3, false),
        (5, 3, true),
    ] {
        let mut g = crate::synthetic::random_box_scene(seed, 2_005, deg);
        for i in (0..g.len()).step_by(7) {
            g.log_scales[i].x += 3.0;
            g.log_scales[i].y -= 4.0;
        }
        g.means[8].x = f32::NAN;
        g.rotations[9] = [0.0; 4];
        g.log_scales[10] = Vec3::splat(60.0);
        g.logit_opacities[11] = f32::NAN;
        let rc = g.rest_count();
        let n = g.len();
        let mut r = || rng.normal() as f32;
        // Odd seeds: colour gradients only, so the mean's gradient is the SH direction's.
        let only_color = seed % 2 == 1;
        let mut r2 = || if only_color { 0.0 } else { r() };
        let screen: Vec<ScreenGrad> = (0..n)
            .map(|_| ScreenGrad {
                mean2d: Vec2::new(r2(), r2()),
                conic: [r2(), r2(), r2()],
                color: Vec3::new(1.0, -0.5, 0.25),
                opacity: r2(),
                depth: r2(),
            })
            .collect();
        let colors: Vec<Vec3> = (0..n)
            .map(|i| {
                crate::reference::scalar_project::project_one(&g, i, &cam, deg, aa, pos)
                    .map_or(Vec3::ZERO, |p| p.color)
            })
            .collect();
        // Every ninth Gaussian was in no tile.
        let touched = |i: usize| i % 9 != 4;
        let (mut want_p, mut got_p) = (Vec::new(), Vec::new());
        let (mut want_r, mut got_r) = (vec![Vec3::ZERO; n * rc], vec![Vec3::ZERO; n * rc]);
        for i in 0..n {
            let p = if touched(i) {
                project_backward_one(
                    &g,
                    i,
                    &cam,
                    deg,
                    aa,
                    pos,
                    colors[i],
                    &screen[i],
                    &mut want_r[i * rc..(i + 1) * rc],
                )
            } else {
                ParamGrad::default()
            };
            want_p.push(p);
        }
        let flat = |p: &ParamGrad| {
            let mut v = p.mean.to_array().to_vec();
            v.extend(p.log_scale.to_array());
            v.extend(p.rotation);
            v.push(p.logit_opacity);
            v.extend(p.sh_dc.to_array());
            v
        };
        for first in (0..n).step_by(LANES) {
            let count = LANES.min(n - first);
            let t = std::array::from_fn(|l| l < count && touched(first + l));
            let at = Block {
                g: &g,
                first,
                cam: &cam,
                sh_degree: deg,
                antialiased: aa,
            };
            let from = BackwardIn {
                colors: &colors[first..first + count],
                screen: &screen[first..first + count],
                touched: t,
            };
            let out =
                project_backward_lanes(&at, &from, &mut got_r[first * rc..(first + count) * rc]);
            got_p.extend_from_slice(&out[..count]);
            // The AVX2 build gives the portable build's bits.
            #[cfg(target_arch = "x86_64")]
            if avx2 {
                let (mut o_port, mut r_port) =
                    ([ParamGrad::default(); LANES], vec![Vec3::ZERO; count * rc]);
                let (mut o_avx, mut r_avx) =
                    ([ParamGrad::default(); LANES], vec![Vec3::ZERO; count * rc]);
                backward_body(&at, &from, &mut r_port, &mut o_port);
                // SAFETY: `avx2` says the CPU has AVX2 and FMA.
                unsafe { backward_avx2(&at, &from, &mut r_avx, &mut o_avx) };
                let bits = |o: &[ParamGrad; LANES], r: &[Vec3]| {
                    let mut v: Vec<f32> = o[..count].iter().flat_map(flat).collect();
                    v.extend(r.iter().flat_map(|x| x.to_array()));
                    v.iter().map(|x| x.to_bits()).collect::<Vec<_>>()
                };
                assert!(
                    bits(&o_avx, &r_avx) == bits(&o_port, &r_port),
                    "seed {seed}: AVX2 and portable backward differ at Gaussians {first}.."
                );
            }
        }
        let mut zeros = 0;
        for i in 0..n {
            let (w, gg) = (flat(&want_p[i]), flat(&got_p[i]));
            let wz = w.iter().all(|v| *v == 0.0);
            let gz = gg.iter().all(|v| *v == 0.0);
            assert_eq!(
                wz, gz,
                "Gaussian {i}: zeroed in one path only: {w:?} vs {gg:?}"
            );
            zeros += wz as usize;
        }
        assert!(
            zeros > n / 10,
            "too few zeroed Gaussians ({zeros}) to test that rule"
        );
        type Group = fn(&ParamGrad) -> Vec<f32>;
        let groups: [(&str, Group); 5] = [
            ("means", |p| p.mean.to_array().to_vec()),
            ("log_scales", |p| p.log_scale.to_array().to_vec()),
            ("rotations", |p| p.rotation.to_vec()),
            ("opacities", |p| vec![p.logit_opacity]),
            ("sh_dc", |p| p.sh_dc.to_array().to_vec()),
        ];
        let rel = |a: &[f32], b: &[f32]| {
            let d: f64 = a.iter().zip(b).map(|(x, y)| ((x - y) as f64).powi(2)).sum();
            let m: f64 = b.iter().map(|y| (*y as f64).powi(2)).sum();
            (d / m.max(1e-30)).sqrt()
        };
        for (name, f) in groups {
            let a: Vec<f32> = got_p.iter().flat_map(f).collect();
            let b: Vec<f32> = want_p.iter().flat_map(f).collect();
            let e = rel(&a, &b);
            assert!(e <= 1e-6, "SH {deg} aa {aa}: {name} differ by {e:e}");
        }
        if rc > 0 {
            let a: Vec<f32> = got_r.iter().flat_map(|v| v.to_array()).collect();
            let b: Vec<f32> = want_r.iter().flat_map(|v| v.to_array()).collect();
            let e = rel(&a, &b);
            assert!(e <= 1e-6, "SH {deg}: SH rest differ by {e:e}");
        }
    }
}
