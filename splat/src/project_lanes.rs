//! [`crate::project::project_one`] for eight Gaussians at once, the forward renderer's
//! projection: the same steps and rules (cull, EWA covariance with the Jacobian clamp, low-pass,
//! antialiasing, opacity-aware radius, SH colour) on [`F8`] lanes, which the compiler
//! vectorises. It agrees with the scalar projection up to the exponentials (a polynomial here,
//! the C library's there; tested), so a radius may differ by one pixel where its extent lands
//! on an integer.

use glam::{Vec2, Vec3};

use crate::camera::Camera;
use crate::conventions::{ALPHA_THRESHOLD, COV2D_BLUR, MAX_EXTENT_SIGMAS, SH_COLOR_OFFSET};
use crate::lanes::{F8, M8, N};
use crate::model::Gaussians;
use crate::project::{Projected, clamp_limits};
use crate::sh::{
    SH_C0, SH_C1, SH_C2_XX, SH_C2_XY, SH_C2_ZZ, SH_C2_ZZ0, SH_C3_A, SH_C3_B, SH_C3_C, SH_C3_C0,
    SH_C3_D, SH_C3_D0,
};

/// Projects Gaussians `first .. first + count` (`count` from 1 to [`N`]); a culled Gaussian,
/// and every lane from `count` on, gets `Projected::default()`.
pub fn project_lanes(
    g: &Gaussians,
    first: usize,
    count: usize,
    cam: &Camera,
    sh_degree: u32,
    antialiased: bool,
) -> [Projected; N] {
    let mut out = [Projected::default(); N];
    let out_part = &mut out[..count.clamp(1, N)];
    #[cfg(target_arch = "x86_64")]
    if crate::blocks::Isa::chosen() != crate::blocks::Isa::Portable {
        // SAFETY: the chosen build's CPU has AVX2 and FMA.
        unsafe { project_avx2(g, first, cam, sh_degree, antialiased, out_part) };
        return out;
    }
    project_body(g, first, cam, sh_degree, antialiased, out_part);
    out
}

/// The same code compiled for AVX2 (the lanes become one register). No FMA is contracted,
/// so it gives the portable build's bits.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn project_avx2(
    g: &Gaussians,
    first: usize,
    cam: &Camera,
    sh_degree: u32,
    antialiased: bool,
    out: &mut [Projected],
) {
    project_body(g, first, cam, sh_degree, antialiased, out);
}

