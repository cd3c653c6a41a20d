//! When a run of `--iters auto` ends: once densification (and a fading λ) is over, as soon as
//! training stops paying, judged only from the training views.
//!
//! Steps are grouped into windows of whole epochs (every training view once per window, in
//! the order [`crate::train::view_index`] draws), so the mean training PSNR of one window and
//! the next differ by what the model learnt, not by which views happened to be drawn. The
//! trend is the least-squares slope through the last [`SPAN`] window means (one window's mean
//! still wanders by a few hundredths of a dB); the run stops when it has been below
//! `min_gain_db` per window at `patience` window ends in a row, then a short final phase at
//! the final position learning rate ends it.

use serde::{Deserialize, Serialize};

/// Gain (dB of training PSNR per 1000 steps) below which training has stopped paying. The
/// training views keep gaining long after the held-out ones have stopped (the model learns
/// them by heart): on the demo scene the training PSNR still rose 0.5-1 dB per 1000 steps
/// where the held-out PSNR had been flat for a thousand steps (RESULTS.md).
pub const MIN_GAIN_DB_PER_1000: f64 = 1.0;
/// Window means the trend is fitted through.
pub const SPAN: usize = 5;
/// Windows in a row that must each gain less, so that one noisy window does not stop a run.
pub const PATIENCE: u32 = 2;
/// Shortest window (steps): a capture of few views still averages over this many.
pub const MIN_WINDOW: u64 = 100;

#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct StopRule {
    /// Steps per window: a whole number of epochs, at least [`MIN_WINDOW`].
    pub window: u64,
    /// Least trend of the windows' mean training PSNR (dB per window).
    pub min_gain_db: f64,
    pub patience: u32,
    /// No stop before this step (densification and a fading λ are over).
    pub not_before: u64,
    /// Steps of the final phase after the rule fires.
    pub final_steps: u64,
}

/// What the rule has seen: the open window's sum, the closed windows' means, and the end of
/// the run once decided. Kept in checkpoints, so a resumed run stops where the straight one
/// would.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct StopState {
    sum: f64,
    count: u64,
    /// Mean training PSNR of every closed window, in order.
    pub windows: Vec<f64>,
    /// Closed windows in a row that gained too little.
    flat: u32,
    /// The step the run ends at, once the rule has fired, and why.
    pub end: Option<(u64, String)>,
}

impl StopRule {
    /// The rule for `views` training views, with no stop before `not_before`.
    pub fn new(views: usize, not_before: u64) -> Self {
        let views = views.max(1) as u64;
        let window = MIN_WINDOW.div_ceil(views) * views;
        StopRule {
            window,
            min_gain_db: MIN_GAIN_DB_PER_1000 * window as f64 / 1000.0,
            patience: PATIENCE,
            not_before,
            final_steps: window,
        }
    }

    /// Takes the training PSNR of the step that brought the count of steps done to `done`;
    /// returns the end of the run when this step decides it.
    pub fn observe(&self, s: &mut StopState, done: u64, psnr: f64) -> Option<(u64, String)> {
        if s.end.is_some() {
            return None;
        }
        if psnr.is_finite() {
            s.sum += psnr;
            s.count += 1;
        }
        if !done.is_multiple_of(self.window) {
            return None;
        }
        let mean = if s.count > 0 {
            s.sum / s.count as f64
        } else {
            f64::NAN
        };
        (s.sum, s.count) = (0.0, 0);
        s.windows.push(mean);
        // Only windows wholly past `not_before` enter the trend.
        let past = done.saturating_sub(self.not_before) / self.window;
        if past < SPAN as u64 {
            s.flat = 0;
            return None;
        }
        let slope = trend(&s.windows[s.windows.len() - SPAN..]);
        match slope {
            g if g < self.min_gain_db => s.flat += 1,
            // A trend through a window without a finite PSNR is no evidence either way.
            g if g.is_nan() => {}
            _ => s.flat = 0,
        }
        if s.flat < self.patience {
            return None;
        }
        let reason = format!(
            "the training views' PSNR rose {:+.3} dB per {} steps over the last {} (less than {:.3})",
            slope,
            self.window,
            SPAN as u64 * self.window,
            self.min_gain_db
        );
        let end = (done + self.final_steps, reason);
        s.end = Some(end.clone());
        Some(end)
    }
}

