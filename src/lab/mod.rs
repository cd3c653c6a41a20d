//! Experiments as library jobs: each checks its inputs, makes what it shares once under its
//! folder, trains its runs and returns a report the binary prints (`metasplat experiment`),
//! saying each stage to a callback as it goes. The runs are trained through a [`Runner`],
//! so the binary can show each run's progress while the job decides what is trained.

pub mod budget;
pub mod demo;
pub mod llff;
pub mod psf_mismatch;
pub mod runs;

use crate::error::Result;
use crate::output::RunSummary;
use crate::settings::RunRequest;

/// Trains one run of an experiment: its summary and training log.
pub type Runner<'a> =
    dyn FnMut(&RunRequest) -> Result<(RunSummary, Vec<crate::train::LogRow>)> + 'a;

/// How close to its final held-out PSNR a run counts as having arrived, coarse and fine.
const NEAR_FINAL_DB: [f64; 2] = [0.5, 0.1];

/// The first evaluation of a run whose held-out PSNR is within `db` of the last one, and when
/// it came: `(step, seconds, total seconds)`.
fn near_final(log: &[crate::train::LogRow], db: f64) -> Option<(u64, f64, f64)> {
    let evals: Vec<_> = log.iter().filter(|r| r.test_psnr.is_some()).collect();
    let last = evals.last()?;
    let final_psnr = last.test_psnr?;
    let first = evals
        .iter()
        .find(|r| r.test_psnr.is_some_and(|p| p >= final_psnr - db))?;
    Some((first.step, first.seconds, last.seconds))
}

/// Where a run came within each of [`NEAR_FINAL_DB`] of its final held-out PSNR, as
/// "step S (M min, P %)" phrases, and its whole training time.
fn arrival(log: &[crate::train::LogRow]) -> Option<(Vec<String>, f64)> {
    let mut total = 0.0;
    let phrases = NEAR_FINAL_DB
        .iter()
        .map(|&db| {
            near_final(log, db).map(|(step, seconds, all)| {
                total = all;
                format!(
                    "within {db} dB at step {step} ({:.1} min, {:.0} %)",
                    seconds / 60.0,
                    100.0 * seconds / all.max(1e-9)
                )
            })
        })
        .collect::<Option<Vec<_>>>()?;
    Some((phrases, total))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::train::LogRow;

    fn row(step: u64, seconds: f64, psnr: Option<f64>) -> LogRow {
        LogRow {
            step,
            seconds,
            loss: 0.0,
            train_psnr: 0.0,
            test_psnr: psnr,
            test_ssim: None,
            splats: 0,
            sh_degree: 0,
        }
    }

    #[test]
    fn near_final_finds_the_first_evaluation_within_half_a_decibel() {
        let log = [
            row(100, 10.0, Some(20.0)),
            row(150, 15.0, None),
            row(200, 20.0, Some(25.4)),
            row(300, 30.0, Some(25.6)),
            row(400, 40.0, Some(25.2)),
            row(500, 50.0, Some(26.0)),
        ];
        // 25.6 is the first at or above 26.0 - 0.5; 25.4 is not. Within 0.1: only the last.
        assert_eq!(near_final(&log, 0.5), Some((300, 30.0, 50.0)));
        assert_eq!(near_final(&log, 0.1), Some((500, 50.0, 50.0)));
        assert_eq!(near_final(&[row(1, 1.0, None)], 0.5), None);
        assert_eq!(near_final(&[], 0.5), None);
        let (phrases, total) = arrival(&log).unwrap();
        assert_eq!(total, 50.0);
        assert_eq!(
            phrases,
            [
                "within 0.5 dB at step 300 (0.5 min, 60 %)",
                "within 0.1 dB at step 500 (0.8 min, 100 %)"
            ]
        );
    }
}
