//! The aberrated-capture maker: layout, agreement with the imaging model applied directly,
//! byte-for-byte reproducibility, and no half scene on failure.

mod common;

use std::path::Path;

use aberration::{BlurMode, ImagingModel, NoiseModel, PsfGrid};
use scenes::aberrated::{self, AberrationRecord, CLEAN_DIR, PSF_FILE};
use scenes::{AberrateOptions, BitDepth, OpenOptions, Resolution, make_aberrated, write_llff};

const W: u32 = 48;
const H: u32 = 36;

fn write_source(dir: &Path) {
    let (cameras, bounds) = common::arc_cameras(5, W, H, 3);
    let images: Vec<_> = (0..5).map(|k| common::pattern(W, H, k)).collect();
    write_llff(dir, &cameras, &bounds, &images, 4, BitDepth::Eight).unwrap();
}

/// A 3×3 grid of Gaussian blurs whose width grows away from the centre.
fn write_psf(path: &Path) -> PsfGrid {
    let (g, k) = (3usize, 7usize);
    let mut planar = Vec::new();
    for cell in 0..g * g {
        let (gy, gx) = ((cell / g) as f64 - 1.0, (cell % g) as f64 - 1.0);
        for c in 0..3 {
            let sigma = 0.6 + 0.4 * (gx * gx + gy * gy).sqrt() + 0.2 * c as f64;
            let mut kernel: Vec<f32> = (0..k * k)
                .map(|i| {
                    let (y, x) = ((i / k) as f64 - 3.0, (i % k) as f64 - 3.0);
                    (-(x * x + y * y) / (2.0 * sigma * sigma)).exp() as f32
                })
                .collect();
            let sum: f32 = kernel.iter().sum();
            kernel.iter_mut().for_each(|v| *v /= sum);
            planar.extend(kernel);
        }
    }
    let psf = PsfGrid::from_planar(g, k, planar).unwrap();
    psf.save_npy(path).unwrap();
    psf
}

fn open(dir: &Path) -> scenes::Capture {
    let options = OpenOptions {
        resolution: Resolution::Downsample(4),
        ..OpenOptions::default()
    };
    scenes::open(dir, &options).unwrap()
}

fn options(seed: u64) -> AberrateOptions {
    AberrateOptions {
        mode: BlurMode::Blend,
        sensor_px: Some(54),
        noise: NoiseModel::default(),
        seed,
        depth: BitDepth::Sixteen,
    }
}

fn all_files(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                let rel = p.strip_prefix(dir).unwrap().display().to_string();
                out.push((rel, std::fs::read(&p).unwrap()));
            }
        }
    }
    out.sort();
    out
}

