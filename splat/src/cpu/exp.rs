//! The exponential the blending kernels use: a polynomial that vectorises, where the scalar
//! reference calls the C library's `expf`.

/// Bound on the relative error of [`exp_neg`] for `σ` in `[0, 87]` (checked in the tests
/// against the float64 exponential).
pub const EXP_REL_ERROR: f64 = 3e-7;

/// `e^(−σ)` for `σ ≥ 0` (inputs are clamped to `[0, 87]`, where the result stays normal):
/// Cody–Waite range reduction to `r ∈ [−ln2/2, ln2/2]` and Cephes' degree-6 polynomial for
/// `e^r`, scaled by `2^n` through the exponent bits. Pure arithmetic, so it vectorises.
#[inline(always)]
pub fn exp_neg(sigma: f32) -> f32 {
    const LOG2E: f32 = std::f32::consts::LOG2_E;
    const LN2_HI: f32 = 0.693_359_4;
    const LN2_LO: f32 = -2.121_944_4e-4;
    // Adding and removing 1.5·2²³ rounds to the nearest integer without a rounding call.
    const ROUND: f32 = 12_582_912.0;
    let x = -sigma.clamp(0.0, 87.0);
    let n = x.mul_add(LOG2E, ROUND) - ROUND;
    let r = (-n).mul_add(LN2_HI, x);
    let r = (-n).mul_add(LN2_LO, r);
    let p: f32 = 1.987_569_1e-4;
    let p = p.mul_add(r, 1.398_199_9e-3);
    let p = p.mul_add(r, 8.333_452e-3);
    let p = p.mul_add(r, 4.166_579_6e-2);
    let p = p.mul_add(r, 1.666_666_5e-1);
    let p = p.mul_add(r, 0.5);
    let e = (p * r).mul_add(r, r) + 1.0;
    e * f32::from_bits(((n as i32 + 127) << 23) as u32)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exp_neg_is_within_its_stated_error() {
        let mut worst = 0.0f64;
        for i in 0..=2_000_000u32 {
            let s = i as f32 * (87.0 / 2_000_000.0);
            let exact = (-(s as f64)).exp();
            let rel = ((exp_neg(s) as f64 - exact) / exact).abs();
            worst = worst.max(rel);
        }
        assert!(worst < EXP_REL_ERROR, "worst relative error {worst:e}");
        // Out-of-range inputs stay finite: masked lanes compute them too.
        for s in [-1.0f32, -1e30, 1e30, f32::INFINITY, f32::NEG_INFINITY] {
            assert!(exp_neg(s).is_finite(), "{s}");
        }
        assert_eq!(exp_neg(0.0), 1.0);
    }
}
