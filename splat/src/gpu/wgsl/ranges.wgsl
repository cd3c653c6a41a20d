// Where each tile's run of sorted keys starts and ends (tiles without keys keep 0..0).

@group(0) @binding(0) var<uniform> len: Len;
@group(0) @binding(1) var<storage, read> keys_hi: array<u32>;
@group(0) @binding(2) var<storage, read_write> ranges: array<u32>;

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
    let t = keys_hi[i];
    if (i == 0u || keys_hi[i - 1u] != t) {
        ranges[2u * t] = i;
    }
    if (i + 1u == len.n || keys_hi[i + 1u] != t) {
        ranges[2u * t + 1u] = i + 1u;
    }
}