#[test]
fn maker_writes_an_llff_capture_the_model_would_record() {
    let tmp = tempfile::tempdir().unwrap();
    let src = tmp.path().join("src");
    write_source(&src);
    let psf_path = tmp.path().join("grid.npy");
    let psf = write_psf(&psf_path);
    let capture = open(&src);
    let dest = tmp.path().join("abr");
    let report = make_aberrated(&capture, &psf_path, &dest, &options(11), &|| {}).unwrap();
    assert_eq!((report.images, report.width, report.height), (5, W, H));
    assert!(report.mean_psnr.is_finite() && report.mean_psnr < 60.0);

    let out = open(&dest);
    assert_eq!(out.len(), capture.len());
    for (a, b) in capture.cameras.iter().zip(&out.cameras) {
        assert_eq!(a.name, b.name);
        assert!((a.fx - b.fx).abs() < 1e-9 && (a.cx - b.cx).abs() < 1e-9);
        let (ma, mb) = (a.world_to_camera.to_mat4(), b.world_to_camera.to_mat4());
        assert!(ma.abs_diff_eq(mb, 1e-9), "{} pose changed", a.name);
    }
    assert_eq!(
        std::fs::read(&psf_path).unwrap(),
        std::fs::read(dest.join(PSF_FILE)).unwrap()
    );
    let record = AberrationRecord::read(&dest).unwrap().unwrap();
    assert_eq!(record.blur_mode(&dest).unwrap(), BlurMode::Blend);
    assert_eq!((record.seed, record.sensor_px), (11, Some(54)));
    assert_eq!(record.load_psf(&dest).unwrap(), psf);

    // Independent of the maker: the imaging model applied by hand to the source image.
    let model = ImagingModel::new(
        &psf,
        W as usize,
        H as usize,
        BlurMode::Blend,
        Some(54),
        NoiseModel::default(),
    )
    .unwrap();
    for i in 0..capture.len() {
        let clean = capture.load_image(i).unwrap();
        let stored_clean = aberrated::load_clean_image(&out, i).unwrap().unwrap();
        assert_eq!(clean, stored_clean, "clean/ must hold the source pixels");
        let expect = model
            .capture(&aberrated::to_planar(&clean), aberrated::image_seed(11, i))
            .unwrap();
        let got = aberrated::to_planar(&out.load_image(i).unwrap());
        let worst = expect
            .data
            .iter()
            .zip(&got.data)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        assert!(worst <= 0.51 / 65535.0 + 1e-7, "image {i}: off by {worst}");
        assert!(
            aberration::psnr(&got, &expect).unwrap()
                > aberration::psnr(&got, &aberrated::to_planar(&clean)).unwrap()
        );
    }

    // A clean/ folder missing one image names it, rather than scoring that view against
    // its blurred photo.
    let name = out.image_paths[1].file_name().unwrap().to_owned();
    let missing = dest.join(aberrated::CLEAN_DIR).join(&name);
    std::fs::remove_file(&missing).unwrap();
    let err = aberrated::load_clean_image(&out, 1)
        .unwrap_err()
        .to_string();
    assert!(err.contains(&*missing.to_string_lossy()), "{err}");
    assert!(aberrated::load_clean_image(&out, 0).unwrap().is_some());

    // A psf.npy swapped for another grid (a valid file, but not the blur the photos have)
    // is refused, naming the file; the original put back reads again.
    let kept = std::fs::read(dest.join(PSF_FILE)).unwrap();
    let mut planar = psf.planar().to_vec();
    planar.swap(0, 24);
    let other = PsfGrid::from_planar(psf.grid(), psf.size(), planar).unwrap();
    other.save_npy(&dest.join(PSF_FILE)).unwrap();
    let err = record.load_psf(&dest).unwrap_err().to_string();
    assert!(
        err.contains("psf.npy") && err.contains("not the PSF grid this capture was made with"),
        "{err}"
    );
    std::fs::write(dest.join(PSF_FILE), &kept).unwrap();
    assert_eq!(record.load_psf(&dest).unwrap(), psf);

    // The record names the grid by XXH3; a record written before XXH3 (its FNV-1a, under
    // `psf_fnv1a`) still checks the grid, both ways.
    let path = dest.join(aberrated::RECORD_FILE);
    let text = std::fs::read_to_string(&path).unwrap();
    let doc: serde_json::Value = serde_json::from_str(&text).unwrap();
    assert!(doc["psf_checksum"].as_str().unwrap().starts_with("xxh3:"));
    let mut old = doc.clone();
    let map = old.as_object_mut().unwrap();
    map.remove("psf_checksum");
    map.insert(
        "psf_fnv1a".into(),
        format!("{:016x}", base::hash::fnv1a64(&kept)).into(),
    );
    std::fs::write(&path, old.to_string()).unwrap();
    let legacy = AberrationRecord::read(&dest).unwrap().unwrap();
    assert_eq!(legacy.load_psf(&dest).unwrap(), psf);
    other.save_npy(&dest.join(PSF_FILE)).unwrap();
    assert!(legacy.load_psf(&dest).is_err());
    std::fs::write(dest.join(PSF_FILE), &kept).unwrap();
    std::fs::write(&path, &text).unwrap();

    // A noise level beyond f32 is reported as written, not as the infinity serde makes of it.
    let path = dest.join(aberrated::RECORD_FILE);
    let text = std::fs::read_to_string(&path).unwrap();
    let mut doc: serde_json::Value = serde_json::from_str(&text).unwrap();
    doc["noise_gaussian_sigma"] = serde_json::json!(1e300);
    std::fs::write(&path, doc.to_string()).unwrap();
    let err = AberrationRecord::read(&dest).unwrap_err().to_string();
    assert!(
        err.contains("noise_gaussian_sigma 1e300") && err.contains("aberration.json"),
        "{err}"
    );
}

