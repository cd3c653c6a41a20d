//! Where a training step goes: the real training loop ([`crate::train::train`]) run for a few
//! steps with a `tracing` layer that adds up the time inside each of the step's spans (render
//! forward, PSF blur, loss, blur adjoint, render backward, Adam, densification statistics; on
//! a GPU the backward and Adam are one span), at each thread count asked for. The spans sit
//! in the step's own code, so nothing here can drift from what training does. A measurement,
//! not a test.

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use tracing::span::Id;
use tracing_subscriber::layer::{Context, Layer, SubscriberExt};
use tracing_subscriber::registry::LookupSpan;

use crate::error::{Result, TrainError};
use crate::splats::device::Device;
use crate::train::config::TrainConfig;
use crate::train::data::Dataset;

/// Milliseconds per step of each span, in the order the spans first ran, for one thread
/// count; `step` is the whole step as the loop counts it (hooks and bookkeeping included).
#[derive(Clone, Debug)]
pub struct StepTimes {
    pub threads: usize,
    pub phases: Vec<(&'static str, f64)>,
    pub step: f64,
}

impl StepTimes {
    /// The whole step less its named phases: hooks, bookkeeping, and what no span covers.
    pub fn other(&self) -> f64 {
        (self.step - self.phases.iter().map(|p| p.1).sum::<f64>()).max(0.0)
    }

    /// Milliseconds per step of the phase `name` (0 when it did not run).
    pub fn phase(&self, name: &str) -> f64 {
        self.phases
            .iter()
            .find(|p| p.0 == name)
            .map_or(0.0, |p| p.1)
    }
}

/// Time spent inside spans, by span name, in the order names were first seen.
#[derive(Clone, Default)]
struct SpanTimes(Arc<Mutex<Vec<(&'static str, Duration)>>>);

struct Entered(Instant);

impl<S: tracing::Subscriber + for<'a> LookupSpan<'a>> Layer<S> for SpanTimes {
    fn on_enter(&self, id: &Id, ctx: Context<'_, S>) {
        if let Some(span) = ctx.span(id) {
            span.extensions_mut().replace(Entered(Instant::now()));
        }
    }

    fn on_exit(&self, id: &Id, ctx: Context<'_, S>) {
        let Some(span) = ctx.span(id) else { return };
        let Some(Entered(at)) = span.extensions_mut().remove::<Entered>() else {
            return;
        };
        let name = span.metadata().name();
        let mut times = self.0.lock().unwrap_or_else(|e| e.into_inner());
        match times.iter_mut().find(|t| t.0 == name) {
            Some(t) => t.1 += at.elapsed(),
            None => times.push((name, at.elapsed())),
        }
    }
}

/// Trains `config` (a short run: its `iters` steps) on `data` with `threads` worker threads on
/// `device`, timing the step's spans. Every thread count starts from the same model.
pub fn time_steps(
    data: &Dataset,
    config: &TrainConfig,
    device: &Device,
    threads: usize,
) -> Result<StepTimes> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| TrainError::Invalid(format!("cannot start {threads} threads: {e}")))?;
    let spans = SpanTimes::default();
    let subscriber = tracing_subscriber::registry().with(spans.clone());
    // The loop runs on the pool's thread, so the layer is that thread's default there.
    let outcome = pool.install(|| {
        tracing::subscriber::with_default(subscriber, || {
            // A span first met on a thread without a subscriber (another run in this
            // process) may have been cached as never enabled: ask every span again.
            tracing::callsite::rebuild_interest_cache();
            crate::train::train(config, data, device, None, false, &mut |_| {})
        })
    })?;
    let per_step = |d: Duration| d.as_secs_f64() * 1e3 / config.iters.max(1) as f64;
    let phases = spans
        .0
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .iter()
        .map(|&(name, d)| (name, per_step(d)))
        .collect();
    Ok(StepTimes {
        threads,
        phases,
        step: outcome.train_seconds * 1e3 / config.iters.max(1) as f64,
    })
}
