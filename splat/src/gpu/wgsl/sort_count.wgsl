// Radix sort, pass 1 of 2 per digit: how many keys of each 4-bit digit each block of 256
// holds, stored digit-major so one exclusive scan gives every (digit, block) its offset.
// Workgroup atomics only: no assumption on subgroup size.

@group(0) @binding(0) var<uniform> pass_: SortPass;
@group(0) @binding(1) var<storage, read> keys_hi: array<u32>;
@group(0) @binding(2) var<storage, read> keys_lo: array<u32>;
@group(0) @binding(3) var<storage, read_write> counts: array<u32>;

var<workgroup> hist: array<atomic<u32>, 16>;

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
    if (li < 16u) {
        atomicStore(&hist[li], 0u);
    }
    workgroupBarrier();
    let i = g * 256u + li;
    if (i < pass_.n) {
        var key = keys_lo[i];
        if (pass_.use_hi != 0u) {
            key = keys_hi[i];
        }
        atomicAdd(&hist[(key >> pass_.shift) & 15u], 1u);
    }
    workgroupBarrier();
    if (li < 16u) {
        counts[li * pass_.num_blocks + g] = atomicLoad(&hist[li]);
    }
}
