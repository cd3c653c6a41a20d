//! The estimate of a training step's memory, which `restorer train` refuses a batch with
//! before it allocates, bounds what a step holds from above without overstating it wildly:
//! measured with a counting allocator over every thread.

use burn::tensor::Device;
use restore::config::RestorerConfig;
use restore::net::kernels::Kernels;
use restore::speed::{Workload, time_workload};

#[global_allocator]
static ALLOCATOR: base::alloc_watch::Watching = base::alloc_watch::Watching;

#[test]
fn the_training_memory_estimate_bounds_a_step_from_above() {
    for (cfg, batch, side) in [
        (RestorerConfig::tiny(), 2, 64),
        (RestorerConfig::tiny(), 1, 128),
        (RestorerConfig::small(), 1, 64),
    ] {
        let workload = Workload::TrainStep { batch, side };
        let (timed, held) = base::alloc_watch::across_threads(|| {
            time_workload(&cfg, workload, Kernels::Fast, 2, 1, 0, &Device::flex())
        });
        timed.unwrap();
        let estimate = cfg.training_bytes(batch, side) as usize;
        eprintln!(
            "{} {}: held {:.1} MB, estimated {:.1} MB ({:.2}x)",
            cfg.name,
            workload.describe(),
            held as f64 / 1e6,
            estimate as f64 / 1e6,
            estimate as f64 / held as f64
        );
        assert!(
            estimate >= held && estimate <= 4 * held,
            "{} {}: a step held {held} bytes, the estimate is {estimate}",
            cfg.name,
            workload.describe()
        );
    }
}
