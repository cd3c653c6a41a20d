//! A network made from a seed is the same network whichever kernels first run it. burn draws a
//! parameter's initial values when it is first read, so a kernel that read a layer's bias
//! before its weights would hand the two each other's random draws and change every
//! from-scratch training run. Alone in its test binary: burn's seed is global to the backend.

use burn::tensor::{Device, Tensor, TensorData};
use restore::net::kernels::{Kernels, with_kernels};
use restore::{RestorerConfig, RestorerNet};

#[test]
fn a_seeded_network_is_initialised_alike_under_either_kernels() {
    let device = Device::flex().autodiff();
    let (b, s) = (2, 32);
    let x: Vec<f32> = (0..b * 39 * s * s)
        .map(|i| 0.3 + 0.4 * (i as f32 * 0.37).sin())
        .collect();
    let x = Tensor::<4>::from_data(TensorData::new(x, [b, 39, s, s]), &device);
    let outputs: Vec<Vec<f32>> = [Kernels::Fast, Kernels::Reference]
        .into_iter()
        .map(|kernels| {
            device.seed(21);
            let net = RestorerNet::new(&RestorerConfig::tiny(), &device);
            with_kernels(kernels, || net.forward(x.clone()))
                .try_into_vec_as::<f32>()
                .unwrap()
        })
        .collect();
    let scale = outputs[1].iter().fold(0.0f32, |m, v| m.max(v.abs()));
    let diff = outputs[0]
        .iter()
        .zip(&outputs[1])
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f32, f32::max);
    // The two kernels agree to 1e-4 of the scale on one network (tests/kernels.rs); two
    // different initialisations differ by about the output's scale.
    assert!(diff < 1e-4 * scale.max(1.0), "{diff:e} of {scale}");
}
