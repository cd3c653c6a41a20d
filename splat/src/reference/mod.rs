//! Brute-force float64 renderer: no tiles, no radius, no culling beyond the depth range and the
//! per-pixel α rule; every pixel looks at every Gaussian sorted by (depth, index). Written
//! independently of the crate's kernels (INRIA-form SH polynomials, explicit matrix algebra,
//! its own literal constants), so that every fast renderer — this crate's tiled CPU one, the
//! GPU one — can be tested against it from any crate. Slow by design: test scenes only.
//!
//! Beside it, the CPU kernels' slow, obvious twins in float32: [`scalar_project`] (one
//! Gaussian at a time) and [`scalar_blend`] (one pixel at a time, with branches). The fast
//! kernels in [`crate::cpu`] are tested against them within float32 rounding, and they against
//! the float64 renderer.

// Index loops read like the matrix algebra they implement.
#![allow(clippy::needless_range_loop)]

pub mod scalar_blend;
pub mod scalar_project;

use crate::{Camera, Gaussians, RenderSettings, sh_rest_count};

/// Parameters per Gaussian in the layout of [`flatten`].
pub fn params_per_gaussian(sh_degree: u32) -> usize {
    14 + 3 * sh_rest_count(sh_degree)
}

/// All parameters of `g` in f64, Gaussian by Gaussian: mean, log-scale, quaternion, logit
/// opacity, SH DC, SH rest (coefficient-major, RGB innermost).
pub fn flatten(g: &Gaussians) -> Vec<f64> {
    g.packed().into_iter().map(f64::from).collect()
}

/// Renders `g` as [`crate::render`] would, in f64.
pub fn render_reference(g: &Gaussians, cam: &Camera, settings: &RenderSettings) -> RefImage {
    render_ref(
        &flatten(g),
        g.sh_degree,
        &RefCamera::from(cam),
        settings.sh_degree,
        settings.background.to_array().map(f64::from),
        settings.antialiased,
    )
}

pub struct RefCamera {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub width: usize,
    pub height: usize,
    pub r: [[f64; 3]; 3],
    pub t: [f64; 3],
    pub near: f64,
    pub far: f64,
}

impl RefCamera {
    pub fn from(cam: &Camera) -> Self {
        let mut r = [[0.0; 3]; 3];
        for (i, row) in r.iter_mut().enumerate() {
            for (j, v) in row.iter_mut().enumerate() {
                *v = cam.rotation.col(j)[i] as f64;
            }
        }
        Self {
            fx: cam.fx as f64,
            fy: cam.fy as f64,
            cx: cam.cx as f64,
            cy: cam.cy as f64,
            width: cam.width as usize,
            height: cam.height as usize,
            r,
            t: cam.translation.to_array().map(f64::from),
            near: cam.near as f64,
            far: cam.far as f64,
        }
    }
}

pub struct RefImage {
    pub color: Vec<[f64; 3]>,
    pub alpha: Vec<f64>,
    pub depth: Vec<f64>,
    /// Smallest relative distance of any decision (α thresholds, transmittance stop, frustum
    /// clamp, colour clamp, near plane) from its threshold; finite differences are only valid
    /// when this is comfortably larger than the perturbation.
    pub margin: f64,
}

type M3 = [[f64; 3]; 3];

fn matmul(a: &M3, b: &M3) -> M3 {
    let mut c = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            for k in 0..3 {
                c[i][j] += a[i][k] * b[k][j];
            }
        }
    }
    c
}

fn transpose(a: &M3) -> M3 {
    let mut c = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            c[i][j] = a[j][i];
        }
    }
    c
}

