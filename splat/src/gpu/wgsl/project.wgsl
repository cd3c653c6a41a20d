// Projection and culling, one invocation per Gaussian: the EWA footprint, opacity-aware
// radius, SH colour and the number of 16×16 tiles the footprint touches. Mirrors `project.rs`.

@group(0) @binding(2) var<storage, read_write> proj: array<f32>;
@group(0) @binding(3) var<storage, read_write> counts: array<u32>;
@group(0) @binding(4) var<storage, read_write> radii: array<f32>;

fn cull(i: u32) {
    counts[i] = 0u;
    radii[2u * i] = 0.0;
    radii[2u * i + 1u] = 0.0;
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
    let base = local * cam.cfg.z;
    let mean = param3(base);
    let geo = splat_geometry(base);
    if (!geo.valid) {
        cull(i);
        return;
    }
    let p_cam = geo.p_cam;
    let z = p_cam.z;
    let ca = geo.cov.x;
    let cb = geo.cov.y;
    let cc = geo.cov.z;
    let ab = ca + COV2D_BLUR;
    let cbb = cc + COV2D_BLUR;
    let det_b = ab * cbb - cb * cb;
    if (!(finite(det_b) && det_b > 0.0)) {
        cull(i);
        return;
    }
    var opacity = 1.0 / (1.0 + exp(-params[base + 10u]));
    if (cam.cfg.w != 0u) {
        let det = ca * cc - cb * cb;
        opacity = opacity * sqrt(max(det / det_b, 0.0));
    }
    if (!(opacity == opacity) || opacity < ALPHA_THRESHOLD) {
        cull(i);
        return;
    }
    let extent = min(MAX_EXTENT_SIGMAS, sqrt(2.0 * log(opacity / ALPHA_THRESHOLD)));
    let rad_x = ceil(extent * sqrt(ab));
    let rad_y = ceil(extent * sqrt(cbb));
    let mx = cam.intr.x * p_cam.x / z + cam.intr.z;
    let my = cam.intr.y * p_cam.y / z + cam.intr.w;
    let w = f32(cam.dims.x);
    let h = f32(cam.dims.y);
    if (!(mx + rad_x > 0.0 && mx - rad_x < w && my + rad_y > 0.0 && my - rad_y < h)) {
        cull(i);
        return;
    }
    let inv = 1.0 / det_b;
    let conic = vec3<f32>(cbb * inv, -cb * inv, ab * inv);
    if (!finite3(conic)) {
        cull(i);
        return;
    }
    var color: vec3<f32>;
    if (cam.cfg.y == 0u) {
        color = param3(base + 11u) * SH_C0 + vec3<f32>(SH_COLOR_OFFSET);
    } else {
        let v = mean - cam.pos.xyz;
        let rcp = 1.0 / length(v);
        var dir = vec3<f32>(0.0);
        if (finite(rcp) && rcp > 0.0) {
            dir = v * rcp;
        }
        color = sh_color(base, dir);
    }
    color = max(color, vec3<f32>(0.0));
    if (!finite3(color)) {
        cull(i);
        return;
    }
    let big = 1073741824.0;
    let r = vec2<f32>(min(rad_x, big), min(rad_y, big));
    let o = i * PROJ_STRIDE;
    proj[o] = mx;
    proj[o + 1u] = my;
    proj[o + 2u] = conic.x;
    proj[o + 3u] = conic.y;
    proj[o + 4u] = conic.z;
    proj[o + 5u] = z;
    proj[o + 6u] = opacity;
    proj[o + 7u] = color.x;
    proj[o + 8u] = color.y;
    proj[o + 9u] = color.z;
    proj[o + 10u] = r.x;
    proj[o + 11u] = r.y;
    radii[2u * i] = r.x;
    radii[2u * i + 1u] = r.y;
    let rect = tile_rect(vec2<f32>(mx, my), r, cam.dims.z, cam.dims.w);
    counts[i] = (rect.y - rect.x) * (rect.w - rect.z);
}
