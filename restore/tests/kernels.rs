//! The fast kernels against the reference ones they replaced: the shipped weights restore a
//! crop alike (to 1e-4, float order), and a training step's loss and gradients agree.

use aberration::optics::{SimConfig, simulate_grid};
use aberration::{BlurMode, Image, ImagingModel, NoiseModel};
use burn::module::Module;
use burn::tensor::{Device, Distribution, Tensor, TensorData};
use restore::data::bank_images;
use restore::infer::{bank_planes, run_tile};
use restore::net::conv_train::trained_applies;
use restore::net::kernels::{Kernels, with_kernels};
use restore::net::layers::{conv, conv3, depthwise, depthwise3, enhance_query, pointwise};
use restore::{RestorerConfig, RestorerNet, shipped};

/// Holds the tests of this binary to one at a time. Each seeds the backend's one random
/// generator and draws its inputs and layers from it: with tests drawing in parallel the draws
/// interleaved and changed from run to run (one such draw once missed a bound).
fn serial() -> std::sync::MutexGuard<'static, ()> {
    static LOCK: std::sync::Mutex<()> = std::sync::Mutex::new(());
    // A test that failed while holding it leaves it poisoned; the others still run.
    LOCK.lock().unwrap_or_else(|e| e.into_inner())
}

fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.try_into_vec_as::<f32>().unwrap()
}

