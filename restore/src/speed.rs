//! Timing the network as `metasplat bench restorer` reports it: forward passes and training
//! steps (forward, backward, AdamW), with either kernels ([`Kernels`]), on a pool of a given
//! number of threads, in wall time and in CPU time (the machine is shared, so CPU seconds and
//! ratios measured side by side are what compare).

use crate::config::RestorerConfig;
use crate::error::{RestoreError, Result};
use crate::infer::run_tile;
use crate::net::RestorerNet;
use crate::net::kernels::{Kernels, with_kernels};
use crate::tiles::Planes;
use aberration::wiener::BANK_SIZE;
use burn::optim::{AdamWConfig, GradientsParams};
use burn::tensor::{Device, Tensor, TensorData};
use std::time::Instant;

/// What is timed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Workload {
    /// One forward pass of a `side × side` tile, as inference runs it.
    Forward { side: usize },
    /// One training step on `batch` crops of `side × side`.
    TrainStep { batch: usize, side: usize },
}

impl Workload {
    /// Pixels one run processes (all crops of a step).
    pub fn pixels(self) -> usize {
        match self {
            Workload::Forward { side } => side * side,
            Workload::TrainStep { batch, side } => batch * side * side,
        }
    }

    pub fn describe(self) -> String {
        match self {
            Workload::Forward { side } => format!("forward {side}²"),
            Workload::TrainStep { batch, side } => format!("train step {batch}×{side}²"),
        }
    }
}

/// One timed run.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sample {
    pub wall_s: f64,
    /// CPU seconds of the whole process (user and system, all threads) over the run.
    pub cpu_s: f64,
}

/// CPU seconds this process has used (user and system, every thread); `None` where the
/// system does not say (outside Linux).
pub fn process_cpu_seconds() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    // Fields after the command name, which is in parentheses and may hold spaces.
    let rest = &stat[stat.rfind(')')? + 2..];
    let fields: Vec<&str> = rest.split_whitespace().collect();
    // utime and stime are fields 14 and 15 of the line, 12 and 13 after the name.
    let ticks: f64 = fields.get(11)?.parse::<f64>().ok()? + fields.get(12)?.parse::<f64>().ok()?;
    // Linux reports these in USER_HZ, which is 100 on every architecture it supports.
    Some(ticks / 100.0)
}

/// Input planes of values in [0, 1) from a fixed pseudo-random stream started at `seed`
/// (timing needs inputs, not photos).
pub fn planes(c: usize, h: usize, w: usize, seed: u64) -> Planes {
    let mut s = seed;
    let data = (0..c * h * w)
        .map(|_| {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 40) as f32 / (1u64 << 24) as f32
        })
        .collect();
    Planes { c, h, w, data }
}

/// Times `reps` runs of `workload` for a network of `config` (weights from `seed`), after
/// one untimed run (first-touch page faults and lazy set-up are not the kernels' cost), on
/// a pool of `threads` threads with `kernels`.
pub fn time_workload(
    config: &RestorerConfig,
    workload: Workload,
    kernels: Kernels,
    threads: usize,
    reps: usize,
    seed: u64,
    device: &Device,
) -> Result<Vec<Sample>> {
    let m = config.multiple();
    let side = match workload {
        Workload::Forward { side } | Workload::TrainStep { side, .. } => side,
    };
    if side == 0 || !side.is_multiple_of(m) {
        return Err(RestoreError::BadInput(format!(
            "a {side} px side: config '{}' needs a positive multiple of {m} px",
            config.name
        )));
    }
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| RestoreError::BadInput(format!("cannot start {threads} threads: {e}")))?;
    pool.install(|| {
        with_kernels(kernels, || match workload {
            Workload::Forward { side } => Ok(time_forward(config, side, reps, seed, device)),
            Workload::TrainStep { batch, side } => {
                Ok(time_train_step(config, batch, side, reps, seed, device))
            }
        })
    })
}

fn timed(f: impl FnOnce()) -> Sample {
    let cpu0 = process_cpu_seconds().unwrap_or(f64::NAN);
    let t = Instant::now();
    f();
    Sample {
        wall_s: t.elapsed().as_secs_f64(),
        cpu_s: process_cpu_seconds().unwrap_or(f64::NAN) - cpu0,
    }
}

fn time_forward(
    config: &RestorerConfig,
    side: usize,
    reps: usize,
    seed: u64,
    device: &Device,
) -> Vec<Sample> {
    let device = device.clone();
    device.seed(seed);
    let net = RestorerNet::new(config, &device);
    let x = planes(3 * BANK_SIZE, side, side, seed);
    let _ = run_tile(&net, &x, &device);
    (0..reps)
        .map(|_| {
            timed(|| {
                let _ = run_tile(&net, &x, &device);
            })
        })
        .collect()
}

fn time_train_step(
    config: &RestorerConfig,
    batch: usize,
    side: usize,
    reps: usize,
    seed: u64,
    device: &Device,
) -> Vec<Sample> {
    let device = device.clone().autodiff();
    device.seed(seed);
    let mut net = RestorerNet::new(config, &device);
    let mut optim = AdamWConfig::new().init();
    let x = planes(3 * BANK_SIZE, side, batch * side, seed);
    let x = Tensor::<4>::from_data(
        TensorData::new(x.data, [batch, 3 * BANK_SIZE, side, side]),
        &device,
    );
    let y = Tensor::<4>::from_data(
        TensorData::new(
            vec![0.5f32; batch * 3 * side * side],
            [batch, 3, side, side],
        ),
        &device,
    );
    let mut step = |net: RestorerNet| {
        let loss = (net.forward(x.clone()) - y.clone()).abs().mean();
        let grads = GradientsParams::from_grads(loss.backward(), &net);
        optim.step(3e-4, net, grads)
    };
    net = step(net);
    let mut samples = Vec::with_capacity(reps);
    for _ in 0..reps {
        let mut next = None;
        samples.push(timed(|| next = Some(step(net.clone()))));
        net = next.expect("the step ran");
    }
    samples
}
