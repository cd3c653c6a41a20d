//! The weights we ship: made for the default simulated PSF grid, and better on a held-out
//! photo than both the median Wiener image and the bank image their residual is added to.

use aberration::optics::{SimConfig, simulate_grid};
use aberration::wiener::BANK_MEDIAN;
use aberration::{BlurMode, Image, ImagingModel, NoiseModel, psnr};
use restore::data::bank_images;
use restore::shipped;
use std::path::Path;

#[test]
fn shipped_weights_fit_the_default_grid_and_beat_the_median_wiener_image() {
    let (native, _) = simulate_grid(&SimConfig::default(), &|_, _| {}).unwrap();
    let restorer = shipped::for_psf(&native)
        .unwrap()
        .expect("the shipped weights are made for the default simulated grid");
    assert_eq!(restorer.config().name, "tiny");
    // Another grid is not theirs.
    let (other, _) = simulate_grid(&SimConfig::small(21), &|_, _| {}).unwrap();
    assert!(shipped::for_psf(&other).unwrap().is_none());

    let photo =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/images/val/kodim05.png");
    if !photo.exists() {
        eprintln!(
            "SKIPPED the restoration check: {} is absent (shared data not present)",
            photo.display()
        );
        return;
    }
    let clean = Image::load(&photo).unwrap();
    let model = ImagingModel::new(
        &native,
        clean.width,
        clean.height,
        BlurMode::Tiled,
        None,
        NoiseModel::default(),
    )
    .unwrap();
    let blurred = model.capture(&clean, 99).unwrap();
    let bank = bank_images(&blurred, model.psf(), true).unwrap();
    let restored = restorer.restore_bank(&bank);
    assert!(restored.is_finite());
    let base = restorer.config().residual_base;
    let (p_net, p_med, p_base) = (
        psnr(&restored, &clean).unwrap(),
        psnr(&bank[BANK_MEDIAN], &clean).unwrap(),
        psnr(&bank[base], &clean).unwrap(),
    );
    println!(
        "kodim05: median Wiener {p_med:.2} dB, filter {base} (the network's base) {p_base:.2} dB, shipped network {p_net:.2} dB"
    );
    assert!(
        p_net > p_med + 2.0,
        "network {p_net:.2} vs median {p_med:.2}"
    );
    // The network must add to the image it starts from, not merely pass it through.
    assert!(
        p_net > p_base + 3.0,
        "network {p_net:.2} vs its base, filter {base}, {p_base:.2}"
    );
}
