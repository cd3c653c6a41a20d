// Key emission: each visible Gaussian writes one (tile, depth) key per tile it touches, at
// its scanned offset, in row-major tile order. Keys of one Gaussian are contiguous and
// Gaussians are in index order, so a stable sort gives the CPU's (depth, index) order. The
// value is the emission slot; `owner` maps it to the Gaussian, and the backward pass writes
// each (tile, Gaussian) gradient at its slot, so one Gaussian's partials stay contiguous.

@group(0) @binding(0) var<uniform> cam: Camera;
@group(0) @binding(1) var<storage, read> proj: array<f32>;
@group(0) @binding(2) var<storage, read> offsets: array<u32>;
@group(0) @binding(3) var<storage, read_write> keys_hi: array<u32>;
@group(0) @binding(4) var<storage, read_write> keys_lo: array<u32>;
@group(0) @binding(5) var<storage, read_write> values: array<u32>;
@group(0) @binding(6) var<storage, read> counts: array<u32>;
@group(0) @binding(7) var<storage, read_write> owner: array<u32>;

@compute @workgroup_size(256)
fn main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) li: u32,
) {
    let i = linear_group(wid, nwg) * 256u + li;
    if (i >= cam.cfg.x || counts[i] == 0u) {
        return;
    }
    let o = i * PROJ_STRIDE;
    let rect = tile_rect(
        vec2<f32>(proj[o], proj[o + 1u]),
        vec2<f32>(proj[o + 10u], proj[o + 11u]),
        cam.dims.z,
        cam.dims.w,
    );
    // Depths are positive, so their bits order like the values.
    let depth_bits = bitcast<u32>(proj[o + 5u]);
    var k = offsets[i];
    for (var ty = rect.z; ty < rect.w; ty = ty + 1u) {
        for (var tx = rect.x; tx < rect.y; tx = tx + 1u) {
            keys_hi[k] = ty * cam.dims.z + tx;
            keys_lo[k] = depth_bits;
            values[k] = k;
            owner[k] = i;
            k = k + 1u;
        }
    }
}