fn max_abs_diff(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

/// Each of `fast`'s tensors (named by `names`) within `tol` of `reference`'s largest value,
/// and finite; `case` names the sizes in a failure.
fn assert_within_scale(
    names: &[&str],
    fast: &[Vec<f32>],
    reference: &[Vec<f32>],
    tol: f32,
    case: &str,
) {
    assert_eq!(fast.len(), reference.len());
    for (what, (a, r)) in names.iter().zip(fast.iter().zip(reference)) {
        assert!(a.iter().all(|v| v.is_finite()), "{case}: {what} not finite");
        let scale = r.iter().fold(0.0f32, |m, v| m.max(v.abs())).max(1e-6);
        let err = max_abs_diff(a, r) / scale;
        assert!(err < tol, "{case}: {what} {err:.2e} of the scale");
    }
}

/// A photo-like test card: smooth shading, a hard edge, fine stripes and a dot grid.
fn test_card(w: usize, h: usize) -> Image {
    let mut data = Vec::with_capacity(3 * w * h);
    for c in 0..3 {
        for y in 0..h {
            for x in 0..w {
                let (u, v) = (x as f32 / w as f32, y as f32 / h as f32);
                let shade = 0.3 + 0.4 * u * (1.0 - v) + 0.1 * c as f32;
                let edge = if u + 0.5 * v > 0.7 { 0.25 } else { 0.0 };
                let stripes = 0.15 * ((x as f32 * 0.9 + c as f32).sin());
                let dots = if x % 9 < 2 && y % 7 < 2 { 0.2 } else { 0.0 };
                data.push((shade + edge + stripes + dots).clamp(0.0, 1.0));
            }
        }
    }
    Image {
        width: w,
        height: h,
        data,
    }
}

#[test]
fn the_shipped_weights_restore_a_crop_alike_with_fast_and_reference_kernels() {
    let _serial = serial();
    let (native, _) = simulate_grid(&SimConfig::default(), &|_, _| {}).unwrap();
    let restorer = shipped::for_psf(&native).unwrap().expect("shipped weights");
    // Not square, and not a multiple of the key window, so border windows are masked.
    let (w, h) = (160, 96);
    assert_eq!(w % restorer.config().multiple(), 0);
    assert_eq!(h % restorer.config().multiple(), 0);
    let clean = test_card(w, h);
    let model =
        ImagingModel::new(&native, w, h, BlurMode::Tiled, None, NoiseModel::default()).unwrap();
    let blurred = model.capture(&clean, 5).unwrap();
    let bank = bank_images(&blurred, model.psf(), true).unwrap();
    let x = bank_planes(&bank);
    let device = restorer.device.clone();
    let fast = with_kernels(Kernels::Fast, || run_tile(&restorer.net, &x, &device));
    let reference = with_kernels(Kernels::Reference, || run_tile(&restorer.net, &x, &device));
    assert!(fast.data.iter().all(|v| v.is_finite()));
    let err = max_abs_diff(&fast.data, &reference.data);
    println!("shipped tiny on a {w}x{h} crop: |fast - reference| max {err:.2e}");
    assert!(err <= 1e-4, "max abs difference {err:.2e}");
    // The comparison could fail: the network's output is not the input's base image.
    let spread = reference.data.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    assert!(spread > 0.1);
}

#[test]
fn query_enhancement_from_the_planes_equals_the_square_pool_with_its_gradient() {
    let _serial = serial();
    // Without gradients and under autodiff, where the gradient is the same kernel again.
    for device in [Device::flex(), Device::flex().autodiff()] {
        device.seed(11);
        // A box wider than the map, too.
        for (k, h, w) in [
            (3, 19, 23),
            (7, 19, 23),
            (11, 19, 23),
            (15, 19, 23),
            (7, 3, 2),
        ] {
            let x = Tensor::<4>::random([2, 3, h, w], Distribution::Normal(0.0, 1.0), &device);
            let x = if x.is_autodiff() { x.require_grad() } else { x };
            let wts = Tensor::<4>::random([2, 3, h, w], Distribution::Normal(0.0, 1.0), &device);
            let run = |kernels| {
                with_kernels(kernels, || {
                    let y = enhance_query(x.clone(), k);
                    if !y.is_autodiff() {
                        return (values(y), Vec::new());
                    }
                    let g = (y.clone() * wts.clone()).sum().backward();
                    (values(y), values(x.grad(&g).expect("input gradient")))
                })
            };
            let (fast, reference) = (run(Kernels::Fast), run(Kernels::Reference));
            let err = max_abs_diff(&fast.0, &reference.0);
            assert!(err < 1e-5, "k {k} on {h}x{w}: {err:.2e}");
            assert_eq!(fast.1.len(), reference.1.len());
            let err = max_abs_diff(&fast.1, &reference.1);
            assert!(err < 1e-5, "k {k} on {h}x{w}: gradient {err:.2e}");
        }
    }
}

#[test]
fn pointwise_convolution_as_a_matrix_product_equals_the_convolution() {
    let _serial = serial();
    // With gradients, where the matrix product is used.
    let device = Device::flex().autodiff();
    device.seed(12);
    for bias in [false, true] {
        let mut c = conv(5, 7, 1, bias, &device);
        if let Some(b) = c.bias.as_mut() {
            *b = burn::module::Param::from_tensor(Tensor::random(
                [7],
                Distribution::Normal(0.0, 1.0),
                &device,
            ));
        }
        assert!(c.weight.val().is_require_grad());
        let x = Tensor::<4>::random([3, 5, 6, 9], Distribution::Normal(0.0, 1.0), &device);
        let fast = with_kernels(Kernels::Fast, || pointwise(&c, x.clone()));
        assert_eq!(fast.dims(), [3, 7, 6, 9]);
        let err = max_abs_diff(&values(fast), &values(c.forward(x)));
        assert!(err < 1e-5, "bias {bias}: {err:.2e}");
    }
}

/// A layer's output and its input, weight and bias gradients with the fast kernels against
/// burn's `Conv2d` (the reference path), under autodiff on the CPU, where `apply` takes the
/// hand-written kernels. A weighted sum is the loss, so each output's gradient differs.
fn agrees_with_burns_convolution(
    mut layer: burn::nn::conv::Conv2d,
    dims: [usize; 4],
    bias: bool,
    apply: fn(&burn::nn::conv::Conv2d, Tensor<4>) -> Tensor<4>,
) {
    let device = Device::flex().autodiff();
    let cout = layer.weight.dims()[0];
    if bias {
        layer.bias = Some(burn::module::Param::from_tensor(Tensor::random(
            [cout],
            Distribution::Normal(0.0, 1.0),
            &device,
        )));
    }
    let x = Tensor::<4>::random(dims, Distribution::Normal(0.0, 1.0), &device).require_grad();
    assert!(
        trained_applies(&x),
        "the fast path must apply to autodiff CPU maps"
    );
    let [b, _, h, w] = dims;
    let wts = Tensor::<4>::random([b, cout, h, w], Distribution::Normal(0.0, 1.0), &device);
    let run = |kernels| {
        with_kernels(kernels, || {
            let y = apply(&layer, x.clone());
            let loss = (y.clone() * wts.clone()).sum();
            let g = loss.backward();
            let mut out = vec![
                values(y),
                values(x.grad(&g).expect("input gradient")),
                values(layer.weight.val().grad(&g).expect("weight gradient")),
            ];
            if let Some(bias) = &layer.bias {
                out.push(values(bias.val().grad(&g).expect("bias gradient")));
            }
            out
        })
    };
    let (fast, reference) = (run(Kernels::Fast), run(Kernels::Reference));
    assert_eq!(fast.len(), reference.len());
    for (what, (a, r)) in [
        "output",
        "input gradient",
        "weight gradient",
        "bias gradient",
    ]
    .iter()
    .zip(fast.iter().zip(&reference))
    {
        let scale = r.iter().fold(0.0f32, |m, v| m.max(v.abs())).max(1e-6);
        let err = max_abs_diff(a, r);
        assert!(
            err <= 1e-5 * scale * (b * h * w) as f32,
            "{dims:?} {what}: max |fast - burn| {err:.2e} of {scale:.2e}"
        );
    }
    assert_eq!(fast[2].len(), layer.weight.dims().iter().product::<usize>());
}

#[test]
fn the_hand_written_depthwise_convolution_has_burns_values_and_gradients() {
    let _serial = serial();
    // Odd sizes, one- and two-pixel-wide maps.
    let device = Device::flex().autodiff();
    device.seed(21);
    for (dims, bias) in [
        ([2, 5, 7, 9], false),
        ([1, 3, 1, 6], true),
        ([3, 4, 5, 2], false),
        ([1, 2, 4, 1], true),
    ] {
        agrees_with_burns_convolution(depthwise3(dims[1], &device), dims, bias, depthwise);
    }
}

#[test]
fn the_1x1_convolution_as_a_matrix_product_has_burns_gradients() {
    let _serial = serial();
    let device = Device::flex().autodiff();
    device.seed(23);
    // A batch of one and of three, with and without bias, a one-pixel map, and one product
    // large enough for burn to split it over the threads (32 · 32 · 96²).
    for (dims, cout, bias) in [
        ([3, 5, 7, 9], 4, true),
        ([1, 6, 4, 5], 3, false),
        ([2, 3, 1, 1], 5, true),
        ([1, 32, 96, 96], 32, true),
    ] {
        agrees_with_burns_convolution(conv(dims[1], cout, 1, bias, &device), dims, bias, pointwise);
    }
}

#[test]
fn the_dense_3x3_convolution_with_a_hand_written_backward_has_burns_values_and_gradients() {
    let _serial = serial();
    let device = Device::flex().autodiff();
    device.seed(22);
    for (dims, cout, bias) in [
        ([2, 5, 7, 9], 3, false),
        ([1, 3, 1, 6], 4, true),
        ([3, 4, 5, 2], 1, false),
        ([1, 2, 4, 1], 6, true),
    ] {
        agrees_with_burns_convolution(conv(dims[1], cout, 3, bias, &device), dims, bias, conv3);
    }
}

/// The loss and the gradient of every parameter of a small network, on a batch of two crops
/// that are not multiples of the key window.
fn loss_and_gradients(net: &RestorerNet, x: &Tensor<4>, y: &Tensor<4>) -> (f32, Vec<Vec<f32>>) {
    let loss = (net.forward(x.clone()) - y.clone()).abs().mean();
    let value = values(loss.clone())[0];
    let grads = loss.backward();
    let mut all = Vec::new();
    struct Collect<'a> {
        grads: &'a burn::tensor::Gradients,
        out: &'a mut Vec<Vec<f32>>,
    }
    impl burn::module::ModuleVisitor for Collect<'_> {
        fn visit_float<const D: usize>(&mut self, param: &burn::module::Param<Tensor<D>>) {
            if let Some(g) = param.val().grad(self.grads) {
                self.out.push(values(g));
            }
        }
    }
    net.visit(&mut Collect {
        grads: &grads,
        out: &mut all,
    });
    (value, all)
}

