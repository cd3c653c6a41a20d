//! Densification as Markov chain Monte Carlo (Kheradmand et al., "3D Gaussian Splatting as
//! Markov Chain Monte Carlo", NeurIPS 2024; gsplat's `MCMCStrategy`): the Gaussians are
//! samples, so a dead one (too transparent to matter) is not deleted but moved onto a live one
//! chosen in proportion to opacity, new ones are added the same way, and positions get noise
//! that only transparent Gaussians feel. Each move splits a live Gaussian into copies whose
//! opacity and scale are corrected so that together they render nearly as it did: a
//! relocation changes the image little, which is what lets the chain explore.
//!
//! As [`crate::densify`], every structural edit returns `sources` (for each Gaussian of the new
//! model the index it keeps its optimiser state from, `None` for a fresh start), to feed
//! [`crate::optim::Adam::remap`].

use glam::Vec3;

use crate::cpu::project::quat_to_rotmat;
use crate::densify::check_mask;
use crate::error::SplatError;
use crate::model::{Gaussians, logit, sigmoid};
use base::SplitMix64;

/// Most copies one Gaussian is split into by a single move (the paper's table stops here).
pub const MAX_COPIES: usize = 51;

/// Opacity and scale of each of `copies` Gaussians that replace one of `opacity` and `scale`
/// (the paper's eq. 9–10): the copies' opacities compose to the original's at the centre,
/// `1 − (1 − o′)ⁿ = o`, and their scale is chosen so the composed profile keeps its weight.
/// Evaluated in f64: the alternating binomial sum cancels badly in f32.
pub fn relocation(opacity: f32, scale: Vec3, copies: usize) -> (f32, Vec3) {
    let n = copies.clamp(1, MAX_COPIES);
    let o = (opacity as f64).clamp(0.0, 1.0);
    let new_o = 1.0 - (1.0 - o).powf(1.0 / n as f64);
    let mut denom = 0.0f64;
    for i in 1..=n {
        // C(i−1, k), built up term by term.
        let mut c = 1.0f64;
        for k in 0..i {
            let sign = if k % 2 == 0 { 1.0 } else { -1.0 };
            denom += c * sign / ((k + 1) as f64).sqrt() * new_o.powi(k as i32 + 1);
            c = c * (i - 1 - k) as f64 / (k + 1) as f64;
        }
    }
    let coeff = if denom > 0.0 { o / denom } else { 1.0 };
    (new_o as f32, scale * coeff as f32)
}

/// `n` indices drawn with replacement, each with probability proportional to `weights`
/// (non-finite and negative weights count as zero; all zero: uniform).
fn draw(weights: &[f32], n: usize, rng: &mut SplitMix64) -> Vec<usize> {
    let mut cumulative = Vec::with_capacity(weights.len());
    let mut total = 0.0f64;
    for &w in weights {
        if w.is_finite() && w > 0.0 {
            total += w as f64;
        }
        cumulative.push(total);
    }
    (0..n)
        .map(|_| {
            if total <= 0.0 {
                return (rng.next_u64() % weights.len() as u64) as usize;
            }
            let u = rng.next_f64() * total;
            cumulative
                .partition_point(|&c| c <= u)
                .min(weights.len() - 1)
        })
        .collect()
}

/// Gives each of `targets` (an index may repeat, once per copy it will get) the corrected
/// opacity and scale of one of its copies; the callers then make the copies.
fn split_targets(g: &mut Gaussians, targets: &[usize], min_opacity: f32) {
    let mut copies = vec![0usize; g.len()];
    for &t in targets {
        copies[t] += 1;
    }
    for (i, &extra) in copies.iter().enumerate() {
        if extra == 0 {
            continue;
        }
        let (o, s) = relocation(
            sigmoid(g.logit_opacities[i]),
            g.log_scales[i].exp(),
            extra + 1,
        );
        g.logit_opacities[i] = logit(o.clamp(min_opacity, 1.0 - f32::EPSILON));
        g.log_scales[i] = s.max(Vec3::splat(f32::MIN_POSITIVE)).ln();
    }
}

