//! [`crate::reference::scalar_project::project_one`] and [`crate::reference::scalar_project::project_backward_one`] for eight
//! Gaussians at once, as the CPU renderer runs them: the same steps and rules (cull, EWA
//! covariance with the Jacobian clamp, low-pass, antialiasing, opacity-aware radius, SH colour,
//! and their gradients) on [`F8`] lanes, which the compiler vectorises. They agree with the
//! scalar functions within float32 rounding (the exponentials round as `expf` does except for a
//! few arguments in ten thousand, and some sums run in another order; tested), so a radius may
//! differ by one pixel where its extent lands on an integer.

use glam::{Vec2, Vec3};

use crate::camera::Camera;
use crate::conventions::{ALPHA_THRESHOLD, COV2D_BLUR, MAX_EXTENT_SIGMAS, SH_COLOR_OFFSET};
use crate::cpu::lanes::{F8, LANES, M8};
use crate::cpu::project::{clamp_limits, rotation_backward, rotation_rows};
use crate::cpu::stages::{ParamGrad, Projected, ScreenGrad};
use crate::model::Gaussians;
use crate::sh::{SH_C0, basis_grad_of, basis_of};

/// A block of up to [`LANES`] consecutive Gaussians as one camera sees them: what the projection
/// and its backward both read (the block's length is that of their outputs).
#[derive(Clone, Copy)]
pub struct Block<'a> {
    pub g: &'a Gaussians,
    /// The block's first Gaussian.
    pub first: usize,
    pub cam: &'a Camera,
    pub sh_degree: u32,
    pub antialiased: bool,
}

/// Projects Gaussians `first .. first + count` (`count` from 1 to [`LANES`]); a culled Gaussian,
/// and every lane from `count` on, gets `Projected::default()`.
pub fn project_lanes(at: &Block, count: usize) -> [Projected; LANES] {
    let mut out = [Projected::default(); LANES];
    let out_part = &mut out[..count.clamp(1, LANES)];
    #[cfg(target_arch = "x86_64")]
    if crate::cpu::blend::Isa::chosen() != crate::cpu::blend::Isa::Portable {
        // SAFETY: the chosen build's CPU has AVX2 and FMA.
        unsafe { project_avx2(at, out_part) };
        return out;
    }
    project_body(at, out_part);
    out
}

/// The same code compiled for AVX2 (the lanes become one register). No FMA is contracted,
/// so it gives the portable build's bits.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn project_avx2(at: &Block, out: &mut [Projected]) {
    project_body(at, out);
}

/// What the projection and its backward share of a Gaussian (the scalar `project::geometry`),
/// on lanes. `valid`: in front of the camera within the far plane, with a finite covariance.
struct Geo {
    mean: [F8; 3],
    p_cam: [F8; 3],
    valid: M8,
    /// The normalised quaternion `(w, x, y, z)` and the raw one's length (zero when it has none).
    qn: [F8; 4],
    qlen: F8,
    /// `rot[row][col]`.
    rot: [[F8; 3]; 3],
    scale: [F8; 3],
    /// `R diag(s)`.
    m: [[F8; 3]; 3],
    /// Camera-space covariance, `c[row][col]`.
    c: [[F8; 3]; 3],
    /// Jacobian entries `j0 = (j00, 0, j02)`, `j1 = (0, j11, j12)` and its evaluation point.
    j: [F8; 4],
    txy: [F8; 2],
    clamped: [M8; 2],
    /// Screen covariance before the low-pass.
    cov: [F8; 3],
}

/// Lane `l`: `f(g, idx[l])`.
#[inline(always)]
fn lane(g: &Gaussians, idx: &[usize; LANES], f: fn(&Gaussians, usize) -> f32) -> F8 {
    F8(std::array::from_fn(|l| f(g, idx[l])))
}

