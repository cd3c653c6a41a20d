//! Commands other than splat training (`run.rs`) and the experiments (`lab/`) as jobs of the
//! library: each is prepared (every check, nothing written), then run with its events, and
//! ends in a report the binary prints.

pub mod aberrate;
pub mod bench_restorer;
pub mod bench_step;
pub mod deconvolve;
pub mod export;
pub mod frames;
pub mod psf;
pub mod render;
pub mod restore;
pub mod restorer_eval;
pub mod restorer_net;
pub mod restorer_train;
pub mod scene_aberrate;

use crate::error::{Result, TrainError};

/// A request a job refuses, and why (before any work).
pub(crate) fn refused<T>(why: String) -> Result<T> {
    Err(TrainError::Invalid(why))
}

/// Median of the timings of alternated rounds (the benchmarks' figure: the machine is shared).
pub(crate) fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n == 0 {
        return f64::NAN;
    }
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}
