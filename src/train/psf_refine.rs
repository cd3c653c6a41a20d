//! `--refine-psf`: the PSF grid learnt jointly with the splats from the aberrated photos.
//!
//! The run's grid at the image's scale starts as the supplied one; after a warm-up, every few
//! steps the step's view gives `∂L_abr/∂PSF` ([`aberration::BlurPlan::psf_gradient_pixels`],
//! through the same blur the step used) and [`aberration::refine::PsfRefiner`] takes a step.
//! `λ·L(render, I_ac)` holds the render to the restored image, so the PSF must explain the
//! blur between the render and the photo instead of the splats taking it up (or the PSF
//! taking up the scene's detail), and every view constrains the same grid.

use aberration::refine::warp::WarpRefiner;
use aberration::refine::{PsfRefiner, RefineSettings, RefineState};
use aberration::{ImagingModel, PsfGrid};
use serde::{Deserialize, Serialize};

use crate::error::{Result, TrainError};

/// What is learnt about the PSF grid.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum PsfModel {
    /// Seven numbers: per colour a scale of every PSF about its centre, varying over the
    /// field, and one rotation of the grid (`aberration::refine::warp`).
    Warp,
    /// Every PSF value, kept non-negative and unit-sum, pulled towards the supplied grid and
    /// smooth across neighbouring cells (`aberration::refine`).
    Free,
}

impl std::fmt::Display for PsfModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Warp => "warp",
            Self::Free => "free",
        })
    }
}

/// How the grid is refined (frozen settings; the state is [`PsfRefinement`]).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct PsfRefineConfig {
    pub model: PsfModel,
    /// Adam step of the PSF logits.
    pub lr: f32,
    /// Weight of the pull towards the supplied grid.
    pub anchor: f32,
    /// Weight of the smoothness of the correction across neighbouring grid cells.
    pub smooth: f32,
    /// The PSF stays as supplied until this step: the splats first take up what it explains.
    pub from: u64,
    /// Steps between two PSF updates.
    pub every: u64,
}

impl PsfRefineConfig {
    /// The defaults for a run of `iters` steps.
    pub fn for_iters(iters: u64, model: PsfModel) -> Self {
        let (lr, anchor) = match model {
            PsfModel::Free => (FREE_LR, FREE_ANCHOR),
            PsfModel::Warp => (WARP_LR, WARP_ANCHOR),
        };
        Self {
            model,
            lr,
            anchor,
            smooth: FREE_SMOOTH,
            from: iters * 3 / 10,
            every: EVERY,
        }
    }

    fn settings(&self) -> RefineSettings {
        RefineSettings {
            lr: self.lr,
            anchor: self.anchor,
            smooth: self.smooth,
        }
    }

    /// Whether the PSF takes a step after `step` (0-based, the step just rendered).
    pub fn updates_at(&self, step: u64) -> bool {
        step >= self.from && (step - self.from).is_multiple_of(self.every.max(1))
    }
}

// Chosen on the procedural scene with the calibration lasers' wavelengths (RESULTS.md, PSF
// refinement): the PSF is freed after 30 % of the run, once the splats hold what the supplied
// grid explains, and updated every other step.
pub const EVERY: u64 = 2;
pub const WARP_LR: f32 = 3e-3;
pub const WARP_ANCHOR: f32 = 1e-4;
pub const FREE_LR: f32 = 1e-2;
pub const FREE_ANCHOR: f32 = 1e-3;
pub const FREE_SMOOTH: f32 = 1.0;

enum Refiner {
    Free(PsfRefiner),
    Warp(WarpRefiner),
}

/// The grid being refined and the blur through it.
pub struct PsfRefinement {
    refiner: Refiner,
    imaging: ImagingModel,
}

impl std::fmt::Debug for PsfRefinement {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PsfRefinement")
            .field("steps", &self.state().steps)
            .finish()
    }
}

