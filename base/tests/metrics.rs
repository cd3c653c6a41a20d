//! One convention for every caller: the layouts agree, sizes that differ are errors.

use base::{psnr, psnr_rgb, ssim, ssim_planar, ssim_value};
use glam::Vec3;

fn image(seed: u64, n: usize) -> Vec<Vec3> {
    base::SplitMix64::new(seed).uniform_rgb(n)
}

fn planar(img: &[Vec3]) -> Vec<f32> {
    (0..3).flat_map(|c| img.iter().map(move |p| p[c])).collect()
}

#[test]
fn interleaved_and_planar_layouts_give_the_same_numbers() {
    let (w, h) = (23, 17);
    let (a, b) = (image(1, w * h), image(2, w * h));
    let s = ssim_value(&a, &b, w as u32, h as u32).unwrap();
    let sp = ssim_planar(&planar(&a), &planar(&b), w as u32, h as u32).unwrap();
    assert_eq!(s, sp);
    assert_eq!(s, ssim(&a, &b, w as u32, h as u32).unwrap().0 as f64);
    let p = psnr_rgb(&a, &b).unwrap();
    let pp = psnr(&planar(&a), &planar(&b)).unwrap();
    assert!((p - pp).abs() < 1e-9, "{p} vs {pp}");
    // Uniform noise of variance 1/6 per value: PSNR = 10 log10(6) ≈ 7.78 dB.
    assert!((p - 7.78).abs() < 0.3, "{p}");
}

#[test]
fn identical_images_are_capped_and_mismatches_are_errors() {
    let a = image(3, 12);
    assert_eq!(psnr_rgb(&a, &a).unwrap(), 100.0);
    assert!((ssim_value(&a, &a, 4, 3).unwrap() - 1.0).abs() < 1e-6);
    assert!(psnr_rgb(&a, &a[1..]).is_err());
    assert!(psnr(&[], &[]).is_err());
    assert!(ssim_value(&a, &a, 5, 3).is_err());
    assert!(ssim_planar(&planar(&a), &planar(&a)[1..], 4, 3).is_err());
}

#[test]
fn fast_ssim_is_the_direct_ssim_bit_for_bit() {
    let sizes = [
        (1usize, 1usize),
        (3, 17),
        (10, 10),
        (11, 12),
        (37, 5),
        (64, 48),
        (131, 97),
    ];
    // Up and down again: the working memory a larger image left behind is reused, unclean,
    // by the smaller ones.
    for &(w, h) in sizes.iter().chain(sizes.iter().rev()) {
        let (a, b) = (image(w as u64, w * h), image(h as u64 + 100, w * h));
        let (v, g) = ssim(&a, &b, w as u32, h as u32).unwrap();
        let (rv, rg) = base::ssim_reference::ssim(&a, &b, w as u32, h as u32);
        assert_eq!(v.to_bits(), rv.to_bits(), "{w}x{h}: value");
        assert!(
            g.iter()
                .zip(&rg)
                .all(|(x, y)| x.to_array().map(f32::to_bits) == y.to_array().map(f32::to_bits)),
            "{w}x{h}: gradient"
        );
        assert_eq!(ssim_value(&a, &b, w as u32, h as u32).unwrap(), rv as f64);
    }
}

/// SSIM's value and gradient bits under one build of the kernels (the one this process chose).
fn ssim_bits() -> Vec<u32> {
    let (w, h) = (131, 97);
    let (a, b) = (image(7, w * h), image(8, w * h));
    let (v, g) = ssim(&a, &b, w as u32, h as u32).unwrap();
    std::iter::once(v.to_bits())
        .chain(g.iter().flat_map(|p| p.to_array()).map(f32::to_bits))
        .collect()
}

/// Every build of the kernels gives the same bits: this process's build against the portable
/// loops (`METASPLAT_NO_AVX2`) and AVX2 at most (`METASPLAT_NO_AVX512`), each in a child
/// process, since the choice is made once per process (`base::isa`).
#[test]
fn ssim_has_the_same_bits_in_every_build() {
    const OUT: &str = "METASPLAT_TEST_SSIM_BITS";
    if let Some(path) = std::env::var_os(OUT) {
        let bytes: Vec<u8> = ssim_bits().iter().flat_map(|b| b.to_le_bytes()).collect();
        std::fs::write(path, bytes).unwrap();
        return;
    }
    let here = ssim_bits();
    eprintln!("this process runs the {:?} build", base::isa::Isa::chosen());
    let dir = tempfile::tempdir().unwrap();
    for var in ["METASPLAT_NO_AVX2", "METASPLAT_NO_AVX512"] {
        let path = dir.path().join(var);
        let status = std::process::Command::new(std::env::current_exe().unwrap())
            .args([
                "--exact",
                "ssim_has_the_same_bits_in_every_build",
                "--test-threads",
                "1",
            ])
            .env(var, "1")
            .env(OUT, &path)
            .status()
            .unwrap();
        assert!(status.success(), "the child with {var} failed");
        let child: Vec<u32> = std::fs::read(&path)
            .unwrap()
            .chunks_exact(4)
            .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        assert!(child == here, "SSIM differs with {var}");
    }
}

#[test]
fn luma_psnr_weights_each_channel_as_bt601_and_a_grey_error_as_plain_psnr() {
    let (w, h) = (9, 7);
    let n = w * h;
    let a = planar(&image(3, n));
    // An error in green alone of d per pixel: MSE of Y = (128.553 d / 255)^2.
    let d = 0.02f32;
    let mut b = a.clone();
    for v in &mut b[n..2 * n] {
        *v += d;
    }
    let want = -20.0 * (128.553 / 255.0 * d as f64).log10();
    let got = base::metrics::psnr_y_planar(&b, &a).unwrap();
    assert!((got - want).abs() < 1e-4, "{got} vs {want}");
    // The same error in blue costs far less than in green (24.966 against 128.553).
    let mut blue = a.clone();
    for v in &mut blue[2 * n..] {
        *v += d;
    }
    let in_blue = base::metrics::psnr_y_planar(&blue, &a).unwrap();
    assert!((in_blue - got - 20.0 * (128.553f64 / 24.966).log10()).abs() < 1e-4);
    // A grey error (all channels alike) moves Y by 219/255 of it: PSNR 1.32 dB above RGB's.
    let grey: Vec<f32> = a.iter().map(|v| v + d).collect();
    let rgb = psnr(&grey, &a).unwrap();
    let y = base::metrics::psnr_y_planar(&grey, &a).unwrap();
    assert!(
        (y - rgb + 20.0 * (219.0f64 / 255.0).log10()).abs() < 1e-3,
        "{y} {rgb}"
    );
    // Sizes that differ, or that are not RGB, are errors.
    assert!(base::metrics::psnr_y_planar(&a, &a[1..]).is_err());
    assert!(base::metrics::psnr_y_planar(&a[1..], &a[1..]).is_err());
}
