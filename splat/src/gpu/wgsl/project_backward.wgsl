// Backward of the projection, one invocation per Gaussian: screen-space gradients (summed over
// pixels by `isect_reduce`) to parameter gradients, laid out like the parameters. Mirrors
// `project::project_backward_one` and `sh::eval_backward`; a Gaussian no tile touched, or one
// whose gradients are not finite, gets zeros.

@group(0) @binding(2) var<storage, read> screen: array<f32>;
@group(0) @binding(3) var<storage, read> counts: array<u32>;
@group(0) @binding(4) var<storage, read_write> grads: array<f32>;

fn zero_all(base: u32) {
    for (var k = 0u; k < cam.cfg.z; k = k + 1u) {
        grads[base + k] = 0.0;
    }
}

// d basis_k / d direction (`sh::basis_grad`).
fn basis_grad(k: u32, d: vec3<f32>) -> vec3<f32> {
    let x = d.x;
    let y = d.y;
    let z = d.z;
    let xx = x * x;
    let yy = y * y;
    let zz = z * z;
    let a = SH_C3_C * zz + SH_C3_C0;
    switch k {
        case 1u: { return vec3<f32>(0.0, -SH_C1, 0.0); }
        case 2u: { return vec3<f32>(0.0, 0.0, SH_C1); }
        case 3u: { return vec3<f32>(-SH_C1, 0.0, 0.0); }
        case 4u: { return vec3<f32>(SH_C2_XY * y, SH_C2_XY * x, 0.0); }
        case 5u: { return vec3<f32>(0.0, -SH_C2_XY * z, -SH_C2_XY * y); }
        case 6u: { return vec3<f32>(0.0, 0.0, 2.0 * SH_C2_ZZ * z); }
        case 7u: { return vec3<f32>(-SH_C2_XY * z, 0.0, -SH_C2_XY * x); }
        case 8u: { return vec3<f32>(2.0 * SH_C2_XX * x, -2.0 * SH_C2_XX * y, 0.0); }
        case 9u: { return vec3<f32>(SH_C3_A * 6.0 * x * y, SH_C3_A * (3.0 * xx - 3.0 * yy), 0.0); }
        case 10u: { return vec3<f32>(SH_C3_B * 2.0 * z * y, SH_C3_B * 2.0 * z * x, SH_C3_B * 2.0 * x * y); }
        case 11u: { return vec3<f32>(0.0, a, 2.0 * SH_C3_C * z * y); }
        case 12u: { return vec3<f32>(0.0, 0.0, 3.0 * SH_C3_D * zz - SH_C3_D0); }
        case 13u: { return vec3<f32>(a, 0.0, 2.0 * SH_C3_C * z * x); }
        case 14u: { return vec3<f32>(2.0 * SH_C3_B * z * x, -2.0 * SH_C3_B * z * y, SH_C3_B * (xx - yy)); }
        case 15u: { return vec3<f32>(SH_C3_A * (3.0 * xx - 3.0 * yy), -SH_C3_A * 6.0 * x * y, 0.0); }
        default: { return vec3<f32>(0.0); }
    }
}

fn outer(u: vec3<f32>, w: vec3<f32>) -> mat3x3<f32> {
    return mat3x3<f32>(u * w.x, u * w.y, u * w.z);
}