#[test]
fn a_training_step_has_the_same_loss_and_gradients_with_either_kernels() {
    let _serial = serial();
    let device = Device::flex().autodiff();
    device.seed(13);
    let cfg = RestorerConfig {
        dim: 8,
        blocks: [1, 1, 1, 1],
        refinement: 1,
        ..RestorerConfig::tiny()
    };
    let net = RestorerNet::new(&cfg, &device);
    let side = cfg.multiple();
    let x = Tensor::<4>::random([2, 39, side, side], Distribution::Default, &device);
    let y = Tensor::<4>::from_data(
        TensorData::new(vec![0.5f32; 2 * 3 * side * side], [2, 3, side, side]),
        &device,
    );
    let (lf, gf) = with_kernels(Kernels::Fast, || loss_and_gradients(&net, &x, &y));
    let (lr, gr) = with_kernels(Kernels::Reference, || loss_and_gradients(&net, &x, &y));
    assert!((lf - lr).abs() <= 1e-5 * lr.abs().max(1.0), "{lf} vs {lr}");
    assert_eq!(gf.len(), gr.len());
    assert!(gf.len() > 50, "{} parameter gradients", gf.len());
    for (i, (a, b)) in gf.iter().zip(&gr).enumerate() {
        let scale = b.iter().fold(0.0f32, |m, v| m.max(v.abs())).max(1e-6);
        let err = max_abs_diff(a, b);
        assert!(
            err <= 1e-3 * scale,
            "parameter {i}: max |fast - reference| {err:.2e} of {scale:.2e}"
        );
    }
}

