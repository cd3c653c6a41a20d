//! Experiments as library jobs: each checks its inputs, makes what it shares once under its
//! folder, trains its runs and returns a report the binary prints (`metasplat experiment`),
//! saying each stage to a callback as it goes.

pub mod psf_mismatch;
pub mod runs;
