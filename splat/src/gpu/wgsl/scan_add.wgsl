// Adds each block's offset (the scanned block totals) to the block's elements.

@group(0) @binding(0) var<uniform> len: Len;
@group(0) @binding(1) var<storage, read> block_offsets: array<u32>;
@group(0) @binding(2) var<storage, read_write> output: array<u32>;

@compute @workgroup_size(256)
fn main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) li: u32,
) {
    let g = linear_group(wid, nwg);
    let i = g * 256u + li;
    if (i < len.n) {
        output[i] = output[i] + block_offsets[g];
    }
}