#[test]
fn the_one_pass_gated_depthwise_equals_the_tensor_gdfn() {
    let _serial = serial();
    let device = Device::flex();
    device.seed(14);
    // Odd sizes, a one-pixel-wide map and a batch of two.
    for (c, hidden, h, w) in [(4, 6, 7, 9), (3, 5, 1, 6), (2, 3, 5, 1)] {
        let mut m = restore::net::layers::Gdfn::new(c, hidden, &device);
        m.depthwise.weight = burn::module::Param::from_tensor(Tensor::random(
            m.depthwise.weight.val().dims(),
            Distribution::Normal(0.0, 1.0),
            &device,
        ));
        let x = Tensor::<4>::random([2, c, h, w], Distribution::Normal(0.0, 2.0), &device);
        let fast = with_kernels(Kernels::Fast, || values(m.forward(x.clone())));
        let reference = with_kernels(Kernels::Reference, || values(m.forward(x.clone())));
        let err = max_abs_diff(&fast, &reference);
        assert!(err < 1e-5, "{c}x{hidden} at {h}x{w}: {err:.2e}");
    }
}

#[test]
fn the_vectorised_gelu_matches_burns_erf_gelu() {
    let _serial = serial();
    let device = Device::flex();
    let xs: Vec<f32> = (0..=4000).map(|i| -10.0 + i as f32 * 0.005).collect();
    let n = xs.len();
    let want = values(burn::tensor::activation::gelu(Tensor::<1>::from_data(
        TensorData::new(xs.clone(), [n]),
        &device,
    )));
    let got: Vec<f32> = xs.iter().map(|&x| restore::net::gelu::gelu(x)).collect();
    let err = max_abs_diff(&got, &want);
    assert!(err < 1e-6, "max abs difference {err:.2e}");
    assert!(restore::net::gelu::gelu(f32::NAN).is_nan());
}

