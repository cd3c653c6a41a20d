//! A downsample whose `images_N/` the capture lacks is made from `images/` at load by the area
//! filter: cameras scaled as LLFF's own folders scale them, photos the means of `N × N` blocks.

mod common;

use scenes::{BitDepth, OpenOptions, Resolution};

fn open(dir: &std::path::Path, n: u32) -> scenes::Result<scenes::Capture> {
    scenes::open(
        dir,
        &OpenOptions {
            resolution: Resolution::Downsample(n),
            ..OpenOptions::default()
        },
    )
}

#[test]
fn images_n_missing_is_made_from_images_by_the_area_filter() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("llff");
    let (cameras, bounds) = common::arc_cameras(4, 81, 61, 2);
    let photos: Vec<_> = (0..4).map(|k| common::pattern(81, 61, k)).collect();
    scenes::write_llff(&dir, &cameras, &bounds, &photos, 1, BitDepth::Sixteen).unwrap();
    assert!(!dir.join("images_2").exists());
    let full = open(&dir, 1).unwrap();
    let half = open(&dir, 2).unwrap();
    assert_eq!((full.shrink, half.shrink), (1, 2));
    for (a, b) in half.cameras.iter().zip(&full.cameras) {
        // 81x61 shrinks to 40x30 (the odd row and column dropped).
        assert_eq!((a.width, a.height), (40, 30));
        assert!(
            (a.fx - b.fx * 40.0 / 81.0).abs() < 1e-9,
            "{} vs {}",
            a.fx,
            b.fx
        );
        assert_eq!(a.world_to_camera, b.world_to_camera);
    }
    let small = half.load_image(1).unwrap();
    let big = full.load_image(1).unwrap();
    assert_eq!((small.width, small.height), (40, 30));
    for (x, y) in [(0, 0), (17, 9), (39, 29)] {
        let want: Vec<f32> = (0..3)
            .map(|c| {
                let s: f32 = [(0, 0), (1, 0), (0, 1), (1, 1)]
                    .iter()
                    .map(|(dx, dy)| big.pixel(2 * x + dx, 2 * y + dy)[c])
                    .sum();
                s / 4.0
            })
            .collect();
        let got = small.pixel(x, y);
        for c in 0..3 {
            assert!((got[c] - want[c]).abs() < 1e-6, "({x}, {y}) channel {c}");
        }
    }
    // An images_N/ that exists is read as it is.
    std::fs::create_dir_all(dir.join("images_2")).unwrap();
    for (k, p) in full.image_paths.iter().enumerate() {
        let name = p.file_name().unwrap();
        scenes::images::write_png(
            &dir.join("images_2").join(name),
            &common::pattern(40, 30, k + 10),
            BitDepth::Eight,
        )
        .unwrap();
    }
    let own = open(&dir, 2).unwrap();
    assert_eq!(own.shrink, 1);
    assert_ne!(own.load_image(1).unwrap(), small);
    // Shrinking below a pixel is refused.
    let e = open(&tmp.path().join("llff"), 64)
        .map(|_| ())
        .unwrap_err()
        .to_string();
    assert!(e.contains("images_64") || e.contains("no pixel"), "{e}");
}
