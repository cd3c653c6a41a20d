//! Adam, the lr schedule, densification primitives, and a small end-to-end fit.

mod common;

use common::{random_scene, test_camera};
use glam::Vec3;
use splat::densify::{
    DensifyStats, clone_gaussians, prune_gaussians, prune_mask, reset_opacity, split_gaussians,
};
use splat::loss::photometric_loss;
use splat::model::sigmoid;
use splat::optim::{Adam, ExponentialLr, LearningRates, ParamGroup};
use splat::{Gaussians, RenderSettings, render, render_backward, render_for_backward};

fn lrs(v: f32) -> LearningRates {
    LearningRates {
        means: v,
        log_scales: v,
        rotations: v,
        opacities: v,
        sh_dc: v,
        sh_rest: v,
    }
}

#[test]
fn adam_first_step_moves_by_lr_against_the_gradient_sign() {
    let mut g = random_scene(1, 4, 1, (0.1, 0.2), 1.0);
    let before = g.clone();
    let mut grads = Gaussians::zeros(4, 1);
    grads.means[2] = Vec3::new(3.0, -0.5, 0.0);
    grads.logit_opacities[1] = -2.0;
    let mut adam = Adam::new(&g);
    adam.step(&mut g, &grads, &lrs(0.01)).unwrap();
    // m̂ = g, v̂ = g² on the first step, so the update is lr·sign(g).
    let d = g.means[2] - before.means[2];
    assert!(
        (d - Vec3::new(-0.01, 0.01, 0.0)).abs().max_element() < 1e-6,
        "{d}"
    );
    assert!((g.logit_opacities[1] - before.logit_opacities[1] - 0.01).abs() < 1e-6);
    assert_eq!(g.means[0], before.means[0]);
}

/// Every group's values as one list, with the group's learning rate.
fn flat_groups(g: &Gaussians, lr: &LearningRates) -> Vec<(f32, f32)> {
    fn v3(v: &[Vec3], r: f32) -> impl Iterator<Item = (f32, f32)> + '_ {
        v.iter().flat_map(|x| x.to_array()).map(move |x| (x, r))
    }
    let mut out: Vec<(f32, f32)> = v3(&g.means, lr.means).collect();
    out.extend(v3(&g.log_scales, lr.log_scales));
    out.extend(g.rotations.iter().flatten().map(|&x| (x, lr.rotations)));
    out.extend(g.logit_opacities.iter().map(|&x| (x, lr.opacities)));
    out.extend(v3(&g.sh_dc, lr.sh_dc));
    out.extend(v3(&g.sh_rest, lr.sh_rest));
    out
}

/// Adam against its update written out element by element (the same float operations, so
/// the same bits) over three steps; an element whose gradient is not finite keeps its value
/// and its moments.
#[test]
fn adam_is_the_per_element_update_and_skips_non_finite_gradients() {
    let mut g = random_scene(2, 300, 2, (0.1, 0.2), 1.0);
    let mut grads = random_scene(3, 300, 2, (0.1, 0.2), 1.0);
    grads.means[5].x = f32::NAN;
    grads.rotations[9][2] = f32::NEG_INFINITY;
    grads.logit_opacities[3] = f32::INFINITY;
    grads.sh_rest[17].y = f32::NAN;
    let lr = LearningRates {
        means: 1e-3,
        log_scales: 5e-3,
        rotations: 1e-3,
        opacities: 5e-2,
        sh_dc: 2.5e-3,
        sh_rest: 1.25e-4,
    };
    let before = flat_groups(&g, &lr);
    let gs: Vec<f32> = flat_groups(&grads, &lr).iter().map(|x| x.0).collect();
    let (mut p, mut m, mut v): (Vec<f32>, Vec<f32>, Vec<f32>) = (
        before.iter().map(|x| x.0).collect(),
        vec![0.0; gs.len()],
        vec![0.0; gs.len()],
    );
    let mut adam = Adam::new(&g);
    for t in 1..=3 {
        adam.step(&mut g, &grads, &lr).unwrap();
        let (b1, b2, eps) = (0.9f32, 0.999f32, 1e-15f32);
        let (bc1, bc2) = (1.0 - b1.powi(t), 1.0 - b2.powi(t));
        for i in 0..p.len() {
            if !gs[i].is_finite() {
                continue;
            }
            m[i] = b1 * m[i] + (1.0 - b1) * gs[i];
            v[i] = b2 * v[i] + (1.0 - b2) * gs[i] * gs[i];
            let (mh, vh) = (m[i] / bc1, v[i] / bc2);
            p[i] -= before[i].1 * mh / (vh.sqrt() + eps);
        }
    }
    let got = flat_groups(&g, &lr);
    let (gm, gv) = adam.moments();
    let (gm, gv) = (flat_groups(gm, &lr), flat_groups(gv, &lr));
    let mut skipped = 0;
    for i in 0..p.len() {
        assert_eq!(got[i].0.to_bits(), p[i].to_bits(), "parameter {i}");
        assert_eq!(gm[i].0.to_bits(), m[i].to_bits(), "first moment {i}");
        assert_eq!(gv[i].0.to_bits(), v[i].to_bits(), "second moment {i}");
        if !gs[i].is_finite() {
            assert_eq!(
                got[i].0, before[i].0,
                "parameter {i} moved on a non-finite gradient"
            );
            assert_eq!((gm[i].0, gv[i].0), (0.0, 0.0));
            skipped += 1;
        }
    }
    assert_eq!(skipped, 4);
}