#[test]
fn the_gelu_extension_has_burns_values_and_gradient() {
    let _serial = serial();
    let device = Device::flex().autodiff();
    // Past ±10 too, where the slope's Gaussian underflows.
    let xs: Vec<f32> = (0..=6000).map(|i| -30.0 + i as f32 * 0.01).collect();
    let n = xs.len();
    let x = Tensor::<4>::from_data(TensorData::new(xs, [1, 1, 1, n]), &device).require_grad();
    let wts = Tensor::<4>::random([1, 1, 1, n], Distribution::Normal(0.0, 1.0), &device);
    let run = |kernels| {
        with_kernels(kernels, || {
            let y = restore::net::layers::gelu(x.clone());
            let g = (y.clone() * wts.clone()).sum().backward();
            (values(y), values(x.grad(&g).expect("input gradient")))
        })
    };
    let ((y, dx), (y_ref, dx_ref)) = (run(Kernels::Fast), run(Kernels::Reference));
    assert!(y.iter().chain(&dx).all(|v| v.is_finite()));
    let err = max_abs_diff(&y, &y_ref);
    assert!(err < 1e-5, "values: {err:.2e}");
    let err = max_abs_diff(&dx, &dx_ref);
    assert!(err < 1e-5, "gradient: {err:.2e}");
}

/// The direct kernels' output bits of a seeded `tiny` network on a small input, under the
/// build this process chose.
fn direct_kernel_bits() -> Vec<u32> {
    let device = Device::flex();
    device.seed(3);
    let net = RestorerNet::new(&RestorerConfig::tiny(), &device);
    let x = restore::speed::planes(39, 64, 96, 11);
    let y = with_kernels(Kernels::Fast, || run_tile(&net, &x, &device));
    y.data.iter().map(|v| v.to_bits()).collect()
}