fn sh_color(deg: u32, coeffs: &[[f64; 3]], d: [f64; 3]) -> [f64; 3] {
    const C0: f64 = 0.28209479177387814;
    const C1: f64 = 0.4886025119029199;
    const C2: [f64; 5] = [
        1.0925484305920792,
        -1.0925484305920792,
        0.31539156525252005,
        -1.0925484305920792,
        0.5462742152960396,
    ];
    const C3: [f64; 7] = [
        -0.5900435899266435,
        2.890611442640554,
        -0.4570457994644658,
        0.3731763325901154,
        -0.4570457994644658,
        1.445305721320277,
        -0.5900435899266435,
    ];
    let [x, y, z] = d;
    let (xx, yy, zz) = (x * x, y * y, z * z);
    let mut b = vec![C0];
    if deg >= 1 {
        b.extend([-C1 * y, C1 * z, -C1 * x]);
    }
    if deg >= 2 {
        b.extend([
            C2[0] * x * y,
            C2[1] * y * z,
            C2[2] * (2.0 * zz - xx - yy),
            C2[3] * x * z,
            C2[4] * (xx - yy),
        ]);
    }
    if deg >= 3 {
        b.extend([
            C3[0] * y * (3.0 * xx - yy),
            C3[1] * x * y * z,
            C3[2] * y * (4.0 * zz - xx - yy),
            C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy),
            C3[4] * x * (4.0 * zz - xx - yy),
            C3[5] * z * (xx - yy),
            C3[6] * x * (xx - 3.0 * yy),
        ]);
    }
    let mut c = [0.5; 3];
    for (k, bk) in b.iter().enumerate() {
        for ch in 0..3 {
            c[ch] += bk * coeffs[k][ch];
        }
    }
    c
}

/// A Gaussian projected to the screen in float64.
pub struct RefSplat {
    pub mean: [f64; 2],
    pub conic: [f64; 3],
    pub opacity: f64,
    pub color: [f64; 3],
    pub depth: f64,
    /// Smallest relative distance of its decisions (near plane, frustum clamp, colour clamp)
    /// from their thresholds.
    pub margin: f64,
}

/// Projects one Gaussian (its parameters `p` in the layout of [`flatten`]); `None` outside the
/// depth range.
pub fn project_ref(
    p: &[f64],
    stored_deg: u32,
    cam: &RefCamera,
    deg: u32,
    antialiased: bool,
) -> Option<RefSplat> {
    let mut margin = f64::INFINITY;
    let rt = transpose(&cam.r);
    let cam_pos = [
        -(rt[0][0] * cam.t[0] + rt[0][1] * cam.t[1] + rt[0][2] * cam.t[2]),
        -(rt[1][0] * cam.t[0] + rt[1][1] * cam.t[1] + rt[1][2] * cam.t[2]),
        -(rt[2][0] * cam.t[0] + rt[2][1] * cam.t[1] + rt[2][2] * cam.t[2]),
    ];
    let mean = [p[0], p[1], p[2]];
    let mut pc = cam.t;
    for a in 0..3 {
        for b in 0..3 {
            pc[a] += cam.r[a][b] * mean[b];
        }
    }
    let z = pc[2];
    if z < cam.near || z > cam.far {
        return None;
    }
    margin = margin.min((z - cam.near) / cam.near);
    let qn = (p[6] * p[6] + p[7] * p[7] + p[8] * p[8] + p[9] * p[9]).sqrt();
    let (w, x, y, zq) = (p[6] / qn, p[7] / qn, p[8] / qn, p[9] / qn);
    let rot = [
        [
            1.0 - 2.0 * (y * y + zq * zq),
            2.0 * (x * y - w * zq),
            2.0 * (x * zq + w * y),
        ],
        [
            2.0 * (x * y + w * zq),
            1.0 - 2.0 * (x * x + zq * zq),
            2.0 * (y * zq - w * x),
        ],
        [
            2.0 * (x * zq - w * y),
            2.0 * (y * zq + w * x),
            1.0 - 2.0 * (x * x + y * y),
        ],
    ];
    let s = [p[3].exp(), p[4].exp(), p[5].exp()];
    let mut m = rot;
    for row in m.iter_mut() {
        for j in 0..3 {
            row[j] *= s[j];
        }
    }
    let sigma = matmul(&m, &transpose(&m));
    let sc = matmul(&matmul(&cam.r, &sigma), &rt);
    let tan_x = 0.5 * cam.width as f64 / cam.fx;
    let tan_y = 0.5 * cam.height as f64 / cam.fy;
    let lims = [
        cam.cx / cam.fx + 0.3 * tan_x,
        (cam.width as f64 - cam.cx) / cam.fx + 0.3 * tan_x,
        cam.cy / cam.fy + 0.3 * tan_y,
        (cam.height as f64 - cam.cy) / cam.fy + 0.3 * tan_y,
    ];
    let (ux, uy) = (pc[0] / z, pc[1] / z);
    for (u, lo, hi) in [(ux, lims[0], lims[1]), (uy, lims[2], lims[3])] {
        margin = margin.min((u + lo).abs() / lo).min((u - hi).abs() / hi);
    }
    let tx = z * ux.clamp(-lims[0], lims[1]);
    let ty = z * uy.clamp(-lims[2], lims[3]);
    let j = [
        [cam.fx / z, 0.0, -cam.fx * tx / (z * z)],
        [0.0, cam.fy / z, -cam.fy * ty / (z * z)],
    ];
    let mut cov = [[0.0; 2]; 2];
    for a in 0..2 {
        for b in 0..2 {
            for k in 0..3 {
                for l in 0..3 {
                    cov[a][b] += j[a][k] * sc[k][l] * j[b][l];
                }
            }
        }
    }
    let det0 = cov[0][0] * cov[1][1] - cov[0][1] * cov[1][0];
    let (a, b, c) = (cov[0][0] + 0.3, cov[0][1], cov[1][1] + 0.3);
    let det = a * c - b * b;
    let mut opacity = 1.0 / (1.0 + (-p[10]).exp());
    if antialiased {
        opacity *= (det0 / det).max(0.0).sqrt();
    }
    let dir_raw = [
        mean[0] - cam_pos[0],
        mean[1] - cam_pos[1],
        mean[2] - cam_pos[2],
    ];
    let len = (dir_raw[0].powi(2) + dir_raw[1].powi(2) + dir_raw[2].powi(2)).sqrt();
    let dir = dir_raw.map(|v| v / len);
    let mut coeffs = vec![[p[11], p[12], p[13]]];
    for k in 0..(sh_rest_count(stored_deg)) {
        coeffs.push([p[14 + 3 * k], p[15 + 3 * k], p[16 + 3 * k]]);
    }
    let pre = sh_color(deg, &coeffs, dir);
    for v in pre {
        margin = margin.min(v.abs());
    }
    Some(RefSplat {
        mean: [cam.fx * pc[0] / z + cam.cx, cam.fy * pc[1] / z + cam.cy],
        conic: [c / det, -b / det, a / det],
        opacity,
        color: pre.map(|v| v.max(0.0)),
        depth: z,
        margin,
    })
}

