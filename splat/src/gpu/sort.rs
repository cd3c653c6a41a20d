//! Exclusive prefix sums and the stable LSD radix sort of (tile, depth) keys, on the GPU.
//! The sort uses 4-bit digits and workgroup memory only, so it does not depend on the
//! subgroup size (software drivers and GPUs differ).

use super::pipelines::Pipelines;
use super::util::{Scratch, bind, blocks, dispatch, grid, uniform};

/// Records an exclusive scan of `n` u32 from `input` into `output` (may not alias).
pub fn scan(
    device: &wgpu::Device,
    k: &Pipelines,
    encoder: &mut wgpu::CommandEncoder,
    input: &wgpu::Buffer,
    output: &wgpu::Buffer,
    n: u32,
    scratch: &mut Scratch,
) {
    if n == 0 {
        return;
    }
    let nb = blocks(n);
    let sums = scratch.storage(device, "block sums", 4 * nb as u64);
    let len = uniform(device, "scan len", bytemuck::bytes_of(&n));
    let g = bind(device, &k.scan, &[&len, input, output, &sums]);
    dispatch(encoder, &k.scan, &g, grid(nb));
    if nb > 1 {
        let offsets = scratch.storage(device, "block offsets", 4 * nb as u64);
        scan(device, k, encoder, &sums, &offsets, nb, scratch);
        let g = bind(device, &k.scan_add, &[&len, &offsets, output]);
        dispatch(encoder, &k.scan_add, &g, grid(nb));
    }
}

/// Keys and values in a pair of buffer sets; the sort moves between them.
pub struct KeyBuffers {
    pub hi: wgpu::Buffer,
    pub lo: wgpu::Buffer,
    pub val: wgpu::Buffer,
}

impl KeyBuffers {
    pub fn new(device: &wgpu::Device, n: u32, scratch: &mut Scratch) -> Self {
        let bytes = 4 * n as u64;
        Self {
            hi: scratch.storage(device, "keys hi", bytes),
            lo: scratch.storage(device, "keys lo", bytes),
            val: scratch.storage(device, "values", bytes),
        }
    }
}

/// Records a stable sort of `n` pairs by `(hi, lo)`, of which only the low `hi_bits` of `hi`
/// can be set. Returns which of `a`, `b` holds the result (`false`: `a`).
pub fn radix_sort(
    device: &wgpu::Device,
    k: &Pipelines,
    encoder: &mut wgpu::CommandEncoder,
    (a, b): (&KeyBuffers, &KeyBuffers),
    n: u32,
    hi_bits: u32,
    scratch: &mut Scratch,
) -> bool {
    if n == 0 {
        return false;
    }
    let nb = blocks(n);
    let counts = scratch.storage(device, "digit counts", 4 * 16 * nb as u64);
    let offsets = scratch.storage(device, "digit offsets", 4 * 16 * nb as u64);
    let passes = (0..8)
        .map(|p| (4 * p, 0u32))
        .chain((0..hi_bits.div_ceil(4)).map(|p| (4 * p, 1u32)));
    let mut in_b = false;
    for (shift, use_hi) in passes {
        let (src, dst) = if in_b { (b, a) } else { (a, b) };
        let params = uniform(
            device,
            "sort pass",
            bytemuck::cast_slice(&[n, shift, use_hi, nb]),
        );
        let g = bind(device, &k.sort_count, &[&params, &src.hi, &src.lo, &counts]);
        dispatch(encoder, &k.sort_count, &g, grid(nb));
        scan(device, k, encoder, &counts, &offsets, 16 * nb, scratch);
        let g = bind(
            device,
            &k.sort_scatter,
            &[
                &params, &src.hi, &src.lo, &src.val, &offsets, &dst.hi, &dst.lo, &dst.val,
            ],
        );
        dispatch(encoder, &k.sort_scatter, &g, grid(nb));
        in_b = !in_b;
    }
    in_b
}