#[test]
fn adam_minimises_a_quadratic_in_every_group() {
    let mut g = random_scene(2, 3, 3, (0.1, 0.2), 1.0);
    let mut adam = Adam::new(&g);
    for _ in 0..2000 {
        // L = ½‖θ‖² per element, gradient θ.
        let grads = g.clone();
        adam.step(&mut g, &grads, &lrs(0.01)).unwrap();
    }
    let all: Vec<f32> = g
        .means
        .iter()
        .chain(&g.log_scales)
        .chain(&g.sh_dc)
        .chain(&g.sh_rest)
        .flat_map(|v| v.to_array())
        .chain(g.rotations.iter().flatten().copied())
        .chain(g.logit_opacities.iter().copied())
        .collect();
    let worst = all.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    assert!(worst < 0.02, "largest parameter after 2000 steps: {worst}");
}

#[test]
fn position_lr_schedule_is_log_linear_and_scaled_by_extent() {
    let s = ExponentialLr::position(5.0);
    assert!((s.at(0) - 8e-4).abs() < 1e-9);
    assert!((s.at(30_000) - 8e-6).abs() < 1e-10);
    assert!((s.at(15_000) - 8e-5).abs() < 1e-8);
    assert_eq!(s.at(90_000), s.at(30_000));
}

#[test]
fn clone_split_prune_and_reset() {
    let mut g = random_scene(3, 5, 2, (0.1, 0.2), 1.0);
    let orig = g.clone();
    let src = clone_gaussians(&mut g, &[false, true, false, false, true]).unwrap();
    assert_eq!(g.len(), 7);
    assert_eq!(
        src,
        vec![Some(0), Some(1), Some(2), Some(3), Some(4), None, None]
    );
    assert_eq!(g.means[5], orig.means[1]);
    assert_eq!(g.sh_rest_of(6), orig.sh_rest_of(4));

    let mut g = orig.clone();
    let src = split_gaussians(&mut g, &[true, false, false, false, false], 11).unwrap();
    assert_eq!(g.len(), 6);
    assert_eq!(&src[..4], &[Some(1), Some(2), Some(3), Some(4)]);
    assert_eq!(&src[4..], &[None, None]);
    let shrink = orig.log_scales[0] - g.log_scales[4];
    assert!((shrink - Vec3::splat(1.6f32.ln())).abs().max_element() < 1e-6);
    assert_ne!(g.means[4], g.means[5]);
    let mut again = orig.clone();
    split_gaussians(&mut again, &[true, false, false, false, false], 11).unwrap();
    assert_eq!(again, g, "split is deterministic for a seed");

    let lowest = (0..5)
        .min_by(|&a, &b| orig.logit_opacities[a].total_cmp(&orig.logit_opacities[b]))
        .unwrap();
    let mask = prune_mask(
        &orig,
        sigmoid(orig.logit_opacities[lowest]) + 1e-6,
        None,
        None,
    );
    assert_eq!(mask.iter().filter(|m| **m).count(), 1);
    let mut g = orig.clone();
    let src = prune_gaussians(&mut g, &mask).unwrap();
    assert_eq!(g.len(), 4);
    assert!(!src.contains(&Some(lowest)));
    let big = orig.log_scales[0].exp().max_element();
    let mask = prune_mask(&orig, 0.0, Some(big - 1e-6), None);
    assert!(mask[0]);

    let mut g = orig.clone();
    reset_opacity(&mut g, 0.01);
    assert!(g.logit_opacities.iter().all(|&o| sigmoid(o) <= 0.01 + 1e-6));
}

#[test]
fn split_children_are_spread_like_the_parent() {
    let mut g = Gaussians::new(0);
    let n = 4000;
    for _ in 0..n {
        g.push(
            Vec3::ZERO,
            Vec3::new(0.0, (2.0f32).ln(), (0.5f32).ln()),
            [1.0, 0.0, 0.0, 0.0],
            0.0,
            Vec3::ZERO,
            &[],
        );
    }
    split_gaussians(&mut g, &vec![true; n], 5).unwrap();
    let var = g.means.iter().fold(Vec3::ZERO, |a, m| a + *m * *m) / g.len() as f32;
    let expect = Vec3::new(1.0, 4.0, 0.25);
    assert!(((var - expect) / expect).abs().max_element() < 0.1, "{var}");
}

