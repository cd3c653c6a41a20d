//! 3DGS's adaptive density control (gsplat's "default strategy"): clone small splats and
//! split large ones where the screen-space gradient is high, prune transparent ones, reset
//! opacities now and then, all held to a splat budget.

use splat::densify::{DensifyStats, clone_gaussians, prune_mask, reset_opacity, split_gaussians};
use splat::optim::{Adam, ParamGroup};
use splat::{Gaussians, RenderOutput};

use super::{Budget, DensifyState, Edit, carry, prune};
use crate::error::Result;
use crate::train::config::{RESET_RECOVERY, Recipe};

/// The strategy's settings, fixed for a run: the recipe's thresholds and schedule, the splat
/// budget and the scene's extent. The hooks read them and change only a [`DensifyState`].
#[derive(Clone, Debug)]
pub struct Adaptive {
    pub recipe: Recipe,
    pub budget: Budget,
    pub extent: f32,
}

impl Adaptive {
    pub fn new(recipe: Recipe, budget: Budget, extent: f32) -> Self {
        Self {
            recipe,
            budget,
            extent,
        }
    }

    fn densifying(&self, step: u64) -> bool {
        step < self.recipe.densify_until
    }

    /// Hook 1: accumulate this view's screen-space gradients.
    pub fn after_backward(
        &self,
        state: &mut DensifyState,
        step: u64,
        means2d: &[[f32; 2]],
        out: &RenderOutput,
    ) {
        if self.densifying(step) {
            state.stats.add_screen(means2d, out);
        }
    }

    fn grows_at(&self, step: u64) -> bool {
        let r = &self.recipe;
        self.densifying(step) && step >= r.densify_from && step.is_multiple_of(r.densify_every)
    }

    fn resets_at(&self, step: u64) -> bool {
        self.densifying(step)
            && self
                .recipe
                .opacity_reset_every
                .is_some_and(|every| step.is_multiple_of(every))
    }

    /// Within [`RESET_RECOVERY`] steps after an opacity reset: too soon to judge opacities.
    fn recovering(&self, step: u64) -> bool {
        self.recipe
            .opacity_reset_every
            .is_some_and(|every| step > every && step % every < RESET_RECOVERY)
    }

    /// Whether [`Adaptive::after_step`] reads or edits the model at `step`.
    pub fn acts_at(&self, step: u64) -> bool {
        self.grows_at(step) || self.resets_at(step)
    }

    /// Hook 2, after the optimiser step `step` (1-based count of steps done).
    pub fn after_step(
        &self,
        state: &mut DensifyState,
        step: u64,
        model: &mut Gaussians,
        adam: &mut Adam,
        seed: u64,
    ) -> Result<Option<Edit>> {
        let r = &self.recipe;
        let mut edit = Edit::default();
        let mut changed = false;
        if self.grows_at(step) {
            self.grow(
                state,
                model,
                adam,
                seed ^ step,
                self.budget.at(step),
                &mut edit,
            )?;
            let after_reset = r.opacity_reset_every.is_some_and(|every| step > every);
            let mask = prune_mask(
                model,
                if self.recovering(step) {
                    0.0
                } else {
                    r.prune_opacity
                },
                after_reset.then_some(r.max_world_scale * self.extent),
                after_reset.then_some((&state.stats, r.max_screen_radius)),
            );
            edit.pruned += prune(state, model, adam, &mask)?;
            state.stats = DensifyStats::new(model.len());
            changed = true;
        }
        if self.resets_at(step) {
            reset_opacity(model, 2.0 * r.prune_opacity);
            adam.reset_group(ParamGroup::Opacities);
            edit.opacity_reset = true;
            changed = true;
        }
        Ok(changed.then_some(edit))
    }

    /// Clone or split the splats with the largest mean screen gradients, as many as the budget
    /// allows (each adds one splat).
    fn grow(
        &self,
        state: &mut DensifyState,
        model: &mut Gaussians,
        adam: &mut Adam,
        seed: u64,
        budget: usize,
        edit: &mut Edit,
    ) -> Result<()> {
        let n = model.len();
        let stats = &state.stats;
        let mut candidates: Vec<(f32, usize)> = stats
            .grow_mask(self.recipe.grad_threshold)
            .iter()
            .enumerate()
            .filter(|(_, m)| **m)
            .map(|(i, _)| (stats.grad_norm_sum[i] / stats.count[i] as f32, i))
            .collect();
        let room = budget.saturating_sub(n);
        if candidates.len() > room {
            candidates.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
            edit.over_budget = candidates.len() - room;
            candidates.truncate(room);
        }
        let small = self.recipe.percent_dense * self.extent;
        let mut clone = vec![false; n];
        let mut split = vec![false; n];
        for &(_, i) in &candidates {
            if model.log_scales[i].exp().max_element() <= small {
                clone[i] = true;
            } else {
                split[i] = true;
            }
        }
        edit.cloned = clone.iter().filter(|m| **m).count();
        edit.split = split.iter().filter(|m| **m).count();
        if edit.cloned > 0 {
            let sources = clone_gaussians(model, &clone)?;
            carry(adam, state, &sources)?;
            split.resize(model.len(), false);
        }
        if edit.split > 0 {
            let sources = split_gaussians(model, &split, seed)?;
            carry(adam, state, &sources)?;
        }
        Ok(())
    }
}
