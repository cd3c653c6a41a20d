//! `bench step` times the real training step through `tracing` spans. Alone in its test
//! binary: `tracing` caches whether a span is wanted per call site, and a training run on
//! another test thread (with no subscriber) can race that cache while this one counts.

mod common;

use metasplat::settings::DataOptions;
use metasplat::splats::device::Device;
use metasplat::train::config::{Mode, TrainConfig};
use metasplat::train::data;

/// `bench step` times the training loop's own step: its spans are all there and add up to
/// no more than the step the loop counted.
#[test]
fn the_step_benchmark_times_the_training_step() {
    let capture = common::small_capture(1);
    let aberrated = &capture.aberrated;
    let options = DataOptions {
        downsample: 1,
        ..DataOptions::default()
    };
    let data = data::load(aberrated, Mode::Aware, &options).unwrap();
    let settings = metasplat::settings::TrainSettings {
        mode: Mode::Aware,
        iters: metasplat::settings::Iters::Steps(3),
        eval_every: Some(0),
        checkpoint_every: Some(0),
        ..Default::default()
    };
    let cfg = TrainConfig::build(&settings, 0, &data);
    let t = metasplat::train::timing::time_steps(&data, &cfg, &Device::Cpu, 1).unwrap();
    let names: Vec<&str> = t.phases.iter().map(|p| p.0).collect();
    for want in [
        "render forward",
        "PSF blur",
        "loss",
        "blur adjoint",
        "render backward",
        "Adam",
        "densification statistics",
    ] {
        assert!(names.contains(&want), "no span '{want}' in {names:?}");
    }
    let named: f64 = t.phases.iter().map(|p| p.1).sum();
    assert!(t.phases.iter().all(|p| p.1 > 0.0), "{:?}", t.phases);
    assert!(
        named <= t.step * 1.001,
        "{named} ms of spans in a {} ms step",
        t.step
    );
}
