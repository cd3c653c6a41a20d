//! SH bands on demand: the model stores only the bands it renders, gains one every
//! `sh_every` steps (as 3DGS raises its active degree), and gives the top band back, and stops
//! growing, when that band does not lower the training loss. A flat-coloured scene thus
//! keeps 3 floats of colour per splat instead of 48.

use serde::{Deserialize, Serialize};
use splat::Gaussians;
use splat::optim::Adam;

use crate::error::Result;

#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum ShEvent {
    Raised {
        degree: u32,
    },
    /// Band `degree + 1` was dropped: its loss gain was below the threshold.
    Dropped {
        degree: u32,
        gain: f64,
    },
    /// Band `degree` was tested and kept.
    Kept {
        degree: u32,
        gain: f64,
    },
}

impl std::fmt::Display for ShEvent {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match *self {
            Self::Raised { degree } => write!(f, "colour detail raised to SH degree {degree}"),
            Self::Kept { degree, gain } => write!(
                f,
                "SH band {degree} kept: it lowers the training loss by {:.2} %",
                gain * 100.0
            ),
            Self::Dropped { degree, gain } => write!(
                f,
                "SH band {} dropped: it lowered the training loss by only {:.3} %, so colours stay at degree {degree}",
                degree + 1,
                gain * 100.0
            ),
        }
    }
}

/// When bands are raised and what a band must earn, fixed for a run.
#[derive(Clone, Debug, PartialEq)]
pub struct ShSchedule {
    pub max_degree: u32,
    pub every: u64,
    /// A band stays when dropping it raises the training loss by at least this fraction
    /// ([`crate::train::config::Recipe::sh_min_gain`]).
    pub min_gain: f64,
}

/// What the schedule's hooks change (saved in checkpoints; a checkpoint's header of earlier
/// versions, which also held the schedule, still reads as one).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ShState {
    /// No more bands once one was dropped.
    pub frozen: bool,
}

/// The mean training loss when rendering with a given number of bands: what a band is
/// judged on. It must be the loss the step minimises at that moment (λ included).
pub type BandLoss<'a> = dyn FnMut(&Gaussians, u32) -> Result<f64> + 'a;

impl ShSchedule {
    pub fn new(max_degree: u32, every: u64, min_gain: f64) -> Self {
        Self {
            max_degree: max_degree.min(splat::MAX_SH_DEGREE),
            every: every.max(1),
            min_gain,
        }
    }

    /// Tests the model's top band with `loss_at(model, degree)` (the mean training loss when
    /// rendering with `degree` bands); drops it if it does not pay.
    fn test_top(
        &self,
        state: &mut ShState,
        model: &mut Gaussians,
        adam: &mut Adam,
        loss_at: &mut BandLoss,
    ) -> Result<Option<ShEvent>> {
        let d = model.sh_degree;
        if d == 0 {
            return Ok(None);
        }
        let with = loss_at(model, d)?;
        let without = loss_at(model, d - 1)?;
        let gain = (without - with) / with.abs().max(1e-12);
        if gain < self.min_gain {
            model.set_sh_degree(d - 1);
            adam.set_sh_degree(d - 1);
            state.frozen = true;
            Ok(Some(ShEvent::Dropped {
                degree: d - 1,
                gain,
            }))
        } else {
            Ok(Some(ShEvent::Kept { degree: d, gain }))
        }
    }

    /// Whether [`ShSchedule::after_step`] reads or edits the model at `step`.
    pub fn acts_at(&self, state: &ShState, step: u64) -> bool {
        !state.frozen && step != 0 && step.is_multiple_of(self.every)
    }

    /// Called after every step: on a band step, test the top band, then raise if it paid.
    pub fn after_step(
        &self,
        state: &mut ShState,
        step: u64,
        model: &mut Gaussians,
        adam: &mut Adam,
        loss_at: &mut BandLoss,
    ) -> Result<Vec<ShEvent>> {
        let mut events = Vec::new();
        if !self.acts_at(state, step) {
            return Ok(events);
        }
        if let Some(e) = self.test_top(state, model, adam, loss_at)? {
            events.push(e);
        }
        if !state.frozen && model.sh_degree < self.max_degree {
            let d = model.sh_degree + 1;
            model.set_sh_degree(d);
            adam.set_sh_degree(d);
            events.push(ShEvent::Raised { degree: d });
        }
        Ok(events)
    }

    /// At the end of training: drop top bands while they do not pay.
    pub fn finish(
        &self,
        state: &mut ShState,
        model: &mut Gaussians,
        adam: &mut Adam,
        loss_at: &mut BandLoss,
    ) -> Result<Vec<ShEvent>> {
        let mut events = Vec::new();
        while let Some(e) = self.test_top(state, model, adam, loss_at)? {
            events.push(e);
            if matches!(e, ShEvent::Kept { .. }) {
                break;
            }
        }
        Ok(events)
    }
}
