//! 3DGS as Markov chain Monte Carlo (Kheradmand et al., NeurIPS 2024; gsplat's
//! `MCMCStrategy`): every few steps the splats too transparent to matter are moved onto
//! opaque ones (drawn in proportion to opacity, with the correction that keeps the image),
//! then the count grows by a fixed fraction up to the budget; every step, positions get noise
//! that only transparent splats feel. Nothing is pruned during training, so the count never
//! falls, and no splat depends on where random initial points happened to land.

use splat::Gaussians;
use splat::mcmc::{add_gaussians, inject_noise, relocate_gaussians};
use splat::model::{logit, sigmoid};
use splat::optim::{Adam, ExponentialLr};

use super::{Budget, DensifyState, Edit, carry};
use crate::error::Result;
use crate::train::config::McmcRecipe;

/// Seeds of the three random moves, apart so that none repeats another's draws.
const RELOCATE: u64 = 0x5245_4c4f;
const ADD: u64 = 0x4144_4400;
const NOISE: u64 = 0x4e4f_4953;

/// The MCMC strategy's settings, fixed for a run.
#[derive(Clone, Debug)]
pub struct Mcmc {
    pub recipe: McmcRecipe,
    pub budget: Budget,
    /// The position learning rate's schedule: the noise follows it.
    pub position_lr: ExponentialLr,
}

impl Mcmc {
    fn refines_at(&self, step: u64) -> bool {
        let r = &self.recipe;
        step > r.refine_from && step < r.refine_until && step.is_multiple_of(r.refine_every)
    }

    /// Every step while there is noise to add, else only when it refines.
    pub fn acts_at(&self, step: u64) -> bool {
        self.recipe.noise_lr > 0.0 || self.refines_at(step)
    }

    /// Splats from points start half opaque and a tenth the size 3DGS gives them: the
    /// chain's penalties shrink and fade what the images do not need.
    pub fn prepare_initial(&self, model: &mut Gaussians) {
        let o = logit(self.recipe.init_opacity);
        model.logit_opacities.fill(o);
        let shrink = self.recipe.init_scale.ln();
        for s in &mut model.log_scales {
            *s += glam::Vec3::splat(shrink);
        }
    }

    /// Moves the `dead` splats onto live ones; returns how many moved.
    pub fn relocate(
        &self,
        state: &mut DensifyState,
        model: &mut Gaussians,
        adam: &mut Adam,
        dead: &[bool],
        seed: u64,
    ) -> Result<usize> {
        let count = dead.iter().filter(|d| **d).count();
        if count == 0 || count == model.len() {
            return Ok(0);
        }
        let sources = relocate_gaussians(model, dead, self.recipe.min_opacity, seed ^ RELOCATE)?;
        carry(adam, state, &sources)?;
        Ok(count)
    }

    pub fn after_step(
        &self,
        state: &mut DensifyState,
        step: u64,
        model: &mut Gaussians,
        adam: &mut Adam,
        seed: u64,
    ) -> Result<Option<Edit>> {
        let r = &self.recipe;
        let seed = seed ^ step.wrapping_mul(base::rng::GOLDEN_GAMMA);
        let mut edit = None;
        if self.refines_at(step) {
            let dead: Vec<bool> = model
                .logit_opacities
                .iter()
                .zip(&model.means)
                .map(|(&o, m)| sigmoid(o) <= r.min_opacity || !m.is_finite())
                .collect();
            let relocated = self.relocate(state, model, adam, &dead, seed)?;
            let n = model.len();
            let target =
                ((n as f64 * (1.0 + r.grow_fraction as f64)) as usize).min(self.budget.at(step));
            let added = target.saturating_sub(n);
            if added > 0 {
                let sources = add_gaussians(model, added, r.min_opacity, seed ^ ADD)?;
                carry(adam, state, &sources)?;
            }
            edit = Some(Edit {
                relocated,
                added,
                ..Edit::default()
            });
        }
        if r.noise_lr > 0.0 {
            inject_noise(model, self.position_lr.at(step) * r.noise_lr, seed ^ NOISE);
        }
        Ok(edit)
    }
}