/// Moves every `dead` Gaussian onto a live one drawn in proportion to its opacity, splitting
/// that one with [`relocation`]'s correction (opacities floored at `min_opacity`). Moved and
/// split Gaussians restart their optimiser state. With no dead or no live ones, nothing moves.
/// Deterministic given `seed`.
pub fn relocate_gaussians(
    g: &mut Gaussians,
    dead: &[bool],
    min_opacity: f32,
    seed: u64,
) -> Result<Vec<Option<usize>>, SplatError> {
    check_mask(g, dead)?;
    let n = g.len();
    let dead_ids: Vec<usize> = (0..n).filter(|&i| dead[i]).collect();
    let alive: Vec<usize> = (0..n).filter(|&i| !dead[i]).collect();
    let mut sources: Vec<Option<usize>> = (0..n).map(Some).collect();
    if dead_ids.is_empty() || alive.is_empty() {
        return Ok(sources);
    }
    let weights: Vec<f32> = alive
        .iter()
        .map(|&i| sigmoid(g.logit_opacities[i]))
        .collect();
    let mut rng = SplitMix64::new(seed);
    let targets: Vec<usize> = draw(&weights, dead_ids.len(), &mut rng)
        .into_iter()
        .map(|k| alive[k])
        .collect();
    split_targets(g, &targets, min_opacity);
    for (&d, &t) in dead_ids.iter().zip(&targets) {
        copy_into(g, d, t);
        sources[d] = None;
        sources[t] = None;
    }
    Ok(sources)
}

/// Appends `count` Gaussians, each a copy of one drawn in proportion to opacity, splitting it
/// with [`relocation`]'s correction; the split ones and the copies start their optimiser
/// state afresh. Deterministic given `seed`.
pub fn add_gaussians(
    g: &mut Gaussians,
    count: usize,
    min_opacity: f32,
    seed: u64,
) -> Result<Vec<Option<usize>>, SplatError> {
    let n = g.len();
    let mut sources: Vec<Option<usize>> = (0..n).map(Some).collect();
    if count == 0 || n == 0 {
        return Ok(sources);
    }
    let weights: Vec<f32> = g.logit_opacities.iter().map(|&x| sigmoid(x)).collect();
    let mut rng = SplitMix64::new(seed);
    let targets = draw(&weights, count, &mut rng);
    split_targets(g, &targets, min_opacity);
    let copies = g.gather(&targets);
    for (k, &t) in targets.iter().enumerate() {
        g.push_from(&copies, k);
        sources[t] = None;
        sources.push(None);
    }
    Ok(sources)
}

/// Overwrites Gaussian `dst` with Gaussian `src`.
fn copy_into(g: &mut Gaussians, dst: usize, src: usize) {
    g.means[dst] = g.means[src];
    g.log_scales[dst] = g.log_scales[src];
    g.rotations[dst] = g.rotations[src];
    g.logit_opacities[dst] = g.logit_opacities[src];
    g.sh_dc[dst] = g.sh_dc[src];
    let r = g.rest_count();
    g.sh_rest.copy_within(src * r..(src + 1) * r, dst * r);
}

/// How strongly a Gaussian of opacity `o` feels the position noise: ≈ 1 below 0.995 opacity's
/// complement, falling steeply to 0 for opaque ones (the paper's `σ(−k(o − t))`, k = 100).
pub fn noise_gate(opacity: f32) -> f32 {
    1.0 / (1.0 + (-100.0 * ((1.0 - opacity) - 0.995)).exp())
}

/// The largest step the exploration noise takes along each of a Gaussian's axes, as a
/// fraction of its own scale on that axis (times the normal draw).
pub const NOISE_MAX_STEP: f32 = 0.25;