// Matrix entries indexed by row and column, as the formulas write them.
#[allow(clippy::needless_range_loop)]
#[inline(always)]
fn project_body(
    g: &Gaussians,
    first: usize,
    cam: &Camera,
    sh_degree: u32,
    antialiased: bool,
    out: &mut [Projected],
) {
    let count = out.len();
    debug_assert!((1..=N).contains(&count));
    // Lanes past the end repeat the last Gaussian; their results are dropped.
    let idx: [usize; N] = std::array::from_fn(|l| first + l.min(count - 1));
    let lane = |f: fn(&Gaussians, usize) -> f32| F8(std::array::from_fn(|l| f(g, idx[l])));
    let (mx, my, mz) = (
        lane(|g, i| g.means[i].x),
        lane(|g, i| g.means[i].y),
        lane(|g, i| g.means[i].z),
    );

    // Camera space: `p_c = W p + t`, in glam's order (column by column).
    let w = cam.rotation;
    let t = cam.translation;
    let pc = |k: usize| {
        let (c0, c1, c2) = (w.x_axis[k], w.y_axis[k], w.z_axis[k]);
        c0 * mx + c1 * my + c2 * mz + t[k]
    };
    let (px, py, pz) = (pc(0), pc(1), pc(2));
    let mut valid = px.is_finite()
        & py.is_finite()
        & pz.is_finite()
        & pz.ge(F8::splat(cam.near))
        & pz.le(F8::splat(cam.far));

    // Rotation of the normalised quaternion (scaled by its largest component first).
    let q: [F8; 4] = [
        lane(|g, i| g.rotations[i][0]),
        lane(|g, i| g.rotations[i][1]),
        lane(|g, i| g.rotations[i][2]),
        lane(|g, i| g.rotations[i][3]),
    ];
    let m = q[0].abs().max(q[1].abs()).max(q[2].abs()).max(q[3].abs());
    let q_ok = m.is_finite() & m.gt(F8::splat(0.0));
    // (No `array::from_fn` with a closure over lanes here or below: the compiler keeps such
    // closures out of line, compiled without AVX2.)
    let s = [q[0] / m, q[1] / m, q[2] / m, q[3] / m];
    let len = (s[0] * s[0] + s[1] * s[1] + s[2] * s[2] + s[3] * s[3]).sqrt();
    let one = F8::splat(1.0);
    let zero = F8::splat(0.0);
    let qw = F8::select(q_ok, s[0] / len, one);
    let qx = F8::select(q_ok, s[1] / len, zero);
    let qy = F8::select(q_ok, s[2] / len, zero);
    let qz = F8::select(q_ok, s[3] / len, zero);
    // r[row][col].
    let r = [
        [
            1.0 - 2.0 * (qy * qy + qz * qz),
            2.0 * (qx * qy - qw * qz),
            2.0 * (qx * qz + qw * qy),
        ],
        [
            2.0 * (qx * qy + qw * qz),
            1.0 - 2.0 * (qx * qx + qz * qz),
            2.0 * (qy * qz - qw * qx),
        ],
        [
            2.0 * (qx * qz - qw * qy),
            2.0 * (qy * qz + qw * qx),
            1.0 - 2.0 * (qx * qx + qy * qy),
        ],
    ];
    let scale = [
        lane(|g, i| g.log_scales[i].x).exp(),
        lane(|g, i| g.log_scales[i].y).exp(),
        lane(|g, i| g.log_scales[i].z).exp(),
    ];
    // M = R diag(s); Σ = M Mᵀ.
    let mut mm = [[zero; 3]; 3];
    for a in 0..3 {
        for j in 0..3 {
            mm[a][j] = r[a][j] * scale[j];
        }
    }
    let sig = |a: usize, b: usize| mm[a][0] * mm[b][0] + mm[a][1] * mm[b][1] + mm[a][2] * mm[b][2];
    let sw = [
        [sig(0, 0), sig(0, 1), sig(0, 2)],
        [sig(0, 1), sig(1, 1), sig(1, 2)],
        [sig(0, 2), sig(1, 2), sig(2, 2)],
    ];
    // Camera-space covariance W Σ Wᵀ.
    let wr = |a: usize, b: usize| w.col(b)[a];
    let mut ws = [[zero; 3]; 3];
    for a in 0..3 {
        for b in 0..3 {
            ws[a][b] = wr(a, 0) * sw[0][b] + wr(a, 1) * sw[1][b] + wr(a, 2) * sw[2][b];
        }
    }
    let cc = |a: usize, b: usize| ws[a][0] * wr(b, 0) + ws[a][1] * wr(b, 1) + ws[a][2] * wr(b, 2);
    // All nine entries: rounding leaves the product slightly asymmetric, and the scalar path
    // reads each where its matrix-vector products do (`c[a][b]`: row a, column b).
    let mut c = [[zero; 3]; 3];
    for a in 0..3 {
        for b in 0..3 {
            c[a][b] = cc(a, b);
        }
    }

    // EWA Jacobian at the clamped point.
    let lim = clamp_limits(cam);
    let rx = px / pz;
    let ry = py / pz;
    let tx = pz * rx.map(|v| v.clamp(-lim[0], lim[1]));
    let ty = pz * ry.map(|v| v.clamp(-lim[2], lim[3]));
    let rz = 1.0 / pz;
    let rz2 = rz * rz;
    let (j00, j02) = (cam.fx * rz, -cam.fx * tx * rz2);
    let (j11, j12) = (cam.fy * rz, -cam.fy * ty * rz2);
    // cov = [j0·C j0, j0·C j1, j1·C j1] with j0 = (j00, 0, j02), j1 = (0, j11, j12).
    let s0 = [
        c[0][0] * j00 + c[0][2] * j02,
        c[1][0] * j00 + c[1][2] * j02,
        c[2][0] * j00 + c[2][2] * j02,
    ];
    let s1 = [
        c[0][1] * j11 + c[0][2] * j12,
        c[1][1] * j11 + c[1][2] * j12,
        c[2][1] * j11 + c[2][2] * j12,
    ];
    let a = j00 * s0[0] + j02 * s0[2];
    let b = j00 * s1[0] + j02 * s1[2];
    let c = j11 * s1[1] + j12 * s1[2];
    valid = valid & a.is_finite() & b.is_finite() & c.is_finite();

    let ab = a + COV2D_BLUR;
    let cb = c + COV2D_BLUR;
    let det_b = ab * cb - b * b;
    valid = valid & det_b.is_finite() & det_b.gt(zero);

    // Opacity, with the antialiasing compensation.
    let logit = lane(|g, i| g.logit_opacities[i]);
    let e = (-logit.abs()).exp();
    let mut opacity = F8::select(logit.ge(zero), 1.0 / (1.0 + e), e / (1.0 + e));
    if antialiased {
        let det = a * c - b * b;
        opacity = opacity * (det / det_b).max(zero).sqrt();
    }
    valid = valid & opacity.ge(F8::splat(ALPHA_THRESHOLD));
    let extent = (2.0 * (opacity / ALPHA_THRESHOLD).map(f32::ln))
        .sqrt()
        .min(F8::splat(MAX_EXTENT_SIGMAS));
    let rad_x = (extent * ab.sqrt()).ceil();
    let rad_y = (extent * cb.sqrt()).ceil();
    let mean_x = cam.fx * px / pz + cam.cx;
    let mean_y = cam.fy * py / pz + cam.cy;
    valid = valid
        & (mean_x + rad_x).gt(zero)
        & (mean_x - rad_x).lt(F8::splat(cam.width as f32))
        & (mean_y + rad_y).gt(zero)
        & (mean_y - rad_y).lt(F8::splat(cam.height as f32));
    let inv = 1.0 / det_b;
    let conic = [cb * inv, -b * inv, ab * inv];
    valid = valid & conic[0].is_finite() & conic[1].is_finite() & conic[2].is_finite();

    let color = sh_color(g, &idx, sh_degree, cam.position(), [mx, my, mz]);
    valid = valid & color[0].is_finite() & color[1].is_finite() & color[2].is_finite();

    // Clamped only so the radius stays representable as i32 (far beyond any image).
    let big = F8::splat((1u32 << 30) as f32);
    let (rad_x, rad_y) = (rad_x.min(big), rad_y.min(big));
    write(
        out,
        valid,
        [mean_x, mean_y],
        conic,
        pz,
        opacity,
        color,
        [rad_x, rad_y],
    );
}

