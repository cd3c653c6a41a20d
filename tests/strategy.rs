//! "Model only what the scene needs": the densification budget and its ranking, pruning of
//! splats no view sees or that can never be blended, and SH bands that must pay their way.

use glam::Vec3;
use metasplat::train::config::Recipe;
use metasplat::train::densify::{DensifyStrategy, Unseen};
use metasplat::train::sh::{ShEvent, ShSchedule, ShState};
use splat::model::logit;
use splat::optim::Adam;
use splat::{Gaussians, RenderSettings, render};

fn row_of_splats(n: usize, degree: u32) -> Gaussians {
    let mut g = Gaussians::new(degree);
    let rest = vec![Vec3::splat(0.05); g.rest_count()];
    for i in 0..n {
        g.push(
            Vec3::new(i as f32 * 0.3 - 1.5, 0.0, 5.0),
            Vec3::splat(-3.0),
            [1.0, 0.0, 0.0, 0.0],
            logit(0.6),
            Vec3::new(0.2, i as f32 * 0.1, 0.5),
            &rest,
        );
    }
    g
}

fn recipe() -> Recipe {
    let mut r = Recipe::for_iters(1000, false);
    r.densify_from = 0;
    r.densify_every = 10;
    r.densify_until = 500;
    r
}

#[test]
fn growth_stops_at_the_budget_and_takes_the_largest_gradients() {
    let n = 12;
    let mut model = row_of_splats(n, 0);
    let mut adam = Adam::new(&model);
    let budget = n + 4;
    let strategy = DensifyStrategy::new(
        recipe(),
        metasplat::train::densify::Budget::fixed(budget),
        10.0,
    );
    let mut d = strategy.initialize_state(n);
    // Every splat is a candidate (mean gradient above 2e-4); splat i has gradient i + 1.
    for i in 0..n {
        d.stats.grad_norm_sum[i] = 1e-3 * (i + 1) as f32;
        d.stats.count[i] = 1;
    }
    d.seen = vec![true; n];
    let edit = strategy
        .after_step(&mut d, 10, &mut model, &mut adam, 7)
        .unwrap()
        .unwrap();
    assert_eq!(model.len(), budget);
    assert_eq!(edit.cloned + edit.split, 4);
    assert_eq!(edit.over_budget, n - 4);
    // Small splats (scale e^-3 ≤ 1 % of the extent 10) are cloned: the copies sit on the
    // four splats with the largest gradients, 8..11.
    assert_eq!(edit.cloned, 4);
    for (k, i) in (8..12).enumerate() {
        assert_eq!(model.means[n + k], model.means[i]);
    }
    // Statistics restart and the optimiser follows the new size.
    assert!(d.stats.count.iter().all(|&c| c == 0) && d.stats.count.len() == budget);
    let grads = Gaussians::zeros(budget, 0);
    adam.step(
        &mut model,
        &grads,
        &Recipe::for_iters(10, false).lrs.with_means(1e-3),
    )
    .unwrap();

    // At the budget, nothing grows however large the gradients.
    for i in 0..budget {
        d.stats.grad_norm_sum[i] = 1.0;
        d.stats.count[i] = 1;
    }
    let edit = strategy
        .after_step(&mut d, 20, &mut model, &mut adam, 7)
        .unwrap()
        .unwrap();
    assert_eq!((edit.cloned, edit.split, edit.over_budget), (0, 0, budget));
    assert_eq!(model.len(), budget);
}

#[test]
fn unseen_and_invisible_splats_are_pruned_without_changing_renders() {
    let n = 10;
    let mut model = row_of_splats(n, 0);
    let mut adam = Adam::new(&model);
    let strategy = DensifyStrategy::new(
        recipe(),
        metasplat::train::densify::Budget::fixed(100),
        10.0,
    );
    let mut d = strategy.initialize_state(n);
    d.seen = (0..n).map(|i| i % 3 != 0).collect();
    let pruned = strategy
        .end_of_epoch(&mut d, 30, &mut model, &mut adam, 0)
        .unwrap();
    assert_eq!(pruned, Unseen::Pruned(4));
    assert_eq!(model.len(), 6);
    assert!(d.seen.iter().all(|s| !s), "a new epoch starts unseen");

    // Opacity below 1/255 can never be blended: dropping it leaves every pixel as it was.
    model.logit_opacities[2] = logit(0.002);
    model.logit_opacities[4] = logit(0.003);
    let cam = splat::Camera::look_at(
        Vec3::ZERO,
        Vec3::new(0.0, 0.0, 5.0),
        Vec3::NEG_Y,
        60.0,
        60.0,
        64,
        48,
    );
    let settings = RenderSettings::default();
    let before = render(&model, &cam, &settings).unwrap().color;
    assert_eq!(strategy.finish(&mut d, &mut model, &mut adam).unwrap(), 2);
    assert_eq!(model.len(), 4);
    assert_eq!(render(&model, &cam, &settings).unwrap().color, before);
}

#[test]
fn sh_bands_stay_only_while_they_lower_the_loss() {
    let mut model = row_of_splats(5, 0);
    let mut adam = Adam::new(&model);
    let min_gain = Recipe::for_iters(1000, false).sh_min_gain;
    let bands = ShSchedule::new(3, 100, min_gain);
    let mut state = ShState::default();
    // A scene whose loss improves with band 1 but not with band 2.
    let mut loss_at = |_: &Gaussians, degree: u32| -> metasplat::Result<f64> {
        Ok(match degree {
            0 => 1.0,
            1 => 0.9,
            _ => 0.9 * (1.0 - min_gain / 10.0),
        })
    };
    assert!(
        bands
            .after_step(&mut state, 50, &mut model, &mut adam, &mut loss_at)
            .unwrap()
            .is_empty()
    );
    let e = bands
        .after_step(&mut state, 100, &mut model, &mut adam, &mut loss_at)
        .unwrap();
    assert_eq!(e, vec![ShEvent::Raised { degree: 1 }]);
    assert_eq!((model.sh_degree, model.sh_rest.len()), (1, 5 * 3));
    let e = bands
        .after_step(&mut state, 200, &mut model, &mut adam, &mut loss_at)
        .unwrap();
    assert!(matches!(e[0], ShEvent::Kept { degree: 1, .. }));
    assert_eq!(e[1], ShEvent::Raised { degree: 2 });
    let e = bands
        .after_step(&mut state, 300, &mut model, &mut adam, &mut loss_at)
        .unwrap();
    assert!(
        matches!(e[..], [ShEvent::Dropped { degree: 1, .. }]),
        "{e:?}"
    );
    assert!(state.frozen);
    assert_eq!((model.sh_degree, model.sh_rest.len()), (1, 5 * 3));
    // Frozen: no more bands; at the end band 1 is tested once more and kept.
    assert!(
        bands
            .after_step(&mut state, 400, &mut model, &mut adam, &mut loss_at)
            .unwrap()
            .is_empty()
    );
    let e = bands
        .finish(&mut state, &mut model, &mut adam, &mut loss_at)
        .unwrap();
    assert!(matches!(e[..], [ShEvent::Kept { degree: 1, .. }]), "{e:?}");
    // Adam follows the model's shape through all of this.
    let grads = Gaussians::zeros(5, 1);
    adam.step(
        &mut model,
        &grads,
        &Recipe::for_iters(10, false).lrs.with_means(1e-3),
    )
    .unwrap();
}
