//! `bench restorer` as a job: the restorer's forward passes and training steps with its fast
//! kernels and with the reference ones they replaced, alternated round by round at each thread
//! count. [`prepare`] checks every size and count; [`PreparedRestorerBench::run`] times the
//! cases and hands each row to the caller as it is done. A measurement: nothing is written.

use clap::Args;
use restore::net::kernels::Kernels;
use restore::speed::{Sample, Workload, time_workload};
use restore::{Preset, RestorerConfig};

use super::{median, refused};
use crate::error::{Result, TrainError};

/// What `bench restorer` is asked to time (its flags).
#[derive(Args, Clone, Debug)]
pub struct RestorerBenchRequest {
    /// Network sizes to time (random weights: the time does not depend on them).
    #[arg(long, value_enum, value_delimiter = ',', default_values_t = [Preset::Tiny, Preset::Small])]
    pub configs: Vec<Preset>,
    /// Tile sides of the forward passes, in px (multiples of each config's padding unit).
    #[arg(long, value_delimiter = ',', default_values_t = [256usize, 512])]
    pub sides: Vec<usize>,
    /// Crops per training step (of each config's training crop size); 0 leaves training out.
    #[arg(long, default_value_t = 4)]
    pub batch: usize,
    /// Side of the training crops, in px (a multiple of each config's padding unit); default:
    /// each config's training crop.
    #[arg(long)]
    pub crop: Option<usize>,
    /// Time training steps only, no forward passes.
    #[arg(long, conflicts_with = "sides")]
    pub train_only: bool,
    /// Thread counts to time, in order.
    #[arg(long, value_delimiter = ',', default_values_t = [1usize, 2])]
    pub threads: Vec<usize>,
    /// Rounds: each times the reference kernels, then the fast ones; the median is reported.
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u64).range(1..=100))]
    pub rounds: u64,
    /// Where to run: `cpu` (burn flex), or `libtorch` / `vulkan` in a build with that
    /// feature (libtorch's threads: `OMP_NUM_THREADS`, not --threads).
    #[arg(long, default_value = "cpu")]
    pub backend: restore::Compute,
    /// Time only the fast kernels (e.g. under `perf record`, so that a profile holds one
    /// path); the reference columns are left empty.
    #[arg(long)]
    pub fast_only: bool,
}

/// The cases to time, every size checked, on the backend's device.
pub struct PreparedRestorerBench {
    request: RestorerBenchRequest,
    cases: Vec<(RestorerConfig, Workload)>,
    device: restore::Device,
}

/// One case at one thread count: medians of the alternated rounds.
#[derive(Clone, Debug)]
pub struct RestorerBenchRow {
    pub config: String,
    pub workload: Workload,
    pub threads: usize,
    /// Wall seconds with the reference kernels (None with `--fast-only`).
    pub reference_s: Option<f64>,
    pub fast_s: f64,
    pub fast_cpu_s: f64,
    /// Analytic operations per second of the fast path (a training step counts as three
    /// forward passes).
    pub gflops: f64,
}

impl RestorerBenchRow {
    /// Wall seconds per megapixel of the fast path.
    pub fn s_per_mp(&self) -> f64 {
        self.fast_s / (self.workload.pixels() as f64 / 1e6)
    }
}

/// Thread counts, `--train-only` with nothing to train, and every side and crop (positive
/// multiples of each config's padding unit) checked; the backend's device opened.
pub fn prepare(a: &RestorerBenchRequest) -> Result<PreparedRestorerBench> {
    if a.threads.iter().any(|&t| t == 0 || t > 1024) {
        return refused("--threads: thread counts are 1 to 1024".into());
    }
    if a.train_only && a.batch == 0 {
        return refused("--train-only with --batch 0 leaves nothing to time".into());
    }
    let configs: Vec<RestorerConfig> = a
        .configs
        .iter()
        .map(|&p| RestorerConfig::preset(p))
        .collect();
    let mut cases = Vec::new();
    for cfg in &configs {
        let m = cfg.multiple();
        if !a.train_only {
            if let Some(s) = a.sides.iter().find(|&&s| s == 0 || !s.is_multiple_of(m)) {
                return refused(format!(
                    "--sides: {s} px is not a positive multiple of {m} px, the padding unit of '{}'",
                    cfg.name
                ));
            }
            cases.extend(
                a.sides
                    .iter()
                    .map(|&side| (cfg.clone(), Workload::Forward { side })),
            );
        }
        if a.batch > 0 {
            let side = a.crop.unwrap_or(cfg.crop);
            if side == 0 || !side.is_multiple_of(m) {
                return refused(format!(
                    "--crop: {side} px is not a positive multiple of {m} px, the padding unit of '{}'",
                    cfg.name
                ));
            }
            let batch = a.batch;
            cases.push((cfg.clone(), Workload::TrainStep { batch, side }));
        }
    }
    let device = a
        .backend
        .device()
        .map_err(|e| TrainError::from(e).context("--backend"))?;
    Ok(PreparedRestorerBench {
        request: a.clone(),
        cases,
        device,
    })
}

impl PreparedRestorerBench {
    /// Rounds of the reference kernels then the fast ones, per case and thread count; each
    /// row goes to `on_row` when done, and all of them are returned.
    pub fn run(self, on_row: &mut dyn FnMut(&RestorerBenchRow)) -> Result<Vec<RestorerBenchRow>> {
        let a = &self.request;
        let mut rows = Vec::new();
        for (cfg, workload) in &self.cases {
            for &threads in &a.threads {
                let mut runs: [Vec<Sample>; 2] = [Vec::new(), Vec::new()];
                for round in 0..a.rounds {
                    for (i, kernels) in [Kernels::Reference, Kernels::Fast].into_iter().enumerate()
                    {
                        if a.fast_only && kernels == Kernels::Reference {
                            continue;
                        }
                        let s =
                            time_workload(cfg, *workload, kernels, threads, 1, round, &self.device)
                                .map_err(|e| {
                                    TrainError::from(e).context(format!(
                                        "timing {} {}",
                                        cfg.name,
                                        workload.describe()
                                    ))
                                })?;
                        runs[i].extend(s);
                    }
                }
                let wall = |r: &[Sample]| median(r.iter().map(|s| s.wall_s).collect());
                let fast_s = wall(&runs[1]);
                let passes = match workload {
                    Workload::Forward { .. } => 1.0,
                    Workload::TrainStep { .. } => 3.0,
                };
                let gflop =
                    cfg.analytic_flops_per_pixel() * workload.pixels() as f64 * passes / 1e9;
                let row = RestorerBenchRow {
                    config: cfg.name.clone(),
                    workload: *workload,
                    threads,
                    reference_s: (!runs[0].is_empty()).then(|| wall(&runs[0])),
                    fast_s,
                    fast_cpu_s: median(runs[1].iter().map(|s| s.cpu_s).collect()),
                    gflops: gflop / fast_s,
                };
                on_row(&row);
                rows.push(row);
            }
        }
        Ok(rows)
    }
}