impl PsfRefinement {
    /// Starts from `supplied`'s grid at the image's scale, or continues from a checkpoint's
    /// `state`.
    pub fn new(
        config: &PsfRefineConfig,
        supplied: &ImagingModel,
        state: Option<RefineState>,
    ) -> Result<Self> {
        let grid = supplied.psf().clone();
        let bad =
            |e: aberration::AberrationError| TrainError::Invalid(format!("--refine-psf: {e}"));
        let refiner = match (config.model, state) {
            (PsfModel::Free, None) => {
                Refiner::Free(PsfRefiner::new(grid, config.settings()).map_err(bad)?)
            }
            (PsfModel::Free, Some(s)) => {
                Refiner::Free(PsfRefiner::resume(grid, config.settings(), s).map_err(bad)?)
            }
            (PsfModel::Warp, None) => {
                Refiner::Warp(WarpRefiner::new(grid, config.lr, config.anchor).map_err(bad)?)
            }
            (PsfModel::Warp, Some(s)) => {
                Refiner::Warp(WarpRefiner::resume(grid, config.lr, config.anchor, s).map_err(bad)?)
            }
        };
        let current = match &refiner {
            Refiner::Free(r) => r.current(),
            Refiner::Warp(r) => r.current(),
        };
        let imaging = supplied.with_psf(current.clone())?;
        Ok(Self { refiner, imaging })
    }

    /// The blur through the grid as refined so far.
    pub fn imaging(&self) -> &ImagingModel {
        &self.imaging
    }

    pub fn supplied(&self) -> &PsfGrid {
        match &self.refiner {
            Refiner::Free(r) => r.supplied(),
            Refiner::Warp(r) => r.supplied(),
        }
    }

    pub fn current(&self) -> &PsfGrid {
        match &self.refiner {
            Refiner::Free(r) => r.current(),
            Refiner::Warp(r) => r.current(),
        }
    }

    pub fn state(&self) -> &RefineState {
        match &self.refiner {
            Refiner::Free(r) => r.state(),
            Refiner::Warp(r) => r.state(),
        }
    }

    /// The warp's parameters (per colour log-scale at the centre and its change to the
    /// corners, then the angle), for the warp model.
    pub fn warp_params(&self) -> Option<Vec<f64>> {
        match &self.refiner {
            Refiner::Warp(r) => Some(r.params()),
            Refiner::Free(_) => None,
        }
    }

    /// One step from the loss's gradient with respect to the PSF values.
    pub fn update(&mut self, gradient: &[f32]) -> Result<()> {
        match &mut self.refiner {
            Refiner::Free(r) => r.step(gradient),
            Refiner::Warp(r) => r.step(gradient),
        }
        .map_err(|e| TrainError::Invalid(format!("--refine-psf: {e}")))?;
        self.imaging.set_psf(self.current().clone())?;
        Ok(())
    }
}

/// The warp a run learnt, as people read it (`metrics.json`).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct WarpSummary {
    /// Per colour (R, G, B), the scale of the PSFs at the centre of the field.
    pub scale_centre: [f64; 3],
    /// Per colour, the scale at the corners.
    pub scale_corner: [f64; 3],
    pub rotation_deg: f64,
}

impl WarpSummary {
    pub fn of(p: &[f64]) -> Option<Self> {
        (p.len() == aberration::refine::warp::PARAMS).then(|| Self {
            scale_centre: std::array::from_fn(|c| p[c].exp()),
            scale_corner: std::array::from_fn(|c| (p[c] + p[3 + c]).exp()),
            rotation_deg: p[6].to_degrees(),
        })
    }

    pub fn sentence(&self) -> String {
        let f = |v: [f64; 3]| {
            v.iter()
                .map(|s| format!("{:+.1} %", 100.0 * (s - 1.0)))
                .collect::<Vec<_>>()
                .join(" / ")
        };
        format!(
            "PSF scale (R / G / B) {} at the centre, {} at the corners, rotation {:+.2} degrees",
            f(self.scale_centre),
            f(self.scale_corner),
            self.rotation_deg
        )
    }
}