/// The direct kernels give the same bits in every build: the build the CPU chose against the
/// portable loops (`METASPLAT_NO_AVX2`), each in a child process running only this test,
/// since the build is chosen once per process (`base::isa`) and the network's seeded weights
/// come from the device's one generator, which tests running beside it would draw from.
#[test]
fn the_direct_kernels_have_the_same_bits_in_every_build() {
    let _serial = serial();
    const OUT: &str = "METASPLAT_TEST_RESTORE_BITS";
    if let Some(path) = std::env::var_os(OUT) {
        eprintln!("this child runs the {:?} build", base::isa::Isa::chosen());
        let bytes: Vec<u8> = direct_kernel_bits()
            .iter()
            .flat_map(|b| b.to_le_bytes())
            .collect();
        std::fs::write(path, bytes).unwrap();
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let run = |portable: bool| -> Vec<u32> {
        let path = dir
            .path()
            .join(if portable { "portable" } else { "chosen" });
        let mut child = std::process::Command::new(std::env::current_exe().unwrap());
        child
            .args([
                "--exact",
                "the_direct_kernels_have_the_same_bits_in_every_build",
                "--test-threads",
                "1",
            ])
            .env(OUT, &path)
            .env_remove("METASPLAT_NO_AVX2")
            .env_remove("METASPLAT_NO_AVX512");
        if portable {
            child.env("METASPLAT_NO_AVX2", "1");
        }
        assert!(child.status().unwrap().success(), "the child failed");
        std::fs::read(&path)
            .unwrap()
            .chunks_exact(4)
            .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect()
    };
    let (chosen, portable) = (run(false), run(true));
    assert_eq!(chosen.len(), portable.len());
    assert!(!chosen.is_empty());
    let differ = chosen.iter().zip(&portable).filter(|(a, b)| a != b).count();
    assert_eq!(differ, 0, "{differ} of {} outputs differ", chosen.len());
}

/// LayerNorm over channels in f64, written out: the independent reference.
fn channel_norm_f64(x: &[f32], g: &[f32], b: &[f32], [n, c, h, w]: [usize; 4]) -> Vec<f32> {
    let plane = h * w;
    let mut out = vec![0.0f32; x.len()];
    for i in 0..n {
        for p in 0..plane {
            let at = |ch: usize| (i * c + ch) * plane + p;
            let mean = (0..c).map(|ch| x[at(ch)] as f64).sum::<f64>() / c as f64;
            let var = (0..c)
                .map(|ch| (x[at(ch)] as f64 - mean).powi(2))
                .sum::<f64>()
                / c as f64;
            for ch in 0..c {
                let v = (x[at(ch)] as f64 - mean) / (var + 1e-5).sqrt();
                out[at(ch)] = (v * g[ch] as f64 + b[ch] as f64) as f32;
            }
        }
    }
    out
}

#[test]
fn the_two_pass_channel_norm_equals_the_tensor_layernorm_and_an_f64_one() {
    let _serial = serial();
    use restore::net::layers::ChannelNorm;
    let device = Device::flex();
    device.seed(21);
    // Odd sizes, a plane longer than one strip and not a multiple of it, a batch of two,
    // one channel (variance zero everywhere), a one-pixel map.
    for (c, h, w) in [(5, 7, 9), (16, 17, 31), (1, 4, 4), (3, 1, 1)] {
        let mut m = ChannelNorm::new(c, &device);
        let g = Tensor::<1>::random([c], Distribution::Normal(1.0, 0.5), &device);
        let b = Tensor::<1>::random([c], Distribution::Normal(0.0, 0.5), &device);
        m.weight = burn::module::Param::from_tensor(g.clone());
        m.bias = burn::module::Param::from_tensor(b.clone());
        // An offset far above the spread: a one-pass variance would lose it.
        let x = Tensor::<4>::random([2, c, h, w], Distribution::Normal(0.0, 2.0), &device)
            .add_scalar(300.0);
        let fast = with_kernels(Kernels::Fast, || values(m.forward(x.clone())));
        let reference = with_kernels(Kernels::Reference, || values(m.forward(x.clone())));
        let exact = channel_norm_f64(&values(x), &values(g), &values(b), [2, c, h, w]);
        let scale = exact.iter().fold(1.0f32, |a, v| a.max(v.abs()));
        let err = max_abs_diff(&fast, &exact) / scale;
        let err_ref = max_abs_diff(&reference, &exact) / scale;
        assert!(fast.iter().all(|v| v.is_finite()), "{c}x{h}x{w}");
        assert!(err < 1e-4, "{c}x{h}x{w}: fast {err:.2e} of the scale");
        assert!(
            err_ref < 1e-4,
            "{c}x{h}x{w}: reference {err_ref:.2e} of the scale"
        );
    }
}

#[test]
fn the_fusion_gate_through_the_mean_equals_the_whole_fuse_out_map() {
    let _serial = serial();
    use restore::net::staf::{BlockSpec, Gate, StafBlock};
    let device = Device::flex();
    device.seed(22);
    let randomise =
        |t: Tensor<4>| Tensor::<4>::random(t.dims(), Distribution::Normal(0.0, 0.4), &device);
    for gate in [Gate::PerPixel, Gate::PerChannel] {
        let spec = BlockSpec {
            channels: 8,
            channel_heads: 2,
            window_heads: 2,
            win: 4,
            kwin: 8,
            hidden: 12,
            qe: 3,
            gate,
        };
        let mut block = StafBlock::new(spec, &device);
        // Biases and weights away from their initial values, so that a dropped term shows.
        block.fuse_out.weight =
            burn::module::Param::from_tensor(randomise(block.fuse_out.weight.val()));
        let bias = Tensor::<1>::random([8], Distribution::Normal(0.0, 0.5), &device);
        block.fuse_out.bias = Some(burn::module::Param::from_tensor(bias));
        let x = Tensor::<4>::random([2, 8, 12, 16], Distribution::Normal(0.0, 1.0), &device);
        let fast = with_kernels(Kernels::Fast, || values(block.forward(x.clone())));
        let reference = with_kernels(Kernels::Reference, || values(block.forward(x.clone())));
        let scale = reference.iter().fold(1.0f32, |a, v| a.max(v.abs()));
        let err = max_abs_diff(&fast, &reference) / scale;
        assert!(err < 1e-5, "{gate:?}: {err:.2e} of the scale");
    }
}

#[test]
fn window_attention_trains_alike_through_the_hand_written_backward() {
    let _serial = serial();
    use restore::net::window::WindowAttention;
    let device = Device::flex().autodiff();
    device.seed(24);
    // tiny's windows with masked border keys, a wider overlap, 4 and 16 channels per head.
    for (c, heads, win, kwin, qe, h, w) in [
        (16, 2, 4, 6, 3, 12, 8),
        (8, 2, 4, 8, 0, 8, 12),
        (16, 1, 4, 6, 0, 4, 8),
    ] {
        let layer = WindowAttention::new(c, heads, win, kwin, qe, &device);
        // Position logits away from their small initial values, so their gradient matters.
        let mut layer = layer;
        layer.relative = burn::module::Param::from_tensor(Tensor::random(
            layer.relative.dims(),
            Distribution::Normal(0.0, 1.0),
            &device,
        ));
        let x = Tensor::<4>::random([2, c, h, w], Distribution::Normal(0.0, 1.0), &device)
            .require_grad();
        let wts = Tensor::<4>::random([2, c, h, w], Distribution::Normal(0.0, 1.0), &device);
        let run = |kernels| {
            with_kernels(kernels, || {
                let y = layer.forward(x.clone());
                let g = (y.clone() * wts.clone()).sum().backward();
                vec![
                    values(y),
                    values(x.grad(&g).expect("input gradient")),
                    values(layer.qkv.weight.val().grad(&g).expect("qkv gradient")),
                    values(layer.relative.val().grad(&g).expect("position gradient")),
                ]
            })
        };
        let (fast, reference) = (run(Kernels::Fast), run(Kernels::Reference));
        assert_within_scale(
            &[
                "output",
                "input gradient",
                "qkv gradient",
                "position gradient",
            ],
            &fast,
            &reference,
            1e-4,
            &format!("{c}/{heads} {win}/{kwin} {h}x{w}"),
        );
    }
}

#[test]
fn the_gdfn_trains_alike_through_the_one_node_gate() {
    let _serial = serial();
    use restore::net::layers::Gdfn;
    let device = Device::flex().autodiff();
    device.seed(26);
    // tiny's widths on odd sizes, a one-pixel-wide map, a batch of three.
    for (c, hidden, [b, h, w]) in [(8, 8, [2, 7, 9]), (4, 6, [1, 5, 1]), (6, 3, [3, 4, 6])] {
        let mut layer = Gdfn::new(c, hidden, &device);
        // Depthwise kernels well away from their initial scale, so GELU's curve matters.
        layer.depthwise.weight = burn::module::Param::from_tensor(Tensor::random(
            layer.depthwise.weight.dims(),
            Distribution::Normal(0.0, 1.0),
            &device,
        ));
        let x = Tensor::<4>::random([b, c, h, w], Distribution::Normal(0.0, 1.0), &device)
            .require_grad();
        let wts = Tensor::<4>::random([b, c, h, w], Distribution::Normal(0.0, 1.0), &device);
        let run = |kernels| {
            with_kernels(kernels, || {
                let y = layer.forward(x.clone());
                let g = (y.clone() * wts.clone()).sum().backward();
                vec![
                    values(y),
                    values(x.grad(&g).expect("input gradient")),
                    values(layer.project_in.weight.val().grad(&g).expect("project_in")),
                    values(layer.depthwise.weight.val().grad(&g).expect("depthwise")),
                    values(
                        layer
                            .project_out
                            .weight
                            .val()
                            .grad(&g)
                            .expect("project_out"),
                    ),
                ]
            })
        };
        let (fast, reference) = (run(Kernels::Fast), run(Kernels::Reference));
        assert_within_scale(
            &[
                "output",
                "input gradient",
                "project_in gradient",
                "depthwise gradient",
                "project_out gradient",
            ],
            &fast,
            &reference,
            1e-4,
            &format!("{c}/{hidden} {b}x{h}x{w}"),
        );
    }
}

#[test]
fn the_guide_trains_alike_through_the_hand_written_cross_attention_backward() {
    let _serial = serial();
    use restore::net::mafg::CrossAttentionGuide;
    let device = Device::flex().autodiff();
    device.seed(25);
    // tiny's guide (8 channels, one head), and two heads of 4 with a wider overlap.
    for (embed, heads, head_dim, win, kwin, h, w) in [(8, 1, 8, 4, 6, 12, 8), (8, 2, 4, 4, 8, 8, 8)]
    {
        let mut guide = CrossAttentionGuide::new(embed, heads, head_dim, win, kwin, true, &device);
        let bigger =
            |t: Tensor<2>| Tensor::<2>::random(t.dims(), Distribution::Normal(0.0, 0.5), &device);
        guide.pos_q = burn::module::Param::from_tensor(bigger(guide.pos_q.val()));
        guide.pos_k = burn::module::Param::from_tensor(bigger(guide.pos_k.val()));
        let x = Tensor::<4>::random([2, 39, h, w], Distribution::Normal(0.5, 0.3), &device)
            .require_grad();
        let wts = Tensor::<4>::random([2, 39, h, w], Distribution::Normal(0.0, 1.0), &device);
        let run = |kernels| {
            with_kernels(kernels, || {
                let y = guide.forward(x.clone());
                let g = (y.clone() * wts.clone()).sum().backward();
                vec![
                    values(y),
                    values(x.grad(&g).expect("input gradient")),
                    values(guide.q.weight.val().grad(&g).expect("query gradient")),
                    values(guide.k.weight.val().grad(&g).expect("key gradient")),
                    values(guide.pos_q.val().grad(&g).expect("query position gradient")),
                    values(guide.pos_k.val().grad(&g).expect("key position gradient")),
                ]
            })
        };
        let (fast, reference) = (run(Kernels::Fast), run(Kernels::Reference));
        let names = [
            "output",
            "input",
            "query",
            "key",
            "query position",
            "key position",
        ];
        assert_within_scale(
            &names,
            &fast,
            &reference,
            1e-4,
            &format!("{heads}x{head_dim} {win}/{kwin}"),
        );
    }
}

#[test]
fn the_channel_norm_trains_alike_through_the_hand_written_backward() {
    let _serial = serial();
    use restore::net::layers::ChannelNorm;
    let device = Device::flex().autodiff();
    device.seed(26);
    // A plane longer than one strip and not a multiple of it, one channel, an offset map.
    for (c, h, w, offset) in [(16, 17, 31, 0.0), (5, 7, 9, 300.0), (1, 4, 4, 0.0)] {
        let mut m = ChannelNorm::new(c, &device);
        m.weight = burn::module::Param::from_tensor(Tensor::random(
            [c],
            Distribution::Normal(1.0, 0.5),
            &device,
        ));
        m.bias = burn::module::Param::from_tensor(Tensor::random(
            [c],
            Distribution::Normal(0.0, 0.5),
            &device,
        ));
        let x = Tensor::<4>::random([2, c, h, w], Distribution::Normal(0.0, 2.0), &device)
            .add_scalar(offset)
            .detach()
            .require_grad();
        let wts = Tensor::<4>::random([2, c, h, w], Distribution::Normal(0.0, 1.0), &device);
        let run = |kernels| {
            with_kernels(kernels, || {
                let y = m.forward(x.clone());
                let g = (y.clone() * wts.clone()).sum().backward();
                vec![
                    values(y),
                    values(x.grad(&g).expect("input gradient")),
                    values(m.weight.val().grad(&g).expect("weight gradient")),
                    values(m.bias.val().grad(&g).expect("bias gradient")),
                ]
            })
        };
        let (fast, reference) = (run(Kernels::Fast), run(Kernels::Reference));
        assert_within_scale(
            &[
                "output",
                "input gradient",
                "weight gradient",
                "bias gradient",
            ],
            &fast,
            &reference,
            1e-4,
            &format!("{c}x{h}x{w}+{offset}"),
        );
    }
}
