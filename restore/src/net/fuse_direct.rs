//! The STAF block's last step for CPU inference, `ca + (sa − ca) · w`, in one pass.
//!
//! As tensors it is three passes, each making a new map of the block's width; here each
//! output plane is made from its two input planes and the gate. It has no gradient:
//! training takes the tensor formulation.

/// `sa`, `ca`: `[b, c, h, w]`; `gate`: `[b, 1, h, w]` (a weight per pixel) or `[b, c, 1, 1]`
/// (a weight per channel) → `ca + (sa − ca) · gate`, `[b, c, h, w]`.
pub fn blend(
    sa: &[f32],
    ca: &[f32],
    gate: &[f32],
    [b, c, h, w]: [usize; 4],
    gate_dims: [usize; 4],
) -> Vec<f32> {
    let plane = h * w;
    let per_pixel = gate_dims == [b, 1, h, w];
    assert!(
        per_pixel || gate_dims == [b, c, 1, 1],
        "a gate of {gate_dims:?} for a map of {:?}",
        [b, c, h, w]
    );
    assert!(sa.len() == b * c * plane && ca.len() == sa.len());
    super::fresh::filled(b * c * plane, plane, |task, dst| {
        let (n, ch) = (task / c, task % c);
        let s = &sa[task * plane..][..plane];
        let a = &ca[task * plane..][..plane];
        if per_pixel {
            let g = &gate[n * plane..][..plane];
            for (((o, &s), &a), &g) in dst.iter_mut().zip(s).zip(a).zip(g) {
                *o = a + (s - a) * g;
            }
        } else {
            let g = gate[n * c + ch];
            for ((o, &s), &a) in dst.iter_mut().zip(s).zip(a) {
                *o = a + (s - a) * g;
            }
        }
    })
}
