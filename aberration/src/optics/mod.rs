//! Metalens optics: phase profile → focal-plane field → sensor PSF grid.

pub mod phase;
pub mod propagate;
pub mod sensor;
pub mod simulate;

pub use phase::{Dispersion, Lens, PhaseProfile};
pub use propagate::{FocalWindow, Propagator};
pub use simulate::{FieldPoint, SimConfig, SimReport, simulate_grid};