#[test]
fn same_seed_same_bytes_other_seed_other_noise() {
    let tmp = tempfile::tempdir().unwrap();
    let src = tmp.path().join("src");
    write_source(&src);
    let psf_path = tmp.path().join("grid.npy");
    write_psf(&psf_path);
    let capture = open(&src);
    let count = std::sync::atomic::AtomicUsize::new(0);
    let tick = || {
        count.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    };
    let a = tmp.path().join("a");
    let b = tmp.path().join("b");
    let c = tmp.path().join("c");
    make_aberrated(&capture, &psf_path, &a, &options(5), &tick).unwrap();
    assert_eq!(count.load(std::sync::atomic::Ordering::Relaxed), 5);
    make_aberrated(&capture, &psf_path, &b, &options(5), &|| {}).unwrap();
    make_aberrated(&capture, &psf_path, &c, &options(6), &|| {}).unwrap();
    let (fa, fb, fc) = (all_files(&a), all_files(&b), all_files(&c));
    let names: Vec<&str> = fa.iter().map(|f| f.0.as_str()).collect();
    assert!(names.contains(&"poses_bounds.npy"));
    assert!(names.contains(&"images_4/img000.png"));
    assert!(names.contains(&format!("{CLEAN_DIR}/img004.png").as_str()));
    assert_eq!(fa, fb, "same seed must reproduce every byte");
    let differing: Vec<&str> = fa
        .iter()
        .zip(&fc)
        .filter(|(x, y)| x.1 != y.1)
        .map(|(x, _)| x.0.as_str())
        .collect();
    assert!(differing.iter().any(|n| n.starts_with("images_4/")));
    assert!(
        differing
            .iter()
            .all(|n| n.starts_with("images_4/") || *n == "aberration.json")
    );
}

#[test]
fn failures_leave_no_half_scene() {
    let tmp = tempfile::tempdir().unwrap();
    let src = tmp.path().join("src");
    write_source(&src);
    let capture = open(&src);
    let listing = |dir: &Path| -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    };

    // Not a PSF file: the error names it and nothing is created.
    let bad = tmp.path().join("bad.npy");
    std::fs::write(&bad, b"not an npy file").unwrap();
    let before = listing(tmp.path());
    let err = make_aberrated(&capture, &bad, &tmp.path().join("x"), &options(0), &|| {})
        .unwrap_err()
        .to_string();
    assert!(err.contains("bad.npy"), "{err}");
    assert_eq!(listing(tmp.path()), before);

    // A source image that turns unreadable half-way: no destination, no staging folder left.
    let psf_path = tmp.path().join("grid.npy");
    write_psf(&psf_path);
    let before = listing(tmp.path());
    std::fs::write(&capture.image_paths[3], b"garbage").unwrap();
    let err = make_aberrated(
        &capture,
        &psf_path,
        &tmp.path().join("y"),
        &options(0),
        &|| {},
    )
    .unwrap_err()
    .to_string();
    assert!(err.contains("img003"), "{err}");
    assert_eq!(listing(tmp.path()), before);

    // An existing destination is never overwritten.
    let existing = tmp.path().join("exists");
    std::fs::create_dir(&existing).unwrap();
    std::fs::write(existing.join("keep.txt"), b"mine").unwrap();
    // (a fresh source: the first one now has a broken image)
    let err = make_aberrated(
        &open_fresh(tmp.path()),
        &psf_path,
        &existing,
        &options(0),
        &|| {},
    )
    .unwrap_err()
    .to_string();
    assert!(err.contains("exists"), "{err}");
    assert_eq!(std::fs::read(existing.join("keep.txt")).unwrap(), b"mine");
}

