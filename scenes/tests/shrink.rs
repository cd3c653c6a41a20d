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

#[test]
fn masks_come_from_the_masks_folder_else_from_the_photos_alpha() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("llff");
    let (cameras, bounds) = common::arc_cameras(3, 20, 10, 4);
    let photos: Vec<_> = (0..3).map(|k| common::pattern(20, 10, k)).collect();
    scenes::write_llff(&dir, &cameras, &bounds, &photos, 1, BitDepth::Eight).unwrap();
    let capture = open(&dir, 1).unwrap();
    // No masks: every pixel counts.
    assert!(capture.load_mask(0).unwrap().is_none());
    // A masks/ folder: white keeps, black leaves out.
    std::fs::create_dir_all(dir.join("masks")).unwrap();
    for (k, p) in capture.image_paths.iter().enumerate() {
        let stem = p.file_stem().unwrap().to_str().unwrap();
        image::GrayImage::from_fn(20, 10, |x, _| {
            image::Luma([if x < 5 + k as u32 { 0 } else { 255 }])
        })
        .save(dir.join("masks").join(format!("{stem}.png")))
        .unwrap();
    }
    let m = capture.load_mask(1).unwrap().unwrap();
    assert_eq!(m.len(), 200);
    assert_eq!((m[0], m[5], m[6], m[19]), (0.0, 0.0, 1.0, 1.0));
    // At half size the mask shrinks with its photo (the area filter: a blended edge).
    let half = open(&dir, 2).unwrap();
    let m2 = half.load_mask(0).unwrap().unwrap();
    assert_eq!(m2.len(), 50);
    assert_eq!((m2[1], m2[2], m2[3]), (0.0, 0.5, 1.0));
    // A mask of the wrong size is refused naming it; a missing one too.
    let first = capture.image_paths[0]
        .file_stem()
        .unwrap()
        .to_str()
        .unwrap()
        .to_string();
    image::GrayImage::new(7, 7)
        .save(dir.join("masks").join(format!("{first}.png")))
        .unwrap();
    let e = capture.load_mask(0).unwrap_err().to_string();
    assert!(e.contains(&first) && e.contains("7x7"), "{e}");
    std::fs::remove_file(dir.join("masks").join(format!("{first}.png"))).unwrap();
    let e = capture.load_mask(0).unwrap_err().to_string();
    assert!(e.contains("masks"), "{e}");
    // Without masks/, an alpha channel is the mask.
    std::fs::remove_dir_all(dir.join("masks")).unwrap();
    image::RgbaImage::from_fn(20, 10, |x, _| {
        image::Rgba([90, 90, 90, if x < 10 { 0 } else { 255 }])
    })
    .save(&capture.image_paths[2])
    .unwrap();
    let m = capture.load_mask(2).unwrap().unwrap();
    assert_eq!((m[9], m[10]), (0.0, 1.0));
}

#[test]
fn photos_made_at_load_are_cached_beside_the_capture_and_read_back_bit_for_bit() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("llff");
    let (cameras, bounds) = common::arc_cameras(3, 81, 61, 2);
    let photos: Vec<_> = (0..3).map(|k| common::pattern(81, 61, k)).collect();
    scenes::write_llff(&dir, &cameras, &bounds, &photos, 1, BitDepth::Sixteen).unwrap();
    let cached = |n| {
        scenes::open(
            &dir,
            &OpenOptions {
                resolution: Resolution::Downsample(n),
                cache_photos: true,
                ..OpenOptions::default()
            },
        )
        .unwrap()
    };
    let cache = dir.join(scenes::photo_cache::CACHE_DIR);
    let entries = || std::fs::read_dir(&cache).map_or(0, |d| d.count());
    // Photos as their files hold them are not cached; opening writes nothing.
    let full = cached(1);
    assert_eq!(full.photo_cache, None);
    let half = cached(2);
    assert_eq!(half.photo_cache.as_deref(), Some(cache.as_path()));
    assert_eq!(entries(), 0);
    let uncached = open(&dir, 2).unwrap().load_image(1).unwrap();
    let first = half.load_image(1).unwrap();
    assert_eq!(first, uncached);
    assert_eq!(entries(), 1);
    // The next run reads the entry: spoil it to a valid entry of other pixels and it shows.
    let again = cached(2);
    assert_eq!(again.load_image(1).unwrap(), first);
    let entry = std::fs::read_dir(&cache)
        .unwrap()
        .next()
        .unwrap()
        .unwrap()
        .path();
    let key = u64::from_str_radix(entry.file_stem().unwrap().to_str().unwrap(), 16).unwrap();
    let mut marked = first.clone();
    marked.data[0] = 0.5;
    scenes::photo_cache::put(&cache, key, &marked).unwrap();
    assert_eq!(cached(2).load_image(1).unwrap(), marked);
    // A photo edited since is another entry, not the stale one.
    let edited = common::pattern(81, 61, 7);
    scenes::images::write_png(&full.image_paths[1], &edited, BitDepth::Sixteen).unwrap();
    let fresh = cached(2).load_image(1).unwrap();
    assert_eq!(fresh, open(&dir, 2).unwrap().load_image(1).unwrap());
    assert_ne!(fresh, first);
    assert_eq!(entries(), 2);
}

