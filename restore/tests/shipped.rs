//! The weights we ship: made for the default simulated PSF grid, and better on a held-out
//! photo than both the median Wiener image and the bank image their residual is added to.

use aberration::optics::{SimConfig, simulate_grid};
use aberration::wiener::BANK_MEDIAN;
use aberration::{BlurMode, Image, ImagingModel, NoiseModel, psnr};
use aberration::{PsfGrid, Regularizer, deconvolve};
use restore::data::bank_images;
use restore::shipped;
use std::path::Path;
use std::sync::OnceLock;

/// The default simulated grid, simulated once for the binary's tests.
fn default_grid() -> &'static PsfGrid {
    static GRID: OnceLock<PsfGrid> = OnceLock::new();
    GRID.get_or_init(|| simulate_grid(&SimConfig::default(), &|_, _| {}).unwrap().0)
}

/// The paper's lens with a focal length 3 % longer: a lens the shipped network never saw.
fn perturbed_grid() -> PsfGrid {
    let mut cfg = SimConfig::default();
    cfg.lens = cfg.lens.with_focal_scale(1.03);
    simulate_grid(&cfg, &|_, _| {}).unwrap().0
}

#[test]
fn shipped_weights_fit_the_default_grid_and_beat_the_median_wiener_image() {
    let native = default_grid().clone();
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

#[test]
fn auto_takes_the_network_where_it_serves_and_says_why_not_elsewhere() {
    let native = default_grid();
    let header = shipped::header().unwrap();
    let [lo, hi] = header
        .trained_psf_px
        .expect("the shipped weights record their scales");
    let inside = (lo + hi) / 2;
    let (serves, why) = shipped::verdict(&header, native, Some(inside));
    assert!(serves, "{why}");
    assert!(
        why.contains("trained on this PSF grid") && why.contains(&format!("{inside} px")),
        "{why}"
    );
    // Two scales outside what it saw: declined, naming both.
    for px in [19, 113] {
        let (serves, why) = shipped::verdict(&header, native, Some(px));
        assert!(!serves, "{px}: {why}");
        assert!(
            why.contains(&format!("{lo}-{hi} px PSFs")) && why.contains(&format!("{px} px")),
            "{why}"
        );
    }
    // A lens 3 % longer: declined at any scale, saying what the weights cover.
    let other = perturbed_grid();
    let (serves, why) = shipped::verdict(&header, &other, Some(inside));
    assert!(!serves);
    assert!(
        why.contains("does not serve this lens") && why.contains("this grid is"),
        "{why}"
    );
    // Where `tiny` declines, auto takes a network of the family: the one for the widest blur
    // at 113 and 150 px (past what any saw, inside its margin), the general one elsewhere (at
    // 19 px, on the lens 3 % longer at tiny's scale, and at 75 px, which the wide-blur one
    // reaches only through its margin); another design neither serves, and the reason names
    // all three.
    for (grid, px, expect) in [
        (native, 19, shipped::FAMILY_NAME),
        (native, 75, shipped::FAMILY_NAME),
        (native, 113, shipped::LARGE_NAME),
        (native, 150, shipped::LARGE_NAME),
        (&other, inside, shipped::FAMILY_NAME),
    ] {
        match shipped::for_capture(grid, Some(px)).unwrap() {
            shipped::Choice::Network(r, why, name) => {
                assert_eq!(name, expect, "{px} px: {why}");
                assert!(why.contains("general restorer"), "{why}");
                assert!(r.header.family.is_some());
            }
            shipped::Choice::Declined(why) => panic!("{px} px declined: {why}"),
        }
    }
    match shipped::for_capture(native, Some(inside)).unwrap() {
        shipped::Choice::Network(_, _, name) => assert_eq!(name, shipped::TINY_NAME),
        shipped::Choice::Declined(why) => panic!("{why}"),
    }
    // Inside `tiny`'s margin but off the scales it saw, the general network, trained there,
    // is taken over it.
    let margin = hi + 7;
    assert!(shipped::verdict(&header, native, Some(margin)).0);
    match shipped::for_capture(native, Some(margin)).unwrap() {
        shipped::Choice::Network(_, why, name) => {
            assert_eq!(name, shipped::FAMILY_NAME, "{margin} px: {why}")
        }
        shipped::Choice::Declined(why) => panic!("{why}"),
    }
    let (small, _) = simulate_grid(&SimConfig::small(21), &|_, _| {}).unwrap();
    match shipped::for_capture(&small, Some(21)).unwrap() {
        shipped::Choice::Declined(why) => assert!(
            why.contains("the shipped restorer ('tiny')")
                && why.contains("a lens family, 15-140 px")
                && why.contains("a lens family, 85-140 px"),
            "{why}"
        ),
        shipped::Choice::Network(_, _, name) => panic!("{name} took another design"),
    }
}

/// Off the scales and the lens it was trained on, the shipped `tiny` still beats the Wiener
/// filter at 113 px and on a lens 3 % longer (measured on kodim05's centre 256²: 21.52 against
/// 19.10 dB, 27.87 against 21.50 dB). Not at 19 px (27.24 against 27.37 dB; whole photo 28.22
/// against 28.65), which is why `auto` passes it over there for the general network
/// ([`the_general_network_beats_wiener_where_auto_takes_it`]).
#[test]
fn off_its_range_the_shipped_network_still_beats_wiener() {
    let photo =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/images/val/kodim05.png");
    if !photo.exists() {
        eprintln!(
            "SKIPPED: {} is absent (shared data not present)",
            photo.display()
        );
        return;
    }
    let whole = Image::load(&photo).unwrap();
    let s = 256;
    let clean =
        restore::train::crop_image(&whole, (whole.width - s) / 2, (whole.height - s) / 2, s);
    let restorer = restore::Restorer::from_bytes_any_grid_on(
        shipped::TINY,
        Path::new(shipped::TINY_NAME),
        burn::tensor::Device::flex(),
    )
    .unwrap();
    let perturbed = perturbed_grid();
    for (name, native, px) in [
        ("default lens at 113 px", default_grid(), 113),
        ("focal +3 % at 57 px", &perturbed, 57),
    ] {
        let sensor = native.sensor_for_psf_px(s, s, px);
        let model = ImagingModel::new(
            native,
            s,
            s,
            BlurMode::Tiled,
            Some(sensor),
            NoiseModel::default(),
        )
        .unwrap();
        let blurred = model.capture(&clean, 7).unwrap();
        let wiener = deconvolve(&blurred, model.psf(), Regularizer::Fixed(1e-2)).unwrap();
        let bank = bank_images(&blurred, model.psf(), true).unwrap();
        let restored = restorer.restore_bank(&bank);
        let (p_net, p_wiener) = (
            psnr(&restored, &clean).unwrap(),
            psnr(&wiener, &clean).unwrap(),
        );
        println!("{name}: Wiener K=1e-2 {p_wiener:.2} dB, shipped network {p_net:.2} dB");
        assert!(
            p_net > p_wiener,
            "{name}: network {p_net:.2} dB, Wiener {p_wiener:.2} dB"
        );
    }
}

/// Where `auto` takes a network of the family (the general one at 19 px and on the lens 3 %
/// longer at 57 px, the wide-blur one at 113 px), it beats the Wiener filter by at least 2 dB
/// on kodim05's centre 256².
#[test]
fn the_general_network_beats_wiener_where_auto_takes_it() {
    let photo =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/images/val/kodim05.png");
    if !photo.exists() {
        eprintln!(
            "SKIPPED: {} is absent (shared data not present)",
            photo.display()
        );
        return;
    }
    let whole = Image::load(&photo).unwrap();
    let s = 256;
    let clean =
        restore::train::crop_image(&whole, (whole.width - s) / 2, (whole.height - s) / 2, s);
    let perturbed = perturbed_grid();
    for (name, native, px) in [
        ("default lens at 19 px", default_grid(), 19),
        ("default lens at 113 px", default_grid(), 113),
        ("focal +3 % at 57 px", &perturbed, 57),
    ] {
        let sensor = native.sensor_for_psf_px(s, s, px);
        let model = ImagingModel::new(
            native,
            s,
            s,
            BlurMode::Tiled,
            Some(sensor),
            NoiseModel::default(),
        )
        .unwrap();
        let restorer = match shipped::for_capture(native, Some(model.psf().size())).unwrap() {
            shipped::Choice::Network(r, _, n) => {
                let expect = if px > 85 {
                    shipped::LARGE_NAME
                } else {
                    shipped::FAMILY_NAME
                };
                assert_eq!(n, expect, "{name}");
                r
            }
            shipped::Choice::Declined(why) => panic!("{name}: {why}"),
        };
        let blurred = model.capture(&clean, 7).unwrap();
        let wiener = deconvolve(&blurred, model.psf(), Regularizer::Fixed(1e-2)).unwrap();
        let restored = restorer.restore(&blurred, model.psf()).unwrap();
        let (p_net, p_wiener) = (
            psnr(&restored, &clean).unwrap(),
            psnr(&wiener, &clean).unwrap(),
        );
        println!("{name}: Wiener K=1e-2 {p_wiener:.2} dB, general network {p_net:.2} dB");
        assert!(
            p_net > p_wiener + 2.0,
            "{name}: network {p_net:.2} dB, Wiener {p_wiener:.2} dB"
        );
    }
}

#[test]
fn the_family_increment_serves_the_default_lens_and_a_perturbed_one_at_every_scale() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("weights/family_tiny_5.bin");
    let (header, _) = restore::weights::read(&path).unwrap();
    assert_eq!(header.trained_psf_px, Some([15, 140]));
    assert!(header.family.is_some());
    for (name, grid) in [
        ("default", default_grid().clone()),
        ("focal +3 %", perturbed_grid()),
    ] {
        let why = header
            .serves(&grid)
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        // The default lens is the family's centre, the grid its fingerprint names.
        let expect = if name == "default" {
            "trained on this PSF grid"
        } else {
            "inside the lens family"
        };
        assert!(why.contains(expect), "{name}: {why}");
        for px in [19, 57, 113] {
            assert!(header.fits_psf_px(px), "{name} at {px} px");
        }
    }
    // Another design is not served.
    let mut ideal = SimConfig::default();
    ideal.lens = aberration::optics::Lens::ideal(
        ideal.lens.aperture_um,
        ideal.lens.focal_um,
        ideal.lens.pitch_um,
        511.0,
    );
    let other = simulate_grid(&ideal, &|_, _| {}).unwrap().0;
    assert!(header.serves(&other).is_err());
    // The wide-blur network: the same family, its scales 85-140 px.
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("weights/large_tiny_9.bin");
    let (large, _) = restore::weights::read(&path).unwrap();
    assert_eq!(large.trained_psf_px, Some([85, 140]));
    assert!(large.serves(&perturbed_grid()).is_ok() && large.serves(&other).is_err());
    assert!(large.fits_psf_px(113) && !large.fits_psf_px(57));
}

/// Each shipped network's name is the repository path of the very file embedded, so messages
/// and run records point at it.
#[test]
fn shipped_names_are_the_paths_of_the_embedded_files() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    for s in shipped::SHIPPED {
        let path = s
            .name
            .strip_suffix(" (shipped)")
            .unwrap_or_else(|| panic!("{}: no ' (shipped)' suffix", s.name));
        let bytes = std::fs::read(root.join(path)).unwrap_or_else(|e| panic!("{path}: {e}"));
        assert!(bytes == s.bytes, "{path} is not the file embedded");
    }
}
