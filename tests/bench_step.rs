//! `bench step` times the real training step through `tracing` spans. Alone in its test
//! binary: `tracing` caches whether a span is wanted per call site, and a training run on
//! another test thread (with no subscriber) can race that cache while this one counts.

mod common;

use metasplat::jobs::bench_step::{StepBenchRequest, prepare};
use metasplat::settings::DataOptions;
use metasplat::splats::device::DeviceChoice;
use metasplat::train::config::Mode;

/// `bench step` times the training loop's own step: its spans are all there and add up to
/// no more than the step the loop counted. Driven through the library's job, refusals first.
#[test]
fn the_step_benchmark_times_the_training_step() {
    let capture = common::small_capture(1);
    let request = StepBenchRequest {
        scene: capture.aberrated.clone(),
        mode: Mode::Aware,
        ply: None,
        steps: 3,
        threads: vec![1],
        device: DeviceChoice::Cpu,
        refine_psf: false,
        data: DataOptions {
            downsample: 1,
            ..DataOptions::default()
        },
    };
    let refused = |r: StepBenchRequest| prepare(&r).err().expect("refused").to_string();
    let e = refused(StepBenchRequest {
        threads: vec![1, 0],
        ..request.clone()
    });
    assert!(e.contains("--threads"), "{e}");
    let e = refused(StepBenchRequest {
        mode: Mode::Plain,
        refine_psf: true,
        ..request.clone()
    });
    assert!(e.contains("--refine-psf"), "{e}");
    let prepared = prepare(&request).unwrap();
    assert!(
        prepared.note.starts_with("3 training steps of mode aware"),
        "{}",
        prepared.note
    );
    let report = prepared.run().unwrap();
    assert_eq!(report.runs.len(), 1);
    assert!(report.refinement.is_empty());
    let t = &report.runs[0];
    assert_eq!(t.threads, 1);
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
