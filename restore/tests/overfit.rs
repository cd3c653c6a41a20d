//! The overfit check, alone in its own test binary: burn's seed is global to the backend, so
//! tests beside it would reseed it concurrently and change this network's initialisation.

use burn::module::Module;
use burn::optim::{AdamWConfig, GradientsParams};
use burn::tensor::{Device, Tensor, TensorData};
use restore::{RestorerConfig, RestorerNet};

#[test]
fn a_few_training_steps_on_a_fixed_batch_reduce_the_loss() {
    let device = Device::flex().autodiff();
    device.seed(21);
    let cfg = RestorerConfig::tiny();
    // burn draws a parameter's initial values when it is first read; reading them all now, in
    // the module's order, keeps the initialisation from depending on the order in which the
    // forward pass's kernels read them.
    let mut net = RestorerNet::new(&cfg, &device);
    net = RestorerNet::new(&cfg, &device).load_record(net.into_record());
    let (b, s) = (2, 32);
    // Inputs: 13 noisy, dimmed and offset copies of a smooth target, so the median input is far
    // from the target whatever the initial weights (tests share burn's global seed, so the
    // initialisation here depends on what runs beside it): the loss must fall well below that.
    let target: Vec<f32> = (0..b * 3 * s * s)
        .map(|i| {
            let (x, y) = ((i % s) as f32, ((i / s) % s) as f32);
            0.5 + 0.3 * (0.3 * x).sin() * (0.2 * y).cos()
        })
        .collect();
    let mut rng = 7u64;
    let mut noisy = Vec::with_capacity(b * 39 * s * s);
    for bi in 0..b {
        for _ in 0..13 {
            for i in 0..3 * s * s {
                rng = rng
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                noisy.push(
                    0.6 * target[bi * 3 * s * s + i]
                        + 0.1
                        + 0.2 * ((rng >> 40) as f32 / (1u64 << 24) as f32 - 0.5),
                );
            }
        }
    }
    let x = Tensor::<4>::from_data(TensorData::new(noisy, [b, 39, s, s]), &device);
    let y = Tensor::<4>::from_data(TensorData::new(target, [b, 3, s, s]), &device);
    let mut optim = AdamWConfig::new().init();
    let mut losses = vec![];
    for _ in 0..12 {
        let loss = (net.forward(x.clone()) - y.clone()).abs().mean();
        let grads = GradientsParams::from_grads(loss.backward(), &net);
        losses.push(loss.into_scalar::<f32>());
        net = optim.step(1e-3, net, grads);
    }
    let (first, last) = (losses[0], *losses.last().unwrap());
    assert!(losses.iter().all(|l| l.is_finite()));
    assert!(first > 0.08, "{losses:?}");
    assert!(last < 0.6 * first, "{losses:?}");
    assert!(net.valid().num_params() == cfg.analytic_params());
}
