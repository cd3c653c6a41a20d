// Backward of the blending, one 16×16 workgroup per tile (as `raster::backward_tile`): splats
// are visited back to front; each pixel undoes its blending step (recovering T by division)
// and computes its contribution to the splat's screen-space gradient. The 256 pixel
// contributions are summed in a fixed order in workgroup memory (16 row sums, then their sum)
// and written to the (tile, splat) pair's own slot: no atomics, so the result is
// deterministic; a splat no pixel of the tile blended skips the sums.
//
// Slot layout (12 floats): ∂mean2d (2), Σ|∂mean2d| (2), ∂conic (3), ∂colour (3), ∂opacity,
// ∂depth.

@group(0) @binding(0) var<uniform> cam: Camera;
@group(0) @binding(1) var<storage, read> proj: array<f32>;
@group(0) @binding(2) var<storage, read> values: array<u32>;
@group(0) @binding(3) var<storage, read> owner: array<u32>;
@group(0) @binding(4) var<storage, read> ranges: array<u32>;
@group(0) @binding(5) var<storage, read> state: array<u32>;
@group(0) @binding(6) var<storage, read> images: array<f32>;
@group(0) @binding(7) var<storage, read> pix: array<f32>;
@group(0) @binding(8) var<storage, read_write> isect: array<f32>;

var<workgroup> red0: array<vec4<f32>, 256>;
var<workgroup> red1: array<vec4<f32>, 256>;
var<workgroup> red2: array<vec4<f32>, 256>;
var<workgroup> row0: array<vec4<f32>, 16>;
var<workgroup> row1: array<vec4<f32>, 16>;
var<workgroup> row2: array<vec4<f32>, 16>;
var<workgroup> w_start: u32;
var<workgroup> w_max_last: atomic<u32>;
var<workgroup> w_last_u: u32;
var<workgroup> w_any: atomic<u32>;
var<workgroup> w_flag: u32;

