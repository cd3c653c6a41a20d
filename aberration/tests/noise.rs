//! Sensor noise: statistics of the Poisson–Gaussian model and reproducibility.

use aberration::{Image, NoiseModel};

#[test]
fn noise_has_the_model_variance_and_is_reproducible() {
    let model = NoiseModel::default();
    for level in [0.05f32, 0.5] {
        let img = Image::filled(256, 256, [level; 3]);
        let a = model.apply(&img, 7);
        let n = a.data.len() as f64;
        let mean = a.data.iter().map(|v| *v as f64).sum::<f64>() / n;
        let var = a
            .data
            .iter()
            .map(|v| (*v as f64 - mean).powi(2))
            .sum::<f64>()
            / n;
        let expect =
            model.poisson_scale as f64 * level as f64 + (model.gaussian_sigma as f64).powi(2);
        assert!(
            (mean - level as f64).abs() < 1e-4,
            "mean {mean} at level {level}"
        );
        assert!(
            (var / expect - 1.0).abs() < 0.03,
            "variance {var} vs model {expect}"
        );
    }
    let img = Image::filled(64, 48, [0.3; 3]);
    let (a, b, c) = (
        model.apply(&img, 1),
        model.apply(&img, 1),
        model.apply(&img, 2),
    );
    assert_eq!(a, b, "same seed must give the same noise");
    assert_ne!(a, c, "different seeds must differ");
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    assert_eq!(
        pool.install(|| model.apply(&img, 1)),
        a,
        "noise depends on the thread count"
    );
}

#[test]
fn noise_keeps_black_and_white_in_range() {
    let model = NoiseModel::default();
    for level in [0.0f32, 1.0] {
        let out = model.apply(&Image::filled(32, 32, [level; 3]), 3);
        assert!(
            out.data
                .iter()
                .all(|v| v.is_finite() && (0.0..=1.0).contains(v))
        );
    }
    let mut weird = Image::filled(4, 4, [0.5; 3]);
    weird.data[0] = f32::NAN;
    weird.data[1] = -3.0;
    weird.data[2] = f32::INFINITY;
    assert!(model.apply(&weird, 0).is_finite());
    assert_eq!(
        NoiseModel::none().apply(&Image::filled(3, 3, [0.25; 3]), 0),
        Image::filled(3, 3, [0.25; 3])
    );
}
