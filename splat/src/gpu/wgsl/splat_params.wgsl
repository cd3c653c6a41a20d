// What the projection and its backward share: the camera, the chunk's splat parameters
// (`cam.cfg.z` floats each: mean, log-scale, quaternion, opacity logit, SH) and the reads of
// them both passes make, so that the backward differentiates exactly what the forward drew.

@group(0) @binding(0) var<uniform> cam: Camera;
@group(0) @binding(1) var<storage, read> params: array<f32>;
@group(0) @binding(5) var<uniform> chunk: Chunk;

fn param3(o: u32) -> vec3<f32> {
    return vec3<f32>(params[o], params[o + 1u], params[o + 2u]);
}

// The EWA geometry of the splat whose parameters start at `base`.
fn splat_geometry(base: u32) -> Geometry {
    return geometry(
        cam,
        param3(base),
        param3(base + 3u),
        vec4<f32>(params[base + 6u], params[base + 7u], params[base + 8u], params[base + 9u]),
    );
}

// The splat's colour seen along `dir` at the rendered SH degree, before the clamp at zero.
fn sh_color(base: u32, dir: vec3<f32>) -> vec3<f32> {
    let deg = cam.cfg.y;
    let b = sh_basis(deg, dir);
    var c = param3(base + 11u) * b[0];
    let nb = (deg + 1u) * (deg + 1u);
    for (var k = 1u; k < nb; k = k + 1u) {
        c = c + param3(base + 14u + 3u * (k - 1u)) * b[k];
    }
    return c + vec3<f32>(SH_COLOR_OFFSET);
}