@compute @workgroup_size(256)
fn main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) li: u32,
) {
    let local = linear_group(wid, nwg) * 256u + li;
    if (local >= chunk.count) {
        return;
    }
    let i = chunk.first + local;
    let stride = cam.cfg.z;
    let base = local * stride;
    if (counts[i] == 0u) {
        zero_all(base);
        return;
    }
    let mean = param3(base);
    let geo = splat_geometry(base);
    if (!geo.valid) {
        zero_all(base);
        return;
    }
    let wr = transpose(mat3x3<f32>(cam.r0.xyz, cam.r1.xyz, cam.r2.xyz));
    let p_cam = geo.p_cam;
    let z = p_cam.z;
    let rot = geo.q.rot;
    let qn = geo.q.qn;
    let qlen = geo.q.len;
    let scale = geo.scale;
    let mm = geo.mm;
    let tx = geo.txy.x;
    let ty = geo.txy.y;
    let rz = 1.0 / z;
    let rz2 = rz * rz;
    let rz3 = rz2 * rz;
    let fx = cam.intr.x;
    let fy = cam.intr.y;
    let j0 = geo.j0;
    let j1 = geo.j1;
    let s0 = geo.cov_cam * j0;
    let s1 = geo.cov_cam * j1;
    let a = geo.cov.x;
    let b = geo.cov.y;
    let c = geo.cov.z;
    let ab = a + COV2D_BLUR;
    let cb = c + COV2D_BLUR;
    let det_b = ab * cb - b * b;
    let inv = 1.0 / det_b;
    let qa = cb * inv;
    let qb = -b * inv;
    let qc = ab * inv;

    let so = i * 12u;
    let v_mean2d = vec2<f32>(screen[so], screen[so + 1u]);
    let va = screen[so + 4u];
    let vb = 0.5 * screen[so + 5u];
    let vc = screen[so + 6u];
    let v_col = vec3<f32>(screen[so + 7u], screen[so + 8u], screen[so + 9u]);
    let v_opacity = screen[so + 10u];
    let v_depth = screen[so + 11u];

    // Conic -> blurred covariance: dCov = -Q V Q.
    let qv00 = qa * va + qb * vb;
    let qv01 = qa * vb + qb * vc;
    let qv10 = qb * va + qc * vb;
    let qv11 = qb * vb + qc * vc;
    var ga = -(qv00 * qa + qv01 * qb);
    var gb = 2.0 * -(qv00 * qb + qv01 * qc);
    var gc = -(qv10 * qb + qv11 * qc);

    let sig = 1.0 / (1.0 + exp(-params[base + 10u]));
    var v_sig = v_opacity;
    if (cam.cfg.w != 0u) {
        let det = a * c - b * b;
        let r = det / det_b;
        if (r > 0.0) {
            let comp = sqrt(r);
            v_sig = v_opacity * comp;
            let v_r = v_opacity * sig * 0.5 / comp;
            let k = det / (det_b * det_b);
            ga = ga + v_r * (c / det_b - k * cb);
            gb = gb + v_r * (-2.0 * b / det_b + k * 2.0 * b);
            gc = gc + v_r * (a / det_b - k * ab);
        } else {
            v_sig = 0.0;
        }
    }
    let g_opacity = v_sig * sig * (1.0 - sig);

    let v_j0 = 2.0 * ga * s0 + gb * s1;
    let v_j1 = gb * s0 + 2.0 * gc * s1;
    let v_cov_cam = outer(j0, j0) * ga + outer(j0, j1) * gb + outer(j1, j1) * gc;
    let v_cov_world = transpose(wr) * v_cov_cam * wr;
    let v_m = (v_cov_world + transpose(v_cov_world)) * mm;
    let v_rot = mat3x3<f32>(v_m[0] * scale.x, v_m[1] * scale.y, v_m[2] * scale.z);
    let v_scale = vec3<f32>(dot(rot[0], v_m[0]), dot(rot[1], v_m[1]), dot(rot[2], v_m[2]));
    let g_log_scale = v_scale * scale;

    // Quaternion (`project::quat_to_rotmat_backward`); g(i, j) = dL/dR[row i][col j].
    var g_quat = vec4<f32>(0.0);
    if (qlen > 0.0) {
        let w = qn.x;
        let x = qn.y;
        let y = qn.z;
        let zq = qn.w;
        let g00 = v_rot[0][0];
        let g10 = v_rot[0][1];
        let g20 = v_rot[0][2];
        let g01 = v_rot[1][0];
        let g11 = v_rot[1][1];
        let g21 = v_rot[1][2];
        let g02 = v_rot[2][0];
        let g12 = v_rot[2][1];
        let g22 = v_rot[2][2];
        let vw = 2.0 * (x * (g21 - g12) + y * (g02 - g20) + zq * (g10 - g01));
        let vx = 2.0 * (y * (g01 + g10) + zq * (g02 + g20) + w * (g21 - g12)) - 4.0 * x * (g11 + g22);
        let vy = 2.0 * (x * (g01 + g10) + w * (g02 - g20) + zq * (g12 + g21)) - 4.0 * y * (g00 + g22);
        let vz = 2.0 * (w * (g10 - g01) + x * (g02 + g20) + y * (g12 + g21)) - 4.0 * zq * (g00 + g11);
        let v = vec4<f32>(vw, vx, vy, vz);
        g_quat = (v - qn * dot(v, qn)) / qlen;
    }

    // Camera-space mean, through the mean projection and the Jacobian.
    var v_pc = vec3<f32>(
        v_mean2d.x * fx * rz,
        v_mean2d.y * fy * rz,
        -(v_mean2d.x * fx * p_cam.x + v_mean2d.y * fy * p_cam.y) * rz2 + v_depth,
    );
    v_pc.z = v_pc.z + (-fx * rz2 * v_j0.x - fy * rz2 * v_j1.y);
    if (geo.clamped_x) {
        v_pc.z = v_pc.z + fx * tx * rz3 * v_j0.z;
    } else {
        v_pc.x = v_pc.x - fx * rz2 * v_j0.z;
        v_pc.z = v_pc.z + 2.0 * fx * tx * rz3 * v_j0.z;
    }
    if (geo.clamped_y) {
        v_pc.z = v_pc.z + fy * ty * rz3 * v_j1.z;
    } else {
        v_pc.y = v_pc.y - fy * rz2 * v_j1.z;
        v_pc.z = v_pc.z + 2.0 * fy * ty * rz3 * v_j1.z;
    }
    var g_mean = transpose(wr) * v_pc;

    // Colour: the clamp at zero passes gradient only where it did not clamp.
    let deg = cam.cfg.y;
    let raw = mean - cam.pos.xyz;
    let len = length(raw);
    var dir = vec3<f32>(0.0);
    if (len > 0.0) {
        dir = raw / len;
    }
    let bs = sh_basis(deg, dir);
    let nb = (deg + 1u) * (deg + 1u);
    let pre = sh_color(base, dir);
    let v_color = select(vec3<f32>(0.0), v_col, pre > vec3<f32>(0.0));
    let g_dc = v_color * bs[0];
    var v_dir = vec3<f32>(0.0);
    var ok = true;
    for (var k = 1u; k < nb; k = k + 1u) {
        let o = base + 14u + 3u * (k - 1u);
        let gr = v_color * bs[k];
        ok = ok && finite3(gr);
        grads[o] = gr.x;
        grads[o + 1u] = gr.y;
        grads[o + 2u] = gr.z;
        v_dir = v_dir + basis_grad(k, dir) * dot(param3(o), v_color);
    }
    for (var k = 14u + 3u * (nb - 1u); k < stride; k = k + 1u) {
        grads[base + k] = 0.0;
    }
    if (len > 0.0 && deg > 0u) {
        g_mean = g_mean + (v_dir - dir * dot(dir, v_dir)) / len;
    }

    // Degenerate inputs (e.g. overflowing scales) must not leak NaN/Inf into the optimiser.
    ok = ok && finite3(g_mean) && finite3(g_log_scale) && finite(g_quat.x) && finite(g_quat.y)
        && finite(g_quat.z) && finite(g_quat.w) && finite(g_opacity) && finite3(g_dc);
    if (!ok) {
        zero_all(base);
        return;
    }
    grads[base] = g_mean.x;
    grads[base + 1u] = g_mean.y;
    grads[base + 2u] = g_mean.z;
    grads[base + 3u] = g_log_scale.x;
    grads[base + 4u] = g_log_scale.y;
    grads[base + 5u] = g_log_scale.z;
    grads[base + 6u] = g_quat.x;
    grads[base + 7u] = g_quat.y;
    grads[base + 8u] = g_quat.z;
    grads[base + 9u] = g_quat.w;
    grads[base + 10u] = g_opacity;
    grads[base + 11u] = g_dc.x;
    grads[base + 12u] = g_dc.y;
    grads[base + 13u] = g_dc.z;
}
