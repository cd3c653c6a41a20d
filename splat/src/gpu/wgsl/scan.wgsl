// Exclusive prefix sum of u32 within blocks of 256, and each block's total (scanned again
// one level up until one block remains, then added back by `scan_add`).

@group(0) @binding(0) var<uniform> len: Len;
@group(0) @binding(1) var<storage, read> input: array<u32>;
@group(0) @binding(2) var<storage, read_write> output: array<u32>;
@group(0) @binding(3) var<storage, read_write> block_sums: array<u32>;

var<workgroup> tmp: array<u32, 256>;

@compute @workgroup_size(256)
fn main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) li: u32,
) {
    let g = linear_group(wid, nwg);
    let i = g * 256u + li;
    var v = 0u;
    if (i < len.n) {
        v = input[i];
    }
    tmp[li] = v;
    workgroupBarrier();
    for (var off = 1u; off < 256u; off = off * 2u) {
        var t = 0u;
        if (li >= off) {
            t = tmp[li - off];
        }
        workgroupBarrier();
        tmp[li] = tmp[li] + t;
        workgroupBarrier();
    }
    if (i < len.n) {
        output[i] = tmp[li] - v;
    }
    if (li == 255u && g * 256u < len.n) {
        block_sums[g] = tmp[255];
    }
}