// Matrix entries indexed by row and column, as the formulas write them.
#[allow(clippy::needless_range_loop)]
#[inline(always)]
fn geometry(g: &Gaussians, idx: &[usize; LANES], cam: &Camera) -> Geo {
    let lane = |f: fn(&Gaussians, usize) -> f32| lane(g, idx, f);
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
    let r = rotation_rows([qw, qx, qy, qz]);
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
    let cx = rx.map(|v| v.clamp(-lim[0], lim[1]));
    let cy = ry.map(|v| v.clamp(-lim[2], lim[3]));
    let tx = pz * cx;
    let ty = pz * cy;
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
    let c2 = j11 * s1[1] + j12 * s1[2];
    valid = valid & a.is_finite() & b.is_finite() & c2.is_finite();

    Geo {
        mean: [mx, my, mz],
        p_cam: [px, py, pz],
        valid,
        qn: [qw, qx, qy, qz],
        qlen: F8::select(q_ok, m * len, zero),
        rot: r,
        scale,
        m: mm,
        c,
        j: [j00, j02, j11, j12],
        txy: [tx, ty],
        clamped: [rx.ne(cx), ry.ne(cy)],
        cov: [a, b, c2],
    }
}

#[inline(always)]
fn project_body(at: &Block, out: &mut [Projected]) {
    let &Block {
        g,
        first,
        cam,
        sh_degree,
        antialiased,
    } = at;
    let count = out.len();
    debug_assert!((1..=LANES).contains(&count));
    // Lanes past the end repeat the last Gaussian; their results are dropped.
    let idx: [usize; LANES] = std::array::from_fn(|l| first + l.min(count - 1));
    let geo = geometry(g, &idx, cam);
    let [mx, my, mz] = geo.mean;
    let [px, py, pz] = geo.p_cam;
    let [a, b, c] = geo.cov;
    let mut valid = geo.valid;
    let zero = F8::splat(0.0);
    let lane = |f: fn(&Gaussians, usize) -> f32| lane(g, &idx, f);
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
fn sh_color(
    g: &Gaussians,
    idx: &[usize; LANES],
    degree: u32,
    cam_pos: Vec3,
    mean: [F8; 3],
) -> [F8; 3] {
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
    let basis = basis_of(degree, [x, y, z]);
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

/// [`crate::reference::scalar_project::project_backward_one`] for Gaussians `first .. first + count`: lane `l`
/// takes the screen-space gradient `screen[l]` and the forward's clamped colour `colors[l]`,
/// and is skipped (zero gradients) unless `touched[l]`. SH-rest gradients go to `v_rest`
/// (`count · rest_count` entries, zeroed by the caller), the rest is returned per lane.
pub fn project_backward_lanes(
    at: &Block,
    from: &BackwardIn,
    v_rest: &mut [Vec3],
) -> [ParamGrad; LANES] {
    let mut out = [ParamGrad::default(); LANES];
    #[cfg(target_arch = "x86_64")]
    if crate::cpu::blend::Isa::chosen() != crate::cpu::blend::Isa::Portable {
        // SAFETY: the chosen build's CPU has AVX2 and FMA.
        unsafe { backward_avx2(at, from, v_rest, &mut out) };
        return out;
    }
    backward_body(at, from, v_rest, &mut out);
    out
}

/// What the backward of a block takes from the forward and the blending backward.
pub struct BackwardIn<'a> {
    /// The forward's clamped colour per lane.
    pub colors: &'a [Vec3],
    /// The screen-space gradient per lane.
    pub screen: &'a [ScreenGrad],
    /// Lanes not touched get zero gradients.
    pub touched: [bool; LANES],
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn backward_avx2(
    at: &Block,
    from: &BackwardIn,
    v_rest: &mut [Vec3],
    out: &mut [ParamGrad; LANES],
) {
    backward_body(at, from, v_rest, out);
}

#[allow(clippy::needless_range_loop)]
#[inline(always)]
fn backward_body(at: &Block, from: &BackwardIn, v_rest: &mut [Vec3], out: &mut [ParamGrad; LANES]) {
    let &Block {
        g,
        first,
        cam,
        sh_degree,
        antialiased,
    } = at;
    let &BackwardIn {
        colors,
        screen,
        touched,
    } = from;
    let count = screen.len();
    debug_assert!((1..=LANES).contains(&count) && colors.len() == count);
    let idx: [usize; LANES] = std::array::from_fn(|l| first + l.min(count - 1));
    let sl = |f: fn(&ScreenGrad) -> f32| F8(std::array::from_fn(|l| f(&screen[l.min(count - 1)])));
    let zero = F8::splat(0.0);
    let geo = geometry(g, &idx, cam);
    let [a, b, c] = geo.cov;
    let ab = a + COV2D_BLUR;
    let cb = c + COV2D_BLUR;
    let det_b = ab * cb - b * b;
    let inv = 1.0 / det_b;
    let (qa, qb, qc) = (cb * inv, -b * inv, ab * inv);

    // Conic -> blurred covariance: dCov = -Q V Q with V = [[va, vb/2], [vb/2, vc]].
    let (va, vb, vc) = (
        sl(|v| v.conic[0]),
        0.5 * sl(|v| v.conic[1]),
        sl(|v| v.conic[2]),
    );
    let qv00 = qa * va + qb * vb;
    let qv01 = qa * vb + qb * vc;
    let qv10 = qb * va + qc * vb;
    let qv11 = qb * vb + qc * vc;
    let h00 = -(qv00 * qa + qv01 * qb);
    let h01 = -(qv00 * qb + qv01 * qc);
    let h11 = -(qv10 * qb + qv11 * qc);
    let (mut ga, mut gb, mut gc) = (h00, 2.0 * h01, h11);

    // Opacity (and antialiasing compensation).
    let logit = lane(g, &idx, |g, i| g.logit_opacities[i]);
    let e = (-logit.abs()).exp();
    let sig = F8::select(logit.ge(zero), 1.0 / (1.0 + e), e / (1.0 + e));
    let v_op = sl(|v| v.opacity);
    let mut v_sig = v_op;
    if antialiased {
        let det = a * c - b * b;
        let r = det / det_b;
        let pos = r.gt(zero);
        let comp = r.sqrt();
        v_sig = F8::select(pos, v_op * comp, zero);
        let v_r = v_op * sig * 0.5 / comp;
        let k = det / (det_b * det_b);
        ga = F8::select(pos, ga + v_r * (c / det_b - k * cb), ga);
        gb = F8::select(pos, gb + v_r * (-2.0 * b / det_b + k * 2.0 * b), gb);
        gc = F8::select(pos, gc + v_r * (a / det_b - k * ab), gc);
    }
    let g_opacity = v_sig * sig * (1.0 - sig);

    // cov = [j0·C j0, j0·C j1, j1·C j1].
    let [j00, j02, j11, j12] = geo.j;
    let cm = &geo.c;
    let s0 = [
        cm[0][0] * j00 + cm[0][2] * j02,
        cm[1][0] * j00 + cm[1][2] * j02,
        cm[2][0] * j00 + cm[2][2] * j02,
    ];
    let s1 = [
        cm[0][1] * j11 + cm[0][2] * j12,
        cm[1][1] * j11 + cm[1][2] * j12,
        cm[2][1] * j11 + cm[2][2] * j12,
    ];
    let (ga2, gc2) = (2.0 * ga, 2.0 * gc);
    let v_j0 = [
        ga2 * s0[0] + gb * s1[0],
        ga2 * s0[1] + gb * s1[1],
        ga2 * s0[2] + gb * s1[2],
    ];
    let v_j1 = [
        gb * s0[0] + gc2 * s1[0],
        gb * s0[1] + gc2 * s1[1],
        gb * s0[2] + gc2 * s1[2],
    ];
    let j0 = [j00, zero, j02];
    let j1 = [zero, j11, j12];
    let mut v_cc = [[zero; 3]; 3];
    for r in 0..3 {
        for col in 0..3 {
            v_cc[r][col] = j0[r] * j0[col] * ga + j0[r] * j1[col] * gb + j1[r] * j1[col] * gc;
        }
    }
    // v_cov_world = Wᵀ v_cov_cam W, left to right.
    let w = cam.rotation;
    let wr = |a: usize, b: usize| w.col(b)[a];
    let mut x = [[zero; 3]; 3];
    for a in 0..3 {
        for b in 0..3 {
            x[a][b] = wr(0, a) * v_cc[0][b] + wr(1, a) * v_cc[1][b] + wr(2, a) * v_cc[2][b];
        }
    }
    let mut vcw = [[zero; 3]; 3];
    for a in 0..3 {
        for b in 0..3 {
            vcw[a][b] = x[a][0] * wr(0, b) + x[a][1] * wr(1, b) + x[a][2] * wr(2, b);
        }
    }
    // v_m = (v_cov_world + v_cov_worldᵀ) M.
    let mut sym = [[zero; 3]; 3];
    for a in 0..3 {
        for b in 0..3 {
            sym[a][b] = vcw[a][b] + vcw[b][a];
        }
    }
    let mm = &geo.m;
    let mut v_m = [[zero; 3]; 3];
    for a in 0..3 {
        for b in 0..3 {
            v_m[a][b] = sym[a][0] * mm[0][b] + sym[a][1] * mm[1][b] + sym[a][2] * mm[2][b];
        }
    }
    let sc = geo.scale;
    let mut v_rot = [[zero; 3]; 3];
    for a in 0..3 {
        for j in 0..3 {
            v_rot[a][j] = v_m[a][j] * sc[j];
        }
    }
    let rot = &geo.rot;
    let vs = |j: usize| rot[0][j] * v_m[0][j] + rot[1][j] * v_m[1][j] + rot[2][j] * v_m[2][j];
    let v_scale = [vs(0), vs(1), vs(2)];
    let g_log_scale = [v_scale[0] * sc[0], v_scale[1] * sc[1], v_scale[2] * sc[2]];
    // A quaternion without a length gets no gradient (as the scalar path returns early).
    let q_has_len = geo.qlen.gt(zero);
    let g_rot = rotation_backward(geo.qn, geo.qlen, &v_rot);
    let g_rot = [
        F8::select(q_has_len, g_rot[0], zero),
        F8::select(q_has_len, g_rot[1], zero),
        F8::select(q_has_len, g_rot[2], zero),
        F8::select(q_has_len, g_rot[3], zero),
    ];

    // Camera-space mean: through the mean projection and the Jacobian.
    let [px, py, pz] = geo.p_cam;
    let (fx, fy) = (cam.fx, cam.fy);
    let rz = 1.0 / pz;
    let rz2 = rz * rz;
    let rz3 = rz2 * rz;
    let (m2x, m2y) = (sl(|v| v.mean2d.x), sl(|v| v.mean2d.y));
    let mut vpx = m2x * fx * rz;
    let mut vpy = m2y * fy * rz;
    let mut vpz = -(m2x * fx * px + m2y * fy * py) * rz2 + sl(|v| v.depth);
    vpz = vpz + (-fx * rz2 * v_j0[0] - fy * rz2 * v_j1[1]);
    let [tx, ty] = geo.txy;
    let [clx, cly] = geo.clamped;
    vpx = F8::select(clx, vpx, vpx + -fx * rz2 * v_j0[2]);
    vpz = F8::select(
        clx,
        vpz + fx * tx * rz3 * v_j0[2],
        vpz + 2.0 * fx * tx * rz3 * v_j0[2],
    );
    vpy = F8::select(cly, vpy, vpy + -fy * rz2 * v_j1[2]);
    vpz = F8::select(
        cly,
        vpz + fy * ty * rz3 * v_j1[2],
        vpz + 2.0 * fy * ty * rz3 * v_j1[2],
    );
    // mean = Wᵀ v_pc.
    let gm = |a: usize| wr(0, a) * vpx + wr(1, a) * vpy + wr(2, a) * vpz;
    let mut g_mean = [gm(0), gm(1), gm(2)];

    // Colour: the clamp at zero passes gradient only where it did not clamp.
    let cam_pos = cam.position();
    let [mx, my, mz] = geo.mean;
    let raw = [mx - cam_pos.x, my - cam_pos.y, mz - cam_pos.z];
    let len = (raw[0] * raw[0] + raw[1] * raw[1] + raw[2] * raw[2]).sqrt();
    let has_len = len.gt(zero);
    let dir = [
        F8::select(has_len, raw[0] / len, zero),
        F8::select(has_len, raw[1] / len, zero),
        F8::select(has_len, raw[2] / len, zero),
    ];
    let fwd = |k: usize| F8(std::array::from_fn(|l| colors[l.min(count - 1)][k]));
    let v_color = [
        F8::select(fwd(0).gt(zero), sl(|v| v.color.x), zero),
        F8::select(fwd(1).gt(zero), sl(|v| v.color.y), zero),
        F8::select(fwd(2).gt(zero), sl(|v| v.color.z), zero),
    ];
    let basis = basis_of(sh_degree, dir);
    let g_dc = [
        zero + v_color[0] * basis[0],
        zero + v_color[1] * basis[0],
        zero + v_color[2] * basis[0],
    ];
    let rc = g.rest_count();
    let nb = crate::sh::num_bases(sh_degree);
    // Non-finite values poison this sum (`x · 0` is NaN for an infinite or NaN `x`): one test
    // for all of them at the end.
    let mut poison = zero;
    let mut g_rest = [[zero; 3]; 15];
    if sh_degree > 0 {
        let grad = basis_grad_of(sh_degree, dir);
        let mut v_d = [zero; 3];
        for k in 1..nb {
            let coef = |ch: usize| F8(std::array::from_fn(|l| g.sh_rest[idx[l] * rc + k - 1][ch]));
            let d = coef(0) * v_color[0] + coef(1) * v_color[1] + coef(2) * v_color[2];
            for ch in 0..3 {
                g_rest[k - 1][ch] = zero + v_color[ch] * basis[k];
                poison = poison + g_rest[k - 1][ch] * 0.0;
                v_d[ch] = v_d[ch] + grad[k][ch] * d;
            }
        }
        // mean += (v_dir − dir (dir · v_dir)) / len where the direction has a length.
        let dd = dir[0] * v_d[0] + dir[1] * v_d[1] + dir[2] * v_d[2];
        for ch in 0..3 {
            let add = (v_d[ch] - dir[ch] * dd) / len;
            g_mean[ch] = F8::select(has_len, g_mean[ch] + add, g_mean[ch]);
        }
    }

    // Degenerate inputs (e.g. overflowing scales) must not leak NaN/Inf into the optimiser.
    for v in g_mean.iter().chain(&g_log_scale).chain(&g_rot).chain(&g_dc) {
        poison = poison + *v * 0.0;
    }
    poison = poison + g_opacity * 0.0;
    let ok = M8(touched) & geo.valid & poison.is_finite();
    for l in 0..count {
        if !ok.0[l] {
            continue;
        }
        out[l] = ParamGrad {
            mean: Vec3::new(g_mean[0].0[l], g_mean[1].0[l], g_mean[2].0[l]),
            log_scale: Vec3::new(
                g_log_scale[0].0[l],
                g_log_scale[1].0[l],
                g_log_scale[2].0[l],
            ),
            rotation: [g_rot[0].0[l], g_rot[1].0[l], g_rot[2].0[l], g_rot[3].0[l]],
            logit_opacity: g_opacity.0[l],
            sh_dc: Vec3::new(g_dc[0].0[l], g_dc[1].0[l], g_dc[2].0[l]),
        };
        for k in 1..nb {
            v_rest[l * rc + k - 1] = Vec3::new(
                g_rest[k - 1][0].0[l],
                g_rest[k - 1][1].0[l],
                g_rest[k - 1][2].0[l],
            );
        }
    }
}

#[cfg(test)]
mod tests;
