//! The timing the restorer benchmark reports: one sample per repetition, wall and CPU seconds
//! that grow with the work, and sizes the network cannot take refused before anything runs.

use burn::tensor::Device;
use restore::RestorerConfig;
use restore::net::kernels::Kernels;
use restore::speed::{Workload, process_cpu_seconds, time_workload};

#[test]
fn samples_count_the_work_and_bad_sizes_are_refused() {
    let cfg = RestorerConfig::tiny();
    let side = cfg.multiple();
    for kernels in [Kernels::Fast, Kernels::Reference] {
        let small = time_workload(
            &cfg,
            Workload::Forward { side },
            kernels,
            1,
            2,
            0,
            &Device::flex(),
        )
        .unwrap();
        assert_eq!(small.len(), 2);
        let big = time_workload(
            &cfg,
            Workload::Forward { side: 4 * side },
            kernels,
            1,
            1,
            0,
            &Device::flex(),
        )
        .unwrap();
        for s in small.iter().chain(&big) {
            assert!(s.wall_s > 0.0 && s.wall_s.is_finite());
            assert!(s.cpu_s >= 0.0 && s.cpu_s.is_finite(), "{s:?}");
        }
        // Sixteen times the pixels takes longer, in wall time and in CPU time.
        assert!(big[0].wall_s > small[0].wall_s, "{big:?} vs {small:?}");
        assert!(big[0].cpu_s > small[0].cpu_s, "{big:?} vs {small:?}");
    }
    let step = Workload::TrainStep { batch: 1, side };
    assert_eq!(step.pixels(), side * side);
    assert_eq!(
        time_workload(&cfg, step, Kernels::Fast, 1, 1, 0, &Device::flex())
            .unwrap()
            .len(),
        1
    );
    let err = time_workload(
        &cfg,
        Workload::Forward { side: side + 1 },
        Kernels::Fast,
        1,
        1,
        0,
        &Device::flex(),
    )
    .unwrap_err()
    .to_string();
    assert!(
        err.contains(&format!("{} px", side + 1)) && err.contains("tiny"),
        "{err}"
    );
    assert!(process_cpu_seconds().is_some(), "Linux reports CPU time");
}
