//! The real LLFF capture `fern`: LLFF poses with COLMAP's points3D.bin.

mod common;

use scenes::{CameraModel, CaptureFormat, OpenOptions, PointSource, Resolution};

fn open_fern(resolution: Resolution) -> Option<scenes::Capture> {
    let dir = common::fern_dir()?;
    let options = OpenOptions {
        resolution,
        ..OpenOptions::default()
    };
    Some(scenes::open(&dir, &options).expect("fern opens"))
}

#[test]
fn fern_loads_at_downsample_8() {
    let Some(capture) = open_fern(Resolution::Downsample(8)) else {
        return;
    };
    println!("{}", capture.summary());
    assert_eq!(capture.format, CaptureFormat::Llff);
    assert_eq!(capture.len(), 20);
    assert_eq!(capture.cameras[0].name, "image000");
    assert_eq!(capture.cameras[19].name, "image019");
    // Full-resolution focal from sparse/0/cameras.bin (SIMPLE_RADIAL f), divided by 8.
    let focal = 3260.5263328805895 / 8.0;
    for c in &capture.cameras {
        assert_eq!((c.width, c.height), (504, 378));
        assert!(
            (c.fx - focal).abs() < 1e-6 && (c.fy - focal).abs() < 1e-6,
            "{}",
            c.fx
        );
        assert_eq!((c.cx, c.cy), (252.0, 189.0));
    }
    assert_eq!(capture.downsample, 8.0);
    // Values read from the file independently (Python struct) when writing this test.
    assert_eq!(capture.bounds[0].near, 17.747087483458166);
    assert_eq!(capture.bounds[0].far, 78.25748707131142);
    assert_eq!(capture.bounds[1].near, 18.91692457964135);
    let summary = capture.summary();
    assert_eq!(summary.near, 16.985296178676084);
    assert_eq!(summary.far, 80.00209740336334);
    assert_eq!((summary.train, summary.test), (17, 3));
    assert_eq!(capture.split.test, vec![0, 8, 16]);
    assert_eq!(capture.points.len(), 10091);
    assert!(matches!(capture.point_source, PointSource::Sparse(_)));
    let d = capture.cameras[0]
        .distortion
        .expect("distortion from cameras.bin");
    assert_eq!(d.model, CameraModel::SimpleRadial);
    assert!((d.k1 - 0.019750463822896944).abs() < 1e-15);
    let text = summary.to_string();
    for needle in [
        "cameras     20",
        "504x378",
        "17 train, 3 test",
        "10091",
        "undistorted at load",
    ] {
        assert!(text.contains(needle), "summary lacks {needle:?}:\n{text}");
    }
}

#[test]
fn fern_cameras_look_at_the_points() {
    let Some(capture) = open_fern(Resolution::Downsample(8)) else {
        return;
    };
    let mut worst = 1.0f64;
    for (camera, bounds) in capture.cameras.iter().zip(&capture.bounds) {
        let mut inside = 0;
        let mut in_range = 0;
        for &p in &capture.points.positions {
            if let Some(pr) = camera.project(p)
                && camera.contains(&pr)
            {
                inside += 1;
                // LLFF's bounds are depth percentiles of these very points.
                if pr.depth >= bounds.near * 0.9 && pr.depth <= bounds.far * 1.1 {
                    in_range += 1;
                }
            }
        }
        let fraction = inside as f64 / capture.points.len() as f64;
        worst = worst.min(fraction);
        assert!(
            in_range as f64 >= 0.95 * inside as f64,
            "{}: depths outside bounds",
            camera.name
        );
    }
    println!("smallest fraction of points inside an image: {worst:.3}");
    assert!(worst > 0.5, "a camera sees only {worst:.3} of the points");
}

#[test]
fn fern_target_width_picks_the_folder_and_images_decode() {
    let Some(small) = open_fern(Resolution::TargetWidth(600)) else {
        return;
    };
    assert!(small.image_dir.ends_with("images_8"));
    let Some(large) = open_fern(Resolution::TargetWidth(5000)) else {
        return;
    };
    assert!(large.image_dir.ends_with("images_4"));
    assert_eq!(
        (large.cameras[0].width, large.cameras[0].height),
        (1008, 756)
    );
    assert!((large.cameras[0].fx - 3260.5263328805895 / 4.0).abs() < 1e-6);

    let all: Vec<usize> = (0..small.len()).collect();
    let images = small.load_images(&all).expect("fern images decode");
    assert_eq!(images.len(), 20);
    for image in &images {
        assert_eq!((image.width, image.height), (504, 378));
        assert_eq!(image.data.len(), 504 * 378 * 3);
        assert!(image.data.iter().all(|v| (0.0..=1.0).contains(v)));
        let mean = image.data.iter().sum::<f32>() / image.data.len() as f32;
        assert!(mean > 0.05 && mean < 0.95, "implausible mean {mean}");
    }
    assert_ne!(images[0], images[1]);
}

#[test]
fn fern_is_forward_facing() {
    let Some(capture) = open_fern(Resolution::Downsample(8)) else {
        return;
    };
    assert!(!capture.surrounds_scene());
}
