// Front-to-back blending, one 16×16 workgroup per tile: the tile's sorted splats are loaded
// into workgroup memory 256 at a time and every pixel applies the CPU's rule (`raster.rs`):
// skip σ < 0 and α < 1/255, cap α at 0.99, stop before a splat that would bring the
// transmittance to 1e-4 or below.

@group(0) @binding(0) var<uniform> cam: Camera;
@group(0) @binding(1) var<storage, read> proj: array<f32>;
@group(0) @binding(2) var<storage, read> values: array<u32>;
@group(0) @binding(3) var<storage, read> ranges: array<u32>;
@group(0) @binding(4) var<storage, read_write> out: array<f32>;
@group(0) @binding(5) var<storage, read_write> state: array<u32>;
@group(0) @binding(6) var<storage, read_write> stats: array<atomic<u32>>;
@group(0) @binding(7) var<storage, read> owner: array<u32>;

var<workgroup> s_mean: array<vec2<f32>, 256>;
var<workgroup> s_conic: array<vec4<f32>, 256>;
var<workgroup> s_color: array<vec4<f32>, 256>;
var<workgroup> w_start: u32;
var<workgroup> w_end: u32;
var<workgroup> w_done: u32;
var<workgroup> n_done: atomic<u32>;

@compute @workgroup_size(16, 16)
fn main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(local_invocation_id) lid: vec3<u32>,
    @builtin(local_invocation_index) li: u32,
) {
    let w = cam.dims.x;
    let h = cam.dims.y;
    let tile = wid.y * cam.dims.z + wid.x;
    let px = wid.x * TILE_SIZE + lid.x;
    let py = wid.y * TILE_SIZE + lid.y;
    let inside = px < w && py < h;
    let q = vec2<f32>(f32(px) + 0.5, f32(py) + 0.5);
    if (li == 0u) {
        w_start = ranges[2u * tile];
        w_end = ranges[2u * tile + 1u];
        atomicStore(&n_done, 0u);
    }
    let start = workgroupUniformLoad(&w_start);
    let end = workgroupUniformLoad(&w_end);

    var tr = 1.0;
    var color = vec3<f32>(0.0);
    var depth = 0.0;
    var last = 0u;
    var blended = 0u;
    var done = !inside;
    if (done) {
        atomicAdd(&n_done, 1u);
    }
    for (var b = start; b < end; b = b + 256u) {
        let idx = b + li;
        if (idx < end) {
            let o = owner[values[idx]] * PROJ_STRIDE;
            s_mean[li] = vec2<f32>(proj[o], proj[o + 1u]);
            s_conic[li] = vec4<f32>(proj[o + 2u], proj[o + 3u], proj[o + 4u], proj[o + 6u]);
            s_color[li] = vec4<f32>(proj[o + 7u], proj[o + 8u], proj[o + 9u], proj[o + 5u]);
        }
        workgroupBarrier();
        let count = min(256u, end - b);
        if (!done) {
            for (var k = 0u; k < count; k = k + 1u) {
                let d = s_mean[k] - q;
                let cn = s_conic[k];
                let sigma = 0.5 * (cn.x * d.x * d.x + cn.z * d.y * d.y) + cn.y * d.x * d.y;
                if (sigma < 0.0) {
                    continue;
                }
                let alpha = min(MAX_ALPHA, cn.w * exp(-sigma));
                if (alpha < ALPHA_THRESHOLD) {
                    continue;
                }
                let next_t = tr * (1.0 - alpha);
                if (next_t <= TRANSMITTANCE_MIN) {
                    done = true;
                    atomicAdd(&n_done, 1u);
                    break;
                }
                let wgt = alpha * tr;
                let c = s_color[k];
                color = color + c.xyz * wgt;
                depth = depth + c.w * wgt;
                tr = next_t;
                last = b - start + k + 1u;
                blended = blended + 1u;
            }
        }
        workgroupBarrier();
        if (li == 0u) {
            w_done = atomicLoad(&n_done);
        }
        if (workgroupUniformLoad(&w_done) == 256u) {
            break;
        }
    }
    if (blended > 0u) {
        atomicAdd(&stats[0], blended);
    }
    if (!inside) {
        return;
    }
    let p = py * w + px;
    let np = w * h;
    let a = 1.0 - tr;
    let rgb = color + cam.bg.xyz * tr;
    out[3u * p] = rgb.x;
    out[3u * p + 1u] = rgb.y;
    out[3u * p + 2u] = rgb.z;
    out[3u * np + p] = a;
    var dz = 0.0;
    if (a > 0.0) {
        dz = depth / a;
    }
    out[4u * np + p] = dz;
    state[p] = bitcast<u32>(tr);
    state[np + p] = last;
}
