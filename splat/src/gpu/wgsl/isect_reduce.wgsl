// Per Gaussian: the sum of its (tile, Gaussian) gradient slots, which are contiguous and in
// row-major tile order (the CPU's order).

@group(0) @binding(0) var<uniform> len: Len;
@group(0) @binding(1) var<storage, read> offsets: array<u32>;
@group(0) @binding(2) var<storage, read> counts: array<u32>;
@group(0) @binding(3) var<storage, read> isect: array<f32>;
@group(0) @binding(4) var<storage, read_write> screen: array<f32>;

@compute @workgroup_size(256)
fn main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) li: u32,
) {
    let i = linear_group(wid, nwg) * 256u + li;
    if (i >= len.n) {
        return;
    }
    var acc: array<f32, 12>;
    let s = offsets[i];
    let c = counts[i];
    for (var k = s; k < s + c; k = k + 1u) {
        for (var j = 0u; j < 12u; j = j + 1u) {
            acc[j] = acc[j] + isect[k * 12u + j];
        }
    }
    for (var j = 0u; j < 12u; j = j + 1u) {
        screen[i * 12u + j] = acc[j];
    }
}
