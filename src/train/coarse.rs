//! Coarse to fine: the first steps of a run train on its views shrunk by whole factors (4,
//! then 2, …), as fast trainers do (OpenSplat's `--num-downscales`, DashGaussian), because a
//! young model has no detail a full-size render would show. Each level holds its own copy
//! of the training views, area-shrunk as LLFF's `images_N/` are, with cameras scaled
//! exactly (the remainder rows and columns are dropped, so the scale is exactly `1/n`), and
//! the lens shrunk alike ([`aberration::ImagingModel::shrunk`]) for `L_abr`. Held-out
//! evaluation, the SH-band probes and PSF refinement stay at full size.
//!
//! This module holds the schedule ([`Coarse`]); the shrunk views and lens a run trains on
//! during it are [`crate::train::levels`].

use serde::{Deserialize, Serialize};

/// The smallest side a coarse level may shrink a view to: below it a level's renders hold
/// too few pixels to say where anything is, and [`Coarse::for_capture`] uses fewer levels.
pub const MIN_COARSE_SIDE: u32 = 32;

/// One coarse level: steps before `until` train on views `factor` times smaller.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct CoarseLevel {
    pub factor: u32,
    pub until: u64,
}

/// The resolution schedule: levels coarsest first, each ending where the next begins; full
/// size from the last level's end.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Coarse {
    pub levels: Vec<CoarseLevel>,
}

impl Coarse {
    /// `levels` levels of `steps` steps each, the first `2^levels` times smaller, halving the
    /// factor at each level; fewer where the capture's shorter side would fall below
    /// [`MIN_COARSE_SIDE`]. None when no level is left.
    pub fn for_capture(levels: u32, steps: u64, width: u32, height: u32) -> Option<Self> {
        let side = width.min(height);
        let fit = (0..=levels.min(8))
            .rev()
            .find(|&l| side >> l >= MIN_COARSE_SIDE)
            .unwrap_or(0);
        if fit == 0 || steps == 0 {
            return None;
        }
        Some(Coarse {
            levels: (0..fit)
                .map(|k| CoarseLevel {
                    factor: 1 << (fit - k),
                    until: steps * (k as u64 + 1),
                })
                .collect(),
        })
    }

    /// The shrink factor of step `step` (1: full size).
    pub fn factor_at(&self, step: u64) -> u32 {
        self.levels
            .iter()
            .find(|l| step < l.until)
            .map_or(1, |l| l.factor)
    }

    /// The schedule in a sentence, for views of `width × height`.
    pub fn describe(&self, width: u32, height: u32) -> String {
        let mut from = 0;
        let parts: Vec<String> = self
            .levels
            .iter()
            .map(|l| {
                let part = format!(
                    "steps {from}-{} at 1/{} size ({}x{})",
                    l.until - 1,
                    l.factor,
                    width / l.factor,
                    height / l.factor
                );
                from = l.until;
                part
            })
            .collect();
        format!(
            "Coarse to fine: {}, full size from step {from}.",
            parts.join(", ")
        )
    }

    /// The first step at full size.
    pub fn end(&self) -> u64 {
        self.levels.last().map_or(0, |l| l.until)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn schedule_halves_the_factor_and_fits_the_capture() {
        let c = Coarse::for_capture(2, 700, 504, 378).unwrap();
        assert_eq!(
            c.levels,
            vec![
                CoarseLevel {
                    factor: 4,
                    until: 700
                },
                CoarseLevel {
                    factor: 2,
                    until: 1400
                }
            ]
        );
        assert_eq!(
            [0, 699, 700, 1399, 1400, 7000].map(|s| c.factor_at(s)),
            [4, 4, 2, 2, 1, 1]
        );
        assert_eq!(c.end(), 1400);
        // 120 px: a 4x level would be 30 px, under the floor; one 2x level is left.
        let small = Coarse::for_capture(2, 100, 160, 120).unwrap();
        assert_eq!(
            small.levels,
            vec![CoarseLevel {
                factor: 2,
                until: 100
            }]
        );
        assert_eq!(Coarse::for_capture(2, 100, 60, 40), None);
        assert_eq!(Coarse::for_capture(0, 100, 600, 400), None);
        assert_eq!(Coarse::for_capture(2, 0, 600, 400), None);
    }
}