/// Least-squares slope through `means` at unit spacing (per window).
fn trend(means: &[f64]) -> f64 {
    let n = means.len() as f64;
    let mid = (n - 1.0) / 2.0;
    let den: f64 = (0..means.len()).map(|i| (i as f64 - mid).powi(2)).sum();
    means
        .iter()
        .enumerate()
        .map(|(i, m)| (i as f64 - mid) * m)
        .sum::<f64>()
        / den
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Runs `rule` over `curve(step)` (the PSNR after each step) up to `cap` steps; the step
    /// the rule fired at, if it did.
    fn fires(rule: &StopRule, cap: u64, curve: impl Fn(u64) -> f64) -> Option<u64> {
        let mut s = StopState::default();
        (1..=cap).find(|&done| rule.observe(&mut s, done, curve(done)).is_some())
    }

    /// Deterministic noise in [-1, 1], a function of the step.
    fn noise(step: u64) -> f64 {
        let mut r = base::rng::SplitMix64::new(step.wrapping_mul(0x9E37));
        2.0 * r.next_f64() - 1.0
    }

    #[test]
    fn windows_are_whole_epochs_of_at_least_a_hundred_steps() {
        for (views, window) in [(1, 100), (17, 102), (12, 108), (69, 138), (250, 250)] {
            let r = StopRule::new(views, 0);
            assert_eq!(r.window, window, "{views} views");
            assert!(r.window.is_multiple_of(views as u64));
            assert!((r.min_gain_db - window as f64 / 1000.0).abs() < 1e-12);
        }
    }

    #[test]
    fn a_plateau_stops_the_run() {
        let rule = StopRule::new(17, 1000);
        // Rises 6 dB with a time constant of 400 steps: flat by step ~2500.
        let at = fires(&rule, 20_000, |t| {
            20.0 + 6.0 * (1.0 - (-(t as f64) / 400.0).exp())
        })
        .expect("a plateau must stop the run");
        assert!((1000..3500).contains(&at), "{at}");
    }

    #[test]
    fn a_slow_steady_gain_does_not_stop_it() {
        let rule = StopRule::new(17, 1000);
        // 1.5 dB per 1000 steps, above the 1.0 the rule asks for, all the way.
        assert_eq!(
            fires(&rule, 20_000, |t| 20.0 + 1.5 * t as f64 / 1000.0),
            None
        );
        // Just below it: stops at the second window end whose trend lies past densification
        // (windows end at multiples of 102; five lie wholly past step 1000 at 1530).
        let at = fires(&rule, 20_000, |t| 20.0 + 0.9 * t as f64 / 1000.0).unwrap();
        assert_eq!(at, 1632, "{at}");
    }

    #[test]
    fn noise_does_not_stop_it_early() {
        let rule = StopRule::new(17, 500);
        // What a step's PSNR swings by: which view it is (±3 dB, the same view each epoch, in
        // a new order every epoch), and the step itself (±0.3 dB).
        let swing = |t: u64| {
            let view = crate::train::view_index(7, t - 1, 17) as u64;
            3.0 * noise(1000 + view) + 0.3 * noise(t)
        };
        // A steady 2 dB per 1000 steps under that noise: no trend may look flat by chance.
        let curve = |t: u64| 20.0 + 2.0 * t as f64 / 1000.0 + swing(t);
        assert_eq!(fires(&rule, 20_000, curve), None);
        // The same noise on a plateau after step 3000 stops it, and not before the plateau.
        let plateau = |t: u64| 20.0 + 2.0 * t.min(3000) as f64 / 1000.0 + swing(t);
        let at = fires(&rule, 20_000, plateau).expect("stops on the plateau");
        assert!((3000..5000).contains(&at), "{at}");
    }

    #[test]
    fn it_never_stops_before_densification_ends() {
        // Flat from the first step: the first stop comes once the trend's windows and the
        // patience's lie wholly past `not_before`.
        let rule = StopRule::new(10, 2500);
        let first = 2500 + (SPAN as u64 + 1) * rule.window;
        let at = fires(&rule, 20_000, |_| 25.0).unwrap();
        assert_eq!(at, first, "{at}");
        // NaN steps (no finite PSNR) neither stop nor break it.
        let at = fires(&rule, 20_000, |t| if t % 3 == 0 { f64::NAN } else { 25.0 }).unwrap();
        assert_eq!(at, first);
    }

    #[test]
    fn the_end_is_decided_once_and_names_the_gain() {
        let rule = StopRule::new(10, 0);
        let mut s = StopState::default();
        let mut end = None;
        for done in 1..=2000 {
            if let Some(e) = rule.observe(&mut s, done, 30.0) {
                assert!(end.is_none());
                end = Some((done, e));
            }
        }
        let (at, (until, why)) = end.unwrap();
        assert_eq!(until, at + rule.final_steps);
        assert_eq!(s.end, Some((until, why.clone())));
        assert!(
            why.contains("rose +0.000 dB per 100 steps over the last 500"),
            "{why}"
        );
        // Serialised and read back (a checkpoint), the state goes on the same way.
        let back: StopState = serde_json::from_str(&serde_json::to_string(&s).unwrap()).unwrap();
        assert_eq!(back, s);
    }
}
