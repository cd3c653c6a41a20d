//! The densification strategy: the 3DGS "default strategy" (clone small, split large, prune
//! transparent, optional opacity reset) held to a splat budget, plus pruning of splats that
//! no training view can see. The trainer calls it at three hooks (after backward, after the
//! optimiser step, at the end of an epoch) and once at the end, so the loop stays short. As in
//! gsplat's strategies, the settings ([`DensifyStrategy`], fixed for a run) are apart from the
//! state the hooks change ([`DensifyState`], what a checkpoint keeps).

use serde::{Deserialize, Serialize};
use splat::conventions::ALPHA_THRESHOLD;
use splat::densify::{
    DensifyStats, clone_gaussians, prune_gaussians, prune_mask, reset_opacity, split_gaussians,
};
use splat::model::sigmoid;
use splat::optim::{Adam, ParamGroup};
use splat::{Gaussians, RenderOutput};

use crate::error::Result;
use crate::train::config::Recipe;

/// What one hook changed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Edit {
    pub cloned: usize,
    pub split: usize,
    pub pruned: usize,
    /// Candidates turned away because the budget was reached.
    pub over_budget: usize,
    pub opacity_reset: bool,
}

impl std::fmt::Display for Edit {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} cloned, {} split, {} pruned",
            self.cloned, self.split, self.pruned
        )?;
        if self.over_budget > 0 {
            write!(f, ", {} turned away at the splat budget", self.over_budget)?;
        }
        if self.opacity_reset {
            write!(f, ", opacities reset")?;
        }
        Ok(())
    }
}

/// The strategy's settings, fixed for a run: the recipe's thresholds and schedule, the splat
/// budget and the scene's extent. The hooks read them and change only a [`DensifyState`].
#[derive(Clone, Debug)]
pub struct DensifyStrategy {
    pub recipe: Recipe,
    pub budget: usize,
    pub extent: f32,
}

/// What the hooks accumulate between their calls (saved in checkpoints).
#[derive(Clone, Debug)]
pub struct DensifyState {
    pub stats: DensifyStats,
    /// Visible in at least one training view since the epoch began.
    pub seen: Vec<bool>,
}

impl DensifyState {
    /// Whether [`DensifyStrategy::end_of_epoch`] would prune anything now.
    pub fn has_unseen(&self) -> bool {
        self.seen.iter().any(|s| !s)
    }

    /// A new epoch: no splat seen yet.
    pub fn start_epoch(&mut self) {
        self.seen.fill(false);
    }
}

/// Applies a structural edit's `sources` to everything indexed by Gaussian.
fn carry(adam: &mut Adam, state: &mut DensifyState, sources: &[Option<usize>]) -> Result<()> {
    adam.remap(sources)?;
    state.stats.remap(sources)?;
    let seen = &state.seen;
    state.seen = sources.iter().map(|s| s.is_none_or(|i| seen[i])).collect();
    Ok(())
}

impl DensifyStrategy {
    pub fn new(recipe: Recipe, budget: usize, extent: f32) -> Self {
        Self {
            recipe,
            budget,
            extent,
        }
    }

    /// The state of a run starting with `n` splats.
    pub fn initialize_state(&self, n: usize) -> DensifyState {
        DensifyState {
            stats: DensifyStats::new(n),
            seen: vec![false; n],
        }
    }

    fn densifying(&self, step: u64) -> bool {
        step < self.recipe.densify_until
    }

    /// Hook 1: accumulate this view's screen-space gradients and visibility.
    pub fn after_backward(
        &self,
        state: &mut DensifyState,
        step: u64,
        means2d: &[[f32; 2]],
        out: &RenderOutput,
    ) {
        for (s, v) in state.seen.iter_mut().zip(&out.visible) {
            *s |= *v;
        }
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

    /// Whether [`DensifyStrategy::after_step`] reads or edits the model at `step`.
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
            self.grow(state, model, adam, seed ^ step, &mut edit)?;
            let after_reset = r.opacity_reset_every.is_some_and(|every| step > every);
            let mask = prune_mask(
                model,
                r.prune_opacity,
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

    /// Hook 3, when every training view has been rendered once since the last call: splats
    /// no view saw get no gradient and can never contribute, so they go.
    pub fn end_of_epoch(
        &self,
        state: &mut DensifyState,
        model: &mut Gaussians,
        adam: &mut Adam,
    ) -> Result<usize> {
        let mask: Vec<bool> = state.seen.iter().map(|s| !s).collect();
        let pruned = prune(state, model, adam, &mask)?;
        state.start_epoch();
        Ok(pruned)
    }

    /// At the end of training: drop splats too transparent ever to be blended (α < 1/255
    /// everywhere), which leaves every render unchanged.
    pub fn finish(
        &self,
        state: &mut DensifyState,
        model: &mut Gaussians,
        adam: &mut Adam,
    ) -> Result<usize> {
        let mask: Vec<bool> = model
            .logit_opacities
            .iter()
            .map(|&o| sigmoid(o) < ALPHA_THRESHOLD)
            .collect();
        prune(state, model, adam, &mask)
    }

    /// Clone or split the splats with the largest mean screen gradients, as many as the budget
    /// allows (each adds one splat).
    fn grow(
        &self,
        state: &mut DensifyState,
        model: &mut Gaussians,
        adam: &mut Adam,
        seed: u64,
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
        let room = self.budget.saturating_sub(n);
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

fn prune(
    state: &mut DensifyState,
    model: &mut Gaussians,
    adam: &mut Adam,
    mask: &[bool],
) -> Result<usize> {
    let count = mask.iter().filter(|m| **m).count();
    if count > 0 {
        let sources = prune_gaussians(model, mask)?;
        carry(adam, state, &sources)?;
    }
    Ok(count)
}
