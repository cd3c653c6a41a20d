//! The densification strategies: how splats are added, moved and removed as training goes.
//! [`Adaptive`] is 3DGS's (clone, split, prune on screen-space gradients); [`Mcmc`] treats the
//! splats as samples and moves transparent ones onto opaque ones, which is what reconstructs
//! a capture from random points. The trainer calls the strategy at three hooks (after
//! backward, after the optimiser step, at the end of an epoch) and once at the end, so the
//! loop stays short. As in gsplat's strategies, the settings (fixed for a run) are apart from
//! the state the hooks change ([`DensifyState`], what a checkpoint keeps).

pub mod adaptive;
pub mod mcmc;

pub use adaptive::Adaptive;
pub use mcmc::Mcmc;

use serde::{Deserialize, Serialize};
use splat::conventions::ALPHA_THRESHOLD;
use splat::densify::{DensifyStats, prune_gaussians};
use splat::model::sigmoid;
use splat::optim::Adam;
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
    /// Transparent splats moved onto opaque ones (MCMC).
    #[serde(default)]
    pub relocated: usize,
    /// Splats added as copies of opaque ones (MCMC).
    #[serde(default)]
    pub added: usize,
}

impl std::fmt::Display for Edit {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let mut parts = Vec::new();
        if self.relocated > 0 || self.added > 0 {
            parts.push(format!(
                "{} relocated, {} added",
                self.relocated, self.added
            ));
        } else {
            parts.push(format!(
                "{} cloned, {} split, {} pruned",
                self.cloned, self.split, self.pruned
            ));
        }
        if self.over_budget > 0 {
            parts.push(format!(
                "{} turned away at the splat budget",
                self.over_budget
            ));
        }
        if self.opacity_reset {
            parts.push("opacities reset".into());
        }
        f.write_str(&parts.join(", "))
    }
}

/// What the hooks accumulate between their calls (saved in checkpoints).
#[derive(Clone, Debug)]
pub struct DensifyState {
    pub stats: DensifyStats,
    /// Visible in at least one training view since the epoch began.
    pub seen: Vec<bool>,
}

impl DensifyState {
    /// Whether [`DensifyStrategy::end_of_epoch`] would act now.
    pub fn has_unseen(&self) -> bool {
        self.seen.iter().any(|s| !s)
    }

    /// A new epoch: no splat seen yet.
    pub fn start_epoch(&mut self) {
        self.seen.fill(false);
    }
}

/// What the end of an epoch did with the splats no view saw.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Unseen {
    Pruned(usize),
    Relocated(usize),
}

impl std::fmt::Display for Unseen {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Unseen::Pruned(n) => write!(f, "{n} splats no view saw were pruned"),
            Unseen::Relocated(n) => {
                write!(f, "{n} splats no view saw were moved onto ones it does")
            }
        }
    }
}

/// The most splats a strategy may grow to after a step: the run's budget, shared out by
/// pixel count while coarse to fine trains at a smaller size (a view shrunk 4 times has a
/// sixteenth of the pixels to fit, so it gets a sixteenth of the splats: DashGaussian's
/// splat count that follows the resolution). The count grows on at full size.
#[derive(Clone, Debug, PartialEq)]
pub struct Budget {
    pub max: usize,
    pub coarse: Option<crate::train::coarse::Coarse>,
}

impl Budget {
    /// A budget of `max` at every step.
    pub fn fixed(max: usize) -> Self {
        Self { max, coarse: None }
    }

    /// The budget after `step` steps, when the next step trains at the level of `step`.
    pub fn at(&self, step: u64) -> usize {
        let f = self.coarse.as_ref().map_or(1, |c| c.factor_at(step)) as usize;
        (self.max / (f * f)).max(1)
    }
}

/// The strategy of a run: its settings, fixed for the run.
#[derive(Clone, Debug)]
pub enum DensifyStrategy {
    Adaptive(Adaptive),
    Mcmc(Mcmc),
}

impl DensifyStrategy {
    /// The adaptive strategy with `recipe`, `budget` and the scene's `extent`.
    pub fn new(recipe: Recipe, budget: Budget, extent: f32) -> Self {
        Self::Adaptive(Adaptive::new(recipe, budget, extent))
    }

    /// The state of a run starting with `n` splats.
    pub fn initialize_state(&self, n: usize) -> DensifyState {
        DensifyState {
            stats: DensifyStats::new(n),
            seen: vec![false; n],
        }
    }

    /// Sets up the splats made from the capture's points the way the strategy starts.
    pub fn prepare_initial(&self, model: &mut Gaussians) {
        if let Self::Mcmc(m) = self {
            m.prepare_initial(model);
        }
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
        if let Self::Adaptive(a) = self {
            a.after_backward(state, step, means2d, out);
        }
    }

    /// Whether [`DensifyStrategy::after_step`] reads or edits the model at `step`.
    pub fn acts_at(&self, step: u64) -> bool {
        match self {
            Self::Adaptive(a) => a.acts_at(step),
            Self::Mcmc(m) => m.acts_at(step),
        }
    }

    /// Hook 2, after the optimiser step `step` (1-based count of steps done). Returns what it
    /// changed when it changed the model's structure or opacities.
    pub fn after_step(
        &self,
        state: &mut DensifyState,
        step: u64,
        model: &mut Gaussians,
        adam: &mut Adam,
        seed: u64,
    ) -> Result<Option<Edit>> {
        match self {
            Self::Adaptive(a) => a.after_step(state, step, model, adam, seed),
            Self::Mcmc(m) => m.after_step(state, step, model, adam, seed),
        }
    }

    /// Hook 3, when every training view has been rendered once since the last call: splats
    /// no view saw get no gradient and can never contribute, so they go (adaptive) or move
    /// onto ones that do (MCMC, which keeps its count).
    pub fn end_of_epoch(
        &self,
        state: &mut DensifyState,
        step: u64,
        model: &mut Gaussians,
        adam: &mut Adam,
        seed: u64,
    ) -> Result<Unseen> {
        let unseen: Vec<bool> = state.seen.iter().map(|s| !s).collect();
        let done = match self {
            Self::Adaptive(_) => Unseen::Pruned(prune(state, model, adam, &unseen)?),
            Self::Mcmc(m) => {
                Unseen::Relocated(m.relocate(state, model, adam, &unseen, seed ^ step)?)
            }
        };
        state.start_epoch();
        Ok(done)
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
}

/// Applies a structural edit's `sources` to everything indexed by Gaussian.
fn carry(adam: &mut Adam, state: &mut DensifyState, sources: &[Option<usize>]) -> Result<()> {
    adam.remap(sources)?;
    state.stats.remap(sources)?;
    let seen = &state.seen;
    state.seen = sources.iter().map(|s| s.is_none_or(|i| seen[i])).collect();
    Ok(())
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_splat_budget_follows_the_pixel_count() {
        let b = Budget {
            max: 95_000,
            coarse: crate::train::coarse::Coarse::for_capture(2, 700, 504, 378),
        };
        assert_eq!(
            [0, 699, 700, 1399, 1400].map(|s| b.at(s)),
            [5937, 5937, 23_750, 23_750, 95_000]
        );
        assert_eq!(Budget::fixed(7).at(0), 7);
    }
}