/// A grey mask of `w × h` whose left `edge` columns are black (left out), the rest white.
fn edge_mask(path: &std::path::Path, w: u32, h: u32, edge: u32) {
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    image::GrayImage::from_fn(w, h, |x, _| image::Luma([if x < edge { 0 } else { 255 }]))
        .save(path)
        .unwrap();
}

#[test]
fn masks_n_beside_images_n_else_full_size_masks_shrunk_to_the_photos() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("llff");
    let (cameras, bounds) = common::arc_cameras(2, 40, 24, 4);
    let photos: Vec<_> = (0..2).map(|k| common::pattern(40, 24, k)).collect();
    // images/ at 40x24 and images_4/ at 10x6, as LLFF captures come.
    scenes::write_llff(&dir, &cameras, &bounds, &photos, 1, BitDepth::Eight).unwrap();
    let full = open(&dir, 1).unwrap();
    let stems: Vec<String> = full
        .image_paths
        .iter()
        .map(|p| p.file_stem().unwrap().to_str().unwrap().to_string())
        .collect();
    std::fs::create_dir_all(dir.join("images_4")).unwrap();
    for (k, p) in full.image_paths.iter().enumerate() {
        scenes::images::write_png(
            &dir.join("images_4").join(p.file_name().unwrap()),
            &common::pattern(10, 6, k + 5),
            BitDepth::Eight,
        )
        .unwrap();
    }
    // Full-size masks/ only: shrunk four times for images_4/ (black for the left 8 of 40
    // columns: the left 2 of 10).
    for s in &stems {
        edge_mask(&dir.join("masks").join(format!("{s}.png")), 40, 24, 8);
    }
    let quarter = open(&dir, 4).unwrap();
    assert_eq!(quarter.mask_folder(), Some(dir.join("masks")));
    assert!(quarter.summary().to_string().contains("masks       masks/"));
    let m = quarter.load_mask(0).unwrap().unwrap();
    assert_eq!(m.len(), 60);
    assert_eq!((m[1], m[2]), (0.0, 1.0));
    // masks_4/ beside images_4/ wins, at the photos' size (black for the left 5 of 10).
    for s in &stems {
        edge_mask(&dir.join("masks_4").join(format!("{s}.png")), 10, 6, 5);
    }
    let quarter = open(&dir, 4).unwrap();
    assert_eq!(quarter.mask_folder(), Some(dir.join("masks_4")));
    assert!(
        quarter
            .summary()
            .to_string()
            .contains("masks       masks_4/")
    );
    let m = quarter.load_mask(1).unwrap().unwrap();
    assert_eq!((m[4], m[5]), (0.0, 1.0));
    // The full-size run still reads masks/.
    assert_eq!(
        open(&dir, 1).unwrap().mask_folder(),
        Some(dir.join("masks"))
    );
    // A masks_4/ file of another size (not a whole multiple) is refused naming it; a missing
    // one names the folder it was looked for in.
    edge_mask(
        &dir.join("masks_4").join(format!("{}.png", stems[0])),
        7,
        6,
        2,
    );
    let e = quarter.load_mask(0).unwrap_err().to_string();
    assert!(
        e.contains("masks_4") && e.contains(&stems[0]) && e.contains("7x6"),
        "{e}"
    );
    std::fs::remove_file(dir.join("masks_4").join(format!("{}.png", stems[0]))).unwrap();
    let e = quarter.load_mask(0).unwrap_err().to_string();
    assert!(e.contains("masks_4/ folder"), "{e}");
}