fn open_fresh(root: &Path) -> scenes::Capture {
    let src = root.join("src2");
    write_source(&src);
    open(&src)
}

#[test]
fn clean_capture_has_no_record_and_no_clean_images() {
    let tmp = tempfile::tempdir().unwrap();
    let src = tmp.path().join("src");
    write_source(&src);
    assert!(AberrationRecord::read(&src).unwrap().is_none());
    assert!(
        aberrated::load_clean_image(&open(&src), 0)
            .unwrap()
            .is_none()
    );
    std::fs::write(src.join(aberrated::RECORD_FILE), "{ \"psf\": 3 }").unwrap();
    let err = AberrationRecord::read(&src).unwrap_err().to_string();
    assert!(err.contains("aberration.json"), "{err}");
}

#[test]
fn a_masked_capture_is_composited_before_the_blur_and_keeps_its_masks() {
    let tmp = tempfile::tempdir().unwrap();
    let src = tmp.path().join("src");
    write_source(&src);
    let capture = open(&src);
    // masks_4/ beside images_4/: the left third of every photo is not the object.
    std::fs::create_dir_all(src.join("masks_4")).unwrap();
    for c in &capture.cameras {
        image::GrayImage::from_fn(W, H, |x, _| image::Luma([if x < W / 3 { 0 } else { 255 }]))
            .save(src.join("masks_4").join(format!("{}.png", c.name)))
            .unwrap();
    }
    let capture = open(&src);
    let psf_path = tmp.path().join("grid.npy");
    let psf = write_psf(&psf_path);
    let dest = tmp.path().join("abr");
    make_aberrated(&capture, &psf_path, &dest, &options(3), &|| {}).unwrap();
    let out = open(&dest);
    let record = AberrationRecord::read(&dest).unwrap().unwrap();
    assert_eq!(record.composited_over, Some([0.0; 3]));
    assert!(!record.masks_from_undistortion, "the source's own masks");
    // The copy's masks are the source's, beside its photos; its clean photos the composites.
    assert_eq!(out.mask_folder(), Some(dest.join("masks_4")));
    let model = ImagingModel::new(
        &psf,
        W as usize,
        H as usize,
        BlurMode::Blend,
        Some(54),
        NoiseModel::default(),
    )
    .unwrap();
    for i in 0..capture.len() {
        let (a, b) = (
            out.load_mask(i).unwrap().unwrap(),
            capture.load_mask(i).unwrap().unwrap(),
        );
        let off = a
            .iter()
            .zip(&b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0f32, f32::max);
        assert!(a.len() == b.len() && off < 1e-6, "mask {i} off by {off}");
        let mut composite = capture.load_image(i).unwrap();
        for (k, p) in composite.data.chunks_exact_mut(3).enumerate() {
            if (k as u32 % W) < W / 3 {
                p.fill(0.0);
            }
        }
        let clean = aberrated::load_clean_image(&out, i).unwrap().unwrap();
        let worst = |a: &[f32], b: &[f32]| {
            a.iter()
                .zip(b)
                .map(|(x, y)| (x - y).abs())
                .fold(0.0f32, f32::max)
        };
        assert!(worst(&clean.data, &composite.data) <= 0.51 / 65535.0);
        // The photo is the lens's blur of the composite, not of the whole photo.
        let expect = model
            .capture(
                &aberrated::to_planar(&composite),
                aberrated::image_seed(3, i),
            )
            .unwrap();
        let got = aberrated::to_planar(&out.load_image(i).unwrap());
        assert!(
            worst(&got.data, &expect.data) <= 0.51 / 65535.0 + 1e-6,
            "image {i}"
        );
    }
    // Without masks the copy has none and the record says nothing of compositing.
    let plain = tmp.path().join("plain");
    let src2 = tmp.path().join("src2");
    write_source(&src2);
    make_aberrated(&open(&src2), &psf_path, &plain, &options(3), &|| {}).unwrap();
    assert_eq!(open(&plain).mask_folder(), None);
    assert_eq!(
        AberrationRecord::read(&plain)
            .unwrap()
            .unwrap()
            .composited_over,
        None
    );
}