/// Stores the lanes that survived; the others are culled.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn write(
    out: &mut [Projected],
    valid: M8,
    mean: [F8; 2],
    conic: [F8; 3],
    depth: F8,
    opacity: F8,
    color: [F8; 3],
    radius: [F8; 2],
) {
    for (l, o) in out.iter_mut().enumerate() {
        *o = if valid.0[l] {
            Projected {
                mean2d: Vec2::new(mean[0].0[l], mean[1].0[l]),
                conic: conic.map(|c| c.0[l]),
                depth: depth.0[l],
                opacity: opacity.0[l],
                color: Vec3::new(color[0].0[l], color[1].0[l], color[2].0[l]),
                radius: radius.map(|r| r.0[l] as i32),
            }
        } else {
            Projected::default()
        };
    }
}

/// The SH colour `max(Σ c_k B_k(d) + 0.5, 0)` per lane, `d = normalize(mean − camera)` (as
/// [`crate::sh::eval`] and [`crate::sh::sh_dc_to_rgb`]).
#[inline(always)]
fn sh_color(g: &Gaussians, idx: &[usize; N], degree: u32, cam_pos: Vec3, mean: [F8; 3]) -> [F8; 3] {
    let zero = F8::splat(0.0);
    let dc = [
        F8(std::array::from_fn(|l| g.sh_dc[idx[l]].x)),
        F8(std::array::from_fn(|l| g.sh_dc[idx[l]].y)),
        F8(std::array::from_fn(|l| g.sh_dc[idx[l]].z)),
    ];
    if degree == 0 {
        let rgb = |d: F8| (d * SH_C0 + SH_COLOR_OFFSET).max(zero);
        return [rgb(dc[0]), rgb(dc[1]), rgb(dc[2])];
    }
    // normalize_or_zero: scaled by the reciprocal length where that is finite and positive.
    let v = [
        mean[0] - cam_pos.x,
        mean[1] - cam_pos.y,
        mean[2] - cam_pos.z,
    ];
    let rcp = 1.0 / (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    let ok = rcp.is_finite() & rcp.gt(zero);
    let x = F8::select(ok, v[0] * rcp, zero);
    let y = F8::select(ok, v[1] * rcp, zero);
    let z = F8::select(ok, v[2] * rcp, zero);
    let mut basis = [zero; 16];
    basis[0] = F8::splat(SH_C0);
    basis[1] = -SH_C1 * y;
    basis[2] = SH_C1 * z;
    basis[3] = -SH_C1 * x;
    if degree >= 2 {
        let (xx, yy, zz) = (x * x, y * y, z * z);
        basis[4] = SH_C2_XY * x * y;
        basis[5] = -SH_C2_XY * y * z;
        basis[6] = SH_C2_ZZ * zz - SH_C2_ZZ0;
        basis[7] = -SH_C2_XY * x * z;
        basis[8] = SH_C2_XX * (xx - yy);
        if degree >= 3 {
            let a = SH_C3_C * zz + SH_C3_C0;
            basis[9] = SH_C3_A * (3.0 * xx * y - yy * y);
            basis[10] = SH_C3_B * z * 2.0 * x * y;
            basis[11] = a * y;
            basis[12] = z * (SH_C3_D * zz - SH_C3_D0);
            basis[13] = a * x;
            basis[14] = SH_C3_B * z * (xx - yy);
            basis[15] = SH_C3_A * (xx * x - 3.0 * x * yy);
        }
    }
    let rc = g.rest_count();
    let nb = crate::sh::num_bases(degree);
    let mut color = [zero; 3];
    for (ch, out) in color.iter_mut().enumerate() {
        let mut c = dc[ch] * basis[0];
        for (k, b) in basis.iter().enumerate().take(nb).skip(1) {
            let coef = F8(std::array::from_fn(|l| g.sh_rest[idx[l] * rc + k - 1][ch]));
            c = c + coef * *b;
        }
        *out = (c + SH_COLOR_OFFSET).max(zero);
    }
    color
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::project::project_one;

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
            for first in (0..g.len()).step_by(N) {
                let count = N.min(g.len() - first);
                let got = project_lanes(&g, first, count, &cam, deg, aa);
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
                    let (truth, truth_opacity) = footprint_f64(&g, i, &cam, aa);
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
                            let a = |p: &Projected| {
                                alpha(p.conic.map(f64::from), p.opacity as f64, dx, dy)
                            };
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

    /// The conic and opacity of Gaussian `i` in float64 (as [`crate::reference`] computes
    /// them).
    fn footprint_f64(g: &Gaussians, i: usize, cam: &Camera, aa: bool) -> ([f64; 3], f64) {
        let d = |v: f32| v as f64;
        let w = cam.rotation;
        let wr = |a: usize, b: usize| d(w.col(b)[a]);
        let mean = g.means[i].to_array().map(d);
        let pc: [f64; 3] = std::array::from_fn(|a| {
            (0..3).map(|b| wr(a, b) * mean[b]).sum::<f64>() + d(cam.translation[a])
        });
        let q = g.rotations[i].map(d);
        let qn = (q.iter().map(|v| v * v).sum::<f64>()).sqrt();
        let (qw, x, y, z) = (q[0] / qn, q[1] / qn, q[2] / qn, q[3] / qn);
        let r = [
            [
                1.0 - 2.0 * (y * y + z * z),
                2.0 * (x * y - qw * z),
                2.0 * (x * z + qw * y),
            ],
            [
                2.0 * (x * y + qw * z),
                1.0 - 2.0 * (x * x + z * z),
                2.0 * (y * z - qw * x),
            ],
            [
                2.0 * (x * z - qw * y),
                2.0 * (y * z + qw * x),
                1.0 - 2.0 * (x * x + y * y),
            ],
        ];
        let s = g.log_scales[i].to_array().map(|v| d(v).exp());
        let m: [[f64; 3]; 3] = std::array::from_fn(|a| std::array::from_fn(|j| r[a][j] * s[j]));
        let sig: [[f64; 3]; 3] = std::array::from_fn(|a| {
            std::array::from_fn(|b| (0..3).map(|j| m[a][j] * m[b][j]).sum())
        });
        let c: [[f64; 3]; 3] = std::array::from_fn(|a| {
            std::array::from_fn(|b| {
                (0..3)
                    .map(|k| (0..3).map(|l| wr(a, k) * sig[k][l] * wr(b, l)).sum::<f64>())
                    .sum()
            })
        });
        let lim = clamp_limits(cam).map(d);
        let zc = pc[2];
        let tx = zc * (pc[0] / zc).clamp(-lim[0], lim[1]);
        let ty = zc * (pc[1] / zc).clamp(-lim[2], lim[3]);
        let (fx, fy) = (d(cam.fx), d(cam.fy));
        let j = [
            [fx / zc, 0.0, -fx * tx / (zc * zc)],
            [0.0, fy / zc, -fy * ty / (zc * zc)],
        ];
        let cov = |a: usize, b: usize| {
            (0..3)
                .map(|k| (0..3).map(|l| j[a][k] * c[k][l] * j[b][l]).sum::<f64>())
                .sum::<f64>()
        };
        let blur = COV2D_BLUR as f64;
        let (a, b, cc) = (cov(0, 0) + blur, cov(0, 1), cov(1, 1) + blur);
        let det = a * cc - b * b;
        let mut opacity = 1.0 / (1.0 + (-d(g.logit_opacities[i])).exp());
        if aa {
            let det0 = cov(0, 0) * cov(1, 1) - cov(0, 1) * cov(0, 1);
            opacity *= (det0 / det).max(0.0).sqrt();
        }
        ([cc / det, -b / det, a / det], opacity)
    }

    /// The AVX2 build and the portable one give the same bits.
    #[test]
    #[cfg(target_arch = "x86_64")]
    fn avx2_and_portable_builds_agree_bit_for_bit() {
        if !crate::blocks::Isa::available().contains(&crate::blocks::Isa::Avx2) {
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
        for first in (0..g.len()).step_by(N) {
            let mut a = [Projected::default(); N];
            let mut b = [Projected::default(); N];
            // SAFETY: checked above.
            unsafe { project_avx2(&g, first, &cam, 3, true, &mut a) };
            project_body(&g, first, &cam, 3, true, &mut b);
            for l in 0..N {
                assert_eq!(bits(&a[l]), bits(&b[l]), "Gaussian {}", first + l);
            }
        }
    }
}