#[test]
fn fitting_a_small_scene_reduces_the_photometric_loss() {
    let cam = test_camera(32, 24, 30.0);
    let settings = RenderSettings {
        sh_degree: 1,
        background: Vec3::ZERO,
        antialiased: false,
    };
    let target_scene = random_scene(30, 40, 1, (0.1, 0.4), 1.0);
    let target = render(&target_scene, &cam, &settings).unwrap().color;
    let mut g = random_scene(31, 40, 1, (0.1, 0.4), 1.0);
    let mut adam = Adam::new(&g);
    let lr = LearningRates {
        means: 2e-3,
        ..LearningRates::default()
    };
    let mut stats = DensifyStats::new(g.len());
    let mut first = None;
    let mut last = 0.0;
    for _ in 0..150 {
        let (out, saved) = render_for_backward(&g, &cam, &settings).unwrap();
        let l = photometric_loss(&out.color, &target, cam.width, cam.height, 0.2).unwrap();
        let grads = render_backward(&g, &saved, &l.grad, None, None).unwrap();
        stats.add(&grads, &out, false);
        adam.step(&mut g, &grads.params, &lr).unwrap();
        first.get_or_insert(l.value);
        last = l.value;
    }
    let first = first.unwrap();
    assert!(last < 0.6 * first, "loss {first} -> {last}");

    // Densify with the optimiser state carried along; training continues without error.
    let grow = stats.grow_mask(0.0);
    assert!(grow.iter().any(|m| *m));
    let src = split_gaussians(&mut g, &grow, 1).unwrap();
    adam.remap(&src).unwrap();
    stats.remap(&src).unwrap();
    adam.reset_group(ParamGroup::Opacities);
    let (out, saved) = render_for_backward(&g, &cam, &settings).unwrap();
    let l = photometric_loss(&out.color, &target, cam.width, cam.height, 0.2).unwrap();
    let grads = render_backward(&g, &saved, &l.grad, None, None).unwrap();
    adam.step(&mut g, &grads.params, &lr).unwrap();
    assert!(g.means.iter().all(|m| m.is_finite()));
}

#[test]
fn mismatched_shapes_are_typed_errors() {
    let mut g = random_scene(4, 3, 1, (0.1, 0.2), 1.0);
    let mut adam = Adam::new(&g);
    assert!(
        adam.step(&mut g, &Gaussians::zeros(2, 1), &lrs(0.1))
            .is_err()
    );
    assert!(
        adam.step(&mut g, &Gaussians::zeros(3, 0), &lrs(0.1))
            .is_err()
    );
    assert!(clone_gaussians(&mut g, &[true]).is_err());
    assert!(split_gaussians(&mut g, &[true; 4], 0).is_err());
    assert!(prune_gaussians(&mut g, &[]).is_err());
    assert!(adam.remap(&[Some(7)]).is_err());
    assert!(DensifyStats::new(3).remap(&[Some(3)]).is_err());
    assert_eq!(g.len(), 3);
}

#[test]
fn sh_degree_can_grow_and_shrink_without_changing_lower_bands() {
    let cam = test_camera(32, 24, 30.0);
    let g1 = random_scene(8, 20, 1, (0.1, 0.4), 1.0);
    let settings = |d| RenderSettings {
        sh_degree: d,
        ..RenderSettings::default()
    };
    let before = render(&g1, &cam, &settings(1)).unwrap().color;
    let mut g3 = g1.clone();
    g3.set_sh_degree(3);
    assert_eq!(g3.sh_rest.len(), 20 * 15);
    assert!(g3.param_bytes() > g1.param_bytes());
    // The new bands are zero: rendering at the full degree gives the same image.
    assert_eq!(render(&g3, &cam, &settings(3)).unwrap().color, before);
    for i in 0..20 {
        assert_eq!(&g3.sh_rest_of(i)[..3], g1.sh_rest_of(i));
    }
    let mut back = g3.clone();
    back.set_sh_degree(1);
    assert_eq!(back, g1);
    back.set_sh_degree(0);
    assert_eq!(back.sh_rest.len(), 0);
    assert_eq!(
        render(&back, &cam, &settings(0)).unwrap().color,
        render(&g1, &cam, &settings(0)).unwrap().color
    );

    // Adam follows the model; its state survives a checkpoint round trip exactly.
    let mut adam = Adam::new(&g1);
    let mut g = g1.clone();
    let grads = Gaussians::zeros(20, 1);
    let mut grads = grads;
    grads.sh_rest.iter_mut().for_each(|v| *v = Vec3::ONE);
    adam.step(&mut g, &grads, &lrs(0.01)).unwrap();
    let (m, v) = adam.moments();
    let mut copy = Adam::from_state(adam.steps_taken(), m.clone(), v.clone()).unwrap();
    let (mut ga, mut gb) = (g.clone(), g.clone());
    adam.step(&mut ga, &grads, &lrs(0.01)).unwrap();
    copy.step(&mut gb, &grads, &lrs(0.01)).unwrap();
    assert_eq!(ga, gb);
    adam.set_sh_degree(2);
    ga.set_sh_degree(2);
    let grads2 = Gaussians::zeros(20, 2);
    adam.step(&mut ga, &grads2, &lrs(0.01)).unwrap();
    assert!(Adam::from_state(1, Gaussians::zeros(2, 0), Gaussians::zeros(3, 0)).is_err());
}