/// Adds the chain's exploration noise to every position: along each of the Gaussian's axes,
/// `s² · n · gate(o) · scaler` (the paper's `Σ · n · gate · scaler`, `s` the scale on that axis,
/// `n ~ N(0, 1)`), but at most `NOISE_MAX_STEP · s · n`; transparent Gaussians wander along
/// their own shape and opaque ones stay. `scaler` is the position learning rate times the
/// noise rate. Deterministic given `seed`.
///
/// Why the bound: the paper's step grows with the square of a Gaussian's size, so a wide,
/// nearly transparent one (what fitting blurred photos makes) is thrown further than its own
/// size at every step and random-walks away, and the copies relocation makes of wide ones keep
/// the width (plain training on `maryrose_tankard` at 3000 steps diverged: RESULTS.md). Small
/// Gaussians, and all of them once the learning rate has decayed, feel the paper's noise.
pub fn inject_noise(g: &mut Gaussians, scaler: f32, seed: u64) {
    let mut rng = SplitMix64::new(seed);
    for i in 0..g.len() {
        let n = rng.normal_vec3();
        let gate = noise_gate(sigmoid(g.logit_opacities[i]));
        let k = gate * scaler;
        if !k.is_normal() {
            continue;
        }
        let (r, _, _) = quat_to_rotmat(g.rotations[i]);
        let s = g.log_scales[i].exp();
        let along = s * s * n * (Vec3::splat(NOISE_MAX_STEP) / s).min(Vec3::splat(k));
        let step = r * along;
        if step.is_finite() {
            g.means[i] += step;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_copy_is_the_gaussian_itself() {
        let (o, s) = relocation(0.7, Vec3::new(0.1, 0.2, 0.3), 1);
        assert!((o - 0.7).abs() < 1e-6);
        assert!((s - Vec3::new(0.1, 0.2, 0.3)).abs().max_element() < 1e-6);
    }

    #[test]
    fn copies_compose_to_the_original_opacity_at_the_centre() {
        for &o in &[0.01f32, 0.3, 0.9, 0.999] {
            for n in [2, 5, 20, MAX_COPIES] {
                let (new_o, s) = relocation(o, Vec3::ONE, n);
                let composed = 1.0 - (1.0 - new_o as f64).powi(n as i32);
                assert!(
                    (composed - o as f64).abs() < 1e-5,
                    "o {o} n {n}: {composed}"
                );
                assert!(s.is_finite() && s.min_element() > 0.0, "o {o} n {n}: {s}");
            }
        }
    }

    #[test]
    fn draws_follow_the_weights() {
        let mut rng = SplitMix64::new(3);
        let picks = draw(&[0.0, 1.0, 3.0, f32::NAN], 40_000, &mut rng);
        let count = |k| picks.iter().filter(|&&p| p == k).count() as f64 / 40_000.0;
        assert_eq!(count(0), 0.0);
        assert_eq!(count(3), 0.0);
        assert!((count(2) - 0.75).abs() < 0.01, "{}", count(2));
    }

    #[test]
    fn noise_moves_transparent_gaussians_and_leaves_opaque_ones() {
        let mut g = Gaussians::new(0);
        for o in [0.01f32, 0.999] {
            g.push(
                Vec3::ZERO,
                Vec3::splat(0.1f32.ln()),
                [1.0, 0.0, 0.0, 0.0],
                logit(o),
                Vec3::ZERO,
                &[],
            );
        }
        inject_noise(&mut g, 10.0, 1);
        assert!(g.means[0].length() > 1e-3, "{}", g.means[0]);
        assert!(g.means[1].length() < 1e-6, "{}", g.means[1]);
    }

    /// A small Gaussian moves by the paper's `Σ · n · gate · scaler`; a wide one by at most a
    /// quarter of its own scale along each axis, whatever the scaler.
    #[test]
    fn noise_follows_the_paper_for_small_splats_and_is_bounded_for_wide_ones() {
        let q = [0.9f32, 0.1, -0.3, 0.2];
        let (r, _, _) = quat_to_rotmat(q);
        let moved = |scale: Vec3, scaler: f32| {
            let mut g = Gaussians::new(0);
            g.push(
                Vec3::ZERO,
                scale.map(f32::ln),
                q,
                logit(0.001),
                Vec3::ZERO,
                &[],
            );
            inject_noise(&mut g, scaler, 9);
            let n = SplitMix64::new(9).normal_vec3();
            (r.transpose() * g.means[0], n, noise_gate(0.001) * scaler)
        };
        let small = Vec3::new(0.01, 0.02, 0.015);
        let (local, n, k) = moved(small, 2.0);
        let paper = glam::Mat3::from_diagonal(small * small) * (n * k);
        assert!(
            (local - paper).length() <= 1e-6 * paper.length(),
            "{local} {paper}"
        );
        let wide = Vec3::new(0.4, 0.1, 0.6);
        let (local, n, _) = moved(wide, 500.0);
        let bound = wide * n.abs() * NOISE_MAX_STEP;
        assert!(local.abs().cmple(bound * 1.0001).all(), "{local} {bound}");
        assert!(
            (local.abs() - bound).abs().max_element() <= 1e-5,
            "{local} {bound}"
        );
    }
}