/// Renders flattened parameters (layout of [`flatten`]) with stored degree `stored_deg`.
pub fn render_ref(
    params: &[f64],
    stored_deg: u32,
    cam: &RefCamera,
    deg: u32,
    background: [f64; 3],
    antialiased: bool,
) -> RefImage {
    let ppg = params_per_gaussian(stored_deg);
    let n = params.len() / ppg;
    let mut margin = f64::INFINITY;
    let mut splats = Vec::new();
    for i in 0..n {
        let p = &params[i * ppg..(i + 1) * ppg];
        let Some(r) = project_ref(p, stored_deg, cam, deg, antialiased) else {
            continue;
        };
        margin = margin.min(r.margin);
        splats.push((i, r));
    }
    splats.sort_by(|(i, a), (j, b)| a.depth.total_cmp(&b.depth).then(i.cmp(j)));

    let npix = cam.width * cam.height;
    let mut img = RefImage {
        color: vec![[0.0; 3]; npix],
        alpha: vec![0.0; npix],
        depth: vec![0.0; npix],
        margin,
    };
    let thr = 1.0 / 255.0;
    for py in 0..cam.height {
        for px in 0..cam.width {
            let q = [px as f64 + 0.5, py as f64 + 0.5];
            let mut t = 1.0;
            let mut col = [0.0; 3];
            let mut dep = 0.0;
            for (_, s) in &splats {
                let d = [s.mean[0] - q[0], s.mean[1] - q[1]];
                let sig = 0.5 * (s.conic[0] * d[0] * d[0] + s.conic[2] * d[1] * d[1])
                    + s.conic[1] * d[0] * d[1];
                if sig < 0.0 {
                    continue;
                }
                let raw = s.opacity * (-sig).exp();
                img.margin = img
                    .margin
                    .min((raw - thr).abs() / thr)
                    .min((raw - 0.99).abs());
                let alpha = raw.min(0.99);
                if alpha < thr {
                    continue;
                }
                let next = t * (1.0 - alpha);
                img.margin = img.margin.min((next - 1e-4).abs() / 1e-4);
                if next <= 1e-4 {
                    break;
                }
                for ch in 0..3 {
                    col[ch] += s.color[ch] * alpha * t;
                }
                dep += s.depth * alpha * t;
                t = next;
            }
            let i = py * cam.width + px;
            let a = 1.0 - t;
            img.color[i] = [0, 1, 2].map(|ch| col[ch] + t * background[ch]);
            img.alpha[i] = a;
            img.depth[i] = if a > 0.0 { dep / a } else { 0.0 };
        }
    }
    img
}
