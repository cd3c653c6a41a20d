//! Splits, extent, random init, distortion and image decoding.

mod common;

use glam::DVec3;
use image::{ImageBuffer, Luma, Rgba};
use proptest::prelude::*;
use scenes::{Bounds, CameraModel, Distortion, Normalization, split};

#[test]
fn split_holds_out_every_eighth_from_zero() {
    let s = split(20, 8);
    assert_eq!(s.test, vec![0, 8, 16]);
    assert_eq!(s.train.len(), 17);
    assert!(!s.train.contains(&0) && s.train.contains(&1) && s.train.contains(&19));
    assert_eq!(split(20, 0).test, Vec::<usize>::new());
    assert_eq!(split(10, 3).test, vec![0, 3, 6, 9]);
    assert_eq!(
        split(0, 8),
        scenes::Split {
            llffhold: 8,
            ..Default::default()
        }
    );
}

proptest! {
    #[test]
    fn split_partitions_the_indices(n in 0usize..200, hold in 0usize..20) {
        let s = split(n, hold);
        let mut all: Vec<usize> = s.train.iter().chain(&s.test).copied().collect();
        all.sort();
        prop_assert_eq!(all, (0..n).collect::<Vec<_>>());
        prop_assert!(s.test.iter().all(|i| hold != 0 && i % hold == 0));
        let expected = if hold == 0 { 0 } else { n.div_ceil(hold) };
        prop_assert_eq!(s.test.len(), expected);
    }
}

#[test]
fn extent_is_the_3dgs_radius() {
    let up = DVec3::Y;
    let cams: Vec<_> = [
        DVec3::new(1.0, 0.0, 0.0),
        DVec3::new(-1.0, 0.0, 0.0),
        DVec3::new(0.0, 3.0, 0.0),
    ]
    .iter()
    .enumerate()
    .map(|(i, &e)| {
        common::look_at(
            &i.to_string(),
            e,
            DVec3::new(0.0, 0.0, 5.0),
            up,
            10,
            10,
            10.0,
        )
    })
    .collect();
    let n = Normalization::from_cameras(&cams);
    // Mean (0, 1, 0); farthest centre (0, 3, 0) at distance 2.
    assert!((n.translate - DVec3::new(0.0, -1.0, 0.0)).length() < 1e-15);
    assert!((n.radius - 2.2).abs() < 1e-12);
    let t = n.transform();
    assert!(
        (t.transform_point3(DVec3::new(0.0, 3.0, 0.0)) - DVec3::new(0.0, 2.0 / 2.2, 0.0)).length()
            < 1e-12
    );
}

#[test]
fn random_points_follow_the_seed_and_fill_the_frusta() {
    let (cams, bounds) = common::arc_cameras(4, 32, 24, 9);
    let a = scenes::random_in_frusta(&cams, &bounds, 500, 1);
    assert_eq!(a, scenes::random_in_frusta(&cams, &bounds, 500, 1));
    assert_ne!(a, scenes::random_in_frusta(&cams, &bounds, 500, 2));
    assert_eq!(a.len(), 500);
    // Depths spread over the range rather than collapsing to one plane.
    let depths: Vec<f64> = a
        .positions
        .iter()
        .filter_map(|&p| cams[0].project(p))
        .filter(|pr| cams[0].contains(pr))
        .map(|pr| pr.depth)
        .collect();
    assert!(depths.len() > 50);
    let Bounds { near, far } = bounds[0];
    assert!(depths.iter().any(|&d| d < near + 0.3 * (far - near)));
    assert!(depths.iter().any(|&d| d > far - 0.3 * (far - near)));
    assert!(a.colors.iter().flatten().all(|c| (0.0..=1.0).contains(c)));
    assert!(scenes::random_in_frusta(&[], &[], 10, 0).is_empty());
}

#[test]
fn distortion_matches_the_opencv_formula() {
    let d = Distortion {
        model: CameraModel::OpenCv,
        k1: 0.1,
        k2: 0.01,
        p1: 0.001,
        p2: 0.002,
        rational: [0.0; 4],
    };
    let (x, y) = d.distort(0.5, -0.25);
    let r2: f64 = 0.3125;
    let radial = 1.0 + 0.1 * r2 + 0.01 * r2 * r2;
    assert!((x - (0.5 * radial + 2.0 * 0.001 * 0.5 * -0.25 + 0.002 * (r2 + 0.5))).abs() < 1e-15);
    assert!(
        (y - (-0.25 * radial + 0.001 * (r2 + 0.125) + 2.0 * 0.002 * 0.5 * -0.25)).abs() < 1e-15
    );
    assert_eq!(
        d.to_string(),
        "OPENCV k1=0.100000 k2=0.010000 p1=0.001000 p2=0.002000"
    );
}

#[test]
fn images_decode_16_bit_grey_and_drop_alpha() {
    let tmp = tempfile::tempdir().unwrap();
    let rgba = tmp.path().join("rgba.png");
    ImageBuffer::from_fn(3, 2, |x, _| Rgba([255u8, 0, 51 * x as u8, 7]))
        .save(&rgba)
        .unwrap();
    let img = scenes::images::load_rgb(&rgba).unwrap();
    assert_eq!((img.width, img.height, img.data.len()), (3, 2, 18));
    assert_eq!(img.pixel(2, 1), [1.0, 0.0, 102.0 / 255.0]);

    let grey = tmp.path().join("grey16.png");
    ImageBuffer::from_fn(2, 2, |x, y| Luma([(x + 2 * y) as u16 * 20000]))
        .save(&grey)
        .unwrap();
    let img = scenes::images::load_rgb(&grey).unwrap();
    let v = 60000.0 / 65535.0;
    assert!(
        img.pixel(1, 1).iter().all(|c| (c - v).abs() < 1e-6),
        "{:?}",
        img.pixel(1, 1)
    );

    let broken = tmp.path().join("broken.png");
    std::fs::write(&broken, b"\x89PNG not really").unwrap();
    let e = scenes::images::load_rgb(&broken).unwrap_err();
    assert!(e.to_string().contains("broken.png"), "{e}");
}
