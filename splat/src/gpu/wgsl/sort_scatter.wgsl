// Radix sort, pass 2 of 2 per digit: each key goes to its digit's offset for this block plus
// the number of keys with the same digit before it in the block, which keeps the sort stable.
// That rank comes from a workgroup prefix sum of one-hot digit counters packed two to a u32
// (16 bits each; a block holds at most 256 keys), so no subgroup operation is needed.

@group(0) @binding(0) var<uniform> pass_: SortPass;
@group(0) @binding(1) var<storage, read> hi_in: array<u32>;
@group(0) @binding(2) var<storage, read> lo_in: array<u32>;
@group(0) @binding(3) var<storage, read> val_in: array<u32>;
@group(0) @binding(4) var<storage, read> offsets: array<u32>;
@group(0) @binding(5) var<storage, read_write> hi_out: array<u32>;
@group(0) @binding(6) var<storage, read_write> lo_out: array<u32>;
@group(0) @binding(7) var<storage, read_write> val_out: array<u32>;

var<workgroup> lanes: array<array<u32, 8>, 256>;

@compute @workgroup_size(256)
fn main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) li: u32,
) {
    let g = linear_group(wid, nwg);
    if (g >= pass_.num_blocks) {
        return;
    }
    let i = g * 256u + li;
    let valid = i < pass_.n;
    var digit = 0u;
    var mine: array<u32, 8>;
    if (valid) {
        var key = lo_in[i];
        if (pass_.use_hi != 0u) {
            key = hi_in[i];
        }
        digit = (key >> pass_.shift) & 15u;
        mine[digit >> 1u] = 1u << ((digit & 1u) * 16u);
    }
    lanes[li] = mine;
    workgroupBarrier();
    for (var off = 1u; off < 256u; off = off * 2u) {
        var t: array<u32, 8>;
        if (li >= off) {
            t = lanes[li - off];
        }
        workgroupBarrier();
        if (li >= off) {
            for (var w = 0u; w < 8u; w = w + 1u) {
                lanes[li][w] = lanes[li][w] + t[w];
            }
        }
        workgroupBarrier();
    }
    if (valid) {
        let inclusive = (lanes[li][digit >> 1u] >> ((digit & 1u) * 16u)) & 0xffffu;
        let dest = offsets[digit * pass_.num_blocks + g] + inclusive - 1u;
        hi_out[dest] = hi_in[i];
        lo_out[dest] = lo_in[i];
        val_out[dest] = val_in[i];
    }
}
