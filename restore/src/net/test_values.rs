//! Deterministic inputs and an error measure shared by the kernels' unit tests.

/// `n` values in [-1, 1) from a xorshift stream seeded with `seed`: the same on every run and
/// in every test thread, with no RNG crate.
pub fn values(n: usize, seed: u64) -> Vec<f32> {
    let mut s = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    (0..n)
        .map(|_| {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 40) as f32 / (1u64 << 23) as f32 - 1.0
        })
        .collect()
}

/// The largest `|a − r|` over the largest `|r|` (at least 1e-12), after checking that every
/// value of `a` is finite.
pub fn rel_err(a: &[f32], r: &[f64]) -> f64 {
    assert_eq!(a.len(), r.len());
    assert!(a.iter().all(|v| v.is_finite()));
    let scale = r.iter().fold(1e-12f64, |m, v| m.max(v.abs()));
    a.iter()
        .zip(r)
        .map(|(&a, &r)| (a as f64 - r).abs())
        .fold(0.0, f64::max)
        / scale
}