@compute @workgroup_size(16, 16)
fn main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(local_invocation_id) lid: vec3<u32>,
    @builtin(local_invocation_index) li: u32,
) {
    let w = cam.dims.x;
    let h = cam.dims.y;
    let np = w * h;
    let tile = wid.y * cam.dims.z + wid.x;
    let px = wid.x * TILE_SIZE + lid.x;
    let py = wid.y * TILE_SIZE + lid.y;
    let inside = px < w && py < h;
    let q = vec2<f32>(f32(px) + 0.5, f32(py) + 0.5);
    if (li == 0u) {
        w_start = ranges[2u * tile];
        atomicStore(&w_max_last, 0u);
        atomicStore(&w_any, 0u);
    }
    workgroupBarrier();

    var tr = 0.0;
    var last = 0u;
    var vc = vec3<f32>(0.0);
    var u = 0.0;
    var v_final = 0.0;
    if (inside) {
        let p = py * w + px;
        tr = bitcast<f32>(state[p]);
        last = state[np + p];
        vc = vec3<f32>(pix[3u * p], pix[3u * p + 1u], pix[3u * p + 2u]);
        let va = pix[3u * np + p];
        let vd = pix[4u * np + p];
        let a_out = 1.0 - tr;
        if (a_out > 0.0) {
            u = vd / a_out;
        }
        v_final = tr * (va - dot(cam.bg.xyz, vc) - u * images[4u * np + p]);
        atomicMax(&w_max_last, last);
    }
    let start = workgroupUniformLoad(&w_start);
    if (li == 0u) {
        w_last_u = atomicLoad(&w_max_last);
    }
    let max_last = workgroupUniformLoad(&w_last_u);

    var behind = vec3<f32>(0.0);
    var behind_z = 0.0;
    for (var kk = 0u; kk < max_last; kk = kk + 1u) {
        let k = max_last - 1u - kk;
        let e = values[start + k];
        let o = owner[e] * PROJ_STRIDE;
        let mean = vec2<f32>(proj[o], proj[o + 1u]);
        let cn = vec3<f32>(proj[o + 2u], proj[o + 3u], proj[o + 4u]);
        let z = proj[o + 5u];
        let op = proj[o + 6u];
        let col = vec3<f32>(proj[o + 7u], proj[o + 8u], proj[o + 9u]);
        var g0 = vec4<f32>(0.0);
        var g1 = vec4<f32>(0.0);
        var g2 = vec4<f32>(0.0);
        if (inside && k < last) {
            let d = mean - q;
            let sigma = 0.5 * (cn.x * d.x * d.x + cn.z * d.y * d.y) + cn.y * d.x * d.y;
            let vis = exp(-sigma);
            let raw = op * vis;
            let alpha = min(MAX_ALPHA, raw);
            if (sigma >= 0.0 && alpha >= ALPHA_THRESHOLD) {
                let ra = 1.0 / (1.0 - alpha);
                tr = tr * ra;
                let fac = alpha * tr;
                let gc = vc * fac;
                let gd = u * fac;
                let v_alpha = dot(col * tr - behind * ra, vc) + (z * tr - behind_z * ra) * u
                    + ra * v_final;
                behind = behind + col * fac;
                behind_z = behind_z + z * fac;
                var vm = vec2<f32>(0.0);
                var gcn = vec3<f32>(0.0);
                var gop = 0.0;
                if (raw <= MAX_ALPHA) {
                    let v_sigma = -raw * v_alpha;
                    gcn = vec3<f32>(0.5 * v_sigma * d.x * d.x, v_sigma * d.x * d.y, 0.5 * v_sigma * d.y * d.y);
                    vm = vec2<f32>(v_sigma * (cn.x * d.x + cn.y * d.y), v_sigma * (cn.y * d.x + cn.z * d.y));
                    gop = vis * v_alpha;
                }
                g0 = vec4<f32>(vm, abs(vm));
                g1 = vec4<f32>(gcn, gc.x);
                g2 = vec4<f32>(gc.y, gc.z, gop, gd);
                atomicStore(&w_any, 1u);
            }
        }
        red0[li] = g0;
        red1[li] = g1;
        red2[li] = g2;
        workgroupBarrier();
        if (li == 0u) {
            w_flag = atomicLoad(&w_any);
            atomicStore(&w_any, 0u);
        }
        // Barriers are what this kernel pays for (each splat of the tile costs two, three when
        // some pixel blended it), so the sums take two levels rather than a tree of eight.
        if (workgroupUniformLoad(&w_flag) != 0u) {
            if (li < 16u) {
                var s0 = vec4<f32>(0.0);
                var s1 = vec4<f32>(0.0);
                var s2 = vec4<f32>(0.0);
                for (var c = 0u; c < 16u; c = c + 1u) {
                    s0 = s0 + red0[li * 16u + c];
                    s1 = s1 + red1[li * 16u + c];
                    s2 = s2 + red2[li * 16u + c];
                }
                row0[li] = s0;
                row1[li] = s1;
                row2[li] = s2;
            }
            workgroupBarrier();
            if (li == 0u) {
                var a0 = vec4<f32>(0.0);
                var a1 = vec4<f32>(0.0);
                var a2 = vec4<f32>(0.0);
                for (var r = 0u; r < 16u; r = r + 1u) {
                    a0 = a0 + row0[r];
                    a1 = a1 + row1[r];
                    a2 = a2 + row2[r];
                }
                let b = e * 12u;
                isect[b] = a0.x;
                isect[b + 1u] = a0.y;
                isect[b + 2u] = a0.z;
                isect[b + 3u] = a0.w;
                isect[b + 4u] = a1.x;
                isect[b + 5u] = a1.y;
                isect[b + 6u] = a1.z;
                isect[b + 7u] = a1.w;
                isect[b + 8u] = a2.x;
                isect[b + 9u] = a2.y;
                isect[b + 10u] = a2.z;
                isect[b + 11u] = a2.w;
            }
        }
    }
}
