//! LLFF: the axis conversion on a hand-made case, a synthetic write/read round trip, and bad
//! input.

mod common;

use std::path::Path;

use glam::{DMat3, DVec3};
use npyz::WriterBuilder;
use scenes::llff::{self, LlffPose};
use scenes::{BitDepth, Bounds, OpenOptions, PointSource, Resolution, SceneError};

fn options(downsample: u32) -> OpenOptions {
    OpenOptions {
        resolution: Resolution::Downsample(downsample),
        random_points: 2000,
        seed: 7,
        ..OpenOptions::default()
    }
}

#[test]
fn llff_axes_convert_to_opencv() {
    // Camera at (4, 0, 0) looking at the origin with world +z up. By hand, in LLFF terms:
    // back = +x (away from the target), down = -z, and right = +y, the one choice for which
    // right x down = forward (-x) as a non-mirrored camera requires.
    let eye = DVec3::new(4.0, 0.0, 0.0);
    let pose = LlffPose {
        axes: DMat3::from_cols(
            DVec3::new(0.0, 0.0, -1.0), // down
            DVec3::new(0.0, 1.0, 0.0),  // right
            DVec3::new(1.0, 0.0, 0.0),  // back
        ),
        center: eye,
        height: 300.0,
        width: 400.0,
        focal: 500.0,
        bounds: Bounds {
            near: 1.0,
            far: 10.0,
        },
    };
    let camera = pose.to_camera("hand", 200, 150);
    assert_eq!(
        (camera.fx, camera.fy, camera.cx, camera.cy),
        (250.0, 250.0, 100.0, 75.0)
    );
    assert!((camera.center() - eye).length() < 1e-15);

    let target = camera.project(DVec3::ZERO).expect("target in front");
    assert_eq!((target.u, target.v, target.depth), (100.0, 75.0, 4.0));
    // One unit to the camera's right (+y world) lands right of centre by f/4 pixels.
    let right = camera.project(DVec3::new(0.0, 1.0, 0.0)).unwrap();
    assert!((right.u - (100.0 + 250.0 / 4.0)).abs() < 1e-12 && (right.v - 75.0).abs() < 1e-12);
    // World up (+z) lands above the centre: smaller v.
    let up = camera.project(DVec3::new(0.0, 0.0, 1.0)).unwrap();
    assert!((up.v - (75.0 - 250.0 / 4.0)).abs() < 1e-12 && (up.u - 100.0).abs() < 1e-12);
    // Behind the camera projects nowhere.
    assert!(camera.project(DVec3::new(8.0, 0.0, 0.0)).is_none());

    let back = LlffPose::from_camera(&camera, pose.bounds, 2.0).unwrap();
    assert_eq!(back, pose);
}

#[test]
fn synthetic_capture_round_trips() {
    let tmp = tempfile::tempdir().unwrap();
    let (cameras, bounds) = common::arc_cameras(11, 64, 48, 3);
    let images: Vec<_> = (0..cameras.len())
        .map(|k| common::pattern(64, 48, k))
        .collect();
    let dir = tmp.path().join("scene");
    scenes::write_llff(&dir, &cameras, &bounds, &images, 2, BitDepth::Sixteen).unwrap();
    assert!(dir.join("images_2/img000.png").is_file());
    // Nothing but the scene is left next to it: the staging folder was renamed.
    assert_eq!(std::fs::read_dir(tmp.path()).unwrap().count(), 1);

    let poses = llff::read_poses_bounds(&dir.join("poses_bounds.npy")).unwrap();
    assert_eq!((poses[0].width, poses[0].height), (128.0, 96.0));
    assert_eq!(poses[0].focal, 64.0 * 0.9 * 2.0);

    let capture = scenes::open(&dir, &options(2)).unwrap();
    assert_eq!(capture.len(), cameras.len());
    for (got, want) in capture.cameras.iter().zip(&cameras) {
        assert_eq!(got.name, want.name);
        assert_eq!((got.width, got.height), (want.width, want.height));
        assert_eq!(
            (got.fx, got.fy, got.cx, got.cy),
            (want.fx, want.fy, want.cx, want.cy)
        );
        let a = got.world_to_camera.to_mat4().to_cols_array();
        let b = want.world_to_camera.to_mat4().to_cols_array();
        let err = a
            .iter()
            .zip(&b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f64::max);
        assert!(err < 1e-12, "{}: matrices differ by {err}", got.name);
    }
    assert_eq!(capture.bounds, bounds);
    for (k, want) in images.iter().enumerate() {
        let got = capture.load_image(k).unwrap();
        let err = got
            .data
            .iter()
            .zip(&want.data)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f32::max);
        assert!(err <= 0.5 / 65535.0 + 1e-7, "16-bit image {k} off by {err}");
    }

    // No sparse model: a seeded random cloud inside the frusta, the same for the same seed.
    assert_eq!(
        capture.point_source,
        PointSource::Random {
            count: 2000,
            seed: 7,
            background: 0,
        }
    );
    assert_eq!(capture.points.len(), 2000);
    for &p in &capture.points.positions {
        let seen = capture.cameras.iter().zip(&capture.bounds).any(|(c, b)| {
            c.project(p).is_some_and(|pr| {
                c.contains(&pr) && pr.depth >= b.near - 1e-9 && pr.depth <= b.far + 1e-9
            })
        });
        assert!(seen, "{p} lies outside every frustum");
    }
    let again = scenes::open(&dir, &options(2)).unwrap();
    assert_eq!(again.points, capture.points);
    let other = scenes::open(
        &dir,
        &OpenOptions {
            seed: 8,
            ..options(2)
        },
    )
    .unwrap();
    assert_ne!(other.points, capture.points);
}

#[test]
fn eight_bit_writer_rounds_and_refuses_non_llff_cameras() {
    let tmp = tempfile::tempdir().unwrap();
    let (mut cameras, bounds) = common::arc_cameras(2, 16, 12, 1);
    let images: Vec<_> = (0..2).map(|k| common::pattern(16, 12, k)).collect();
    let dir = tmp.path().join("eight");
    scenes::write_llff(&dir, &cameras, &bounds, &images, 1, BitDepth::Eight).unwrap();
    let capture = scenes::open(&dir, &options(1)).unwrap();
    let got = capture.load_image(1).unwrap();
    let err = got
        .data
        .iter()
        .zip(&images[1].data)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f32::max);
    assert!(err <= 0.5 / 255.0 + 1e-6 && err > 0.0, "8-bit error {err}");

    // An off-centre principal point cannot be written as LLFF; the scene must not appear.
    cameras[1].cx += 1.0;
    let bad = tmp.path().join("bad");
    let e = scenes::write_llff(&bad, &cameras, &bounds, &images, 1, BitDepth::Eight).unwrap_err();
    assert!(e.to_string().contains("principal point"), "{e}");
    assert!(!bad.exists());
    assert_eq!(
        std::fs::read_dir(tmp.path()).unwrap().count(),
        1,
        "staging folder left behind"
    );
    // Refuses to overwrite.
    assert!(
        scenes::write_llff(
            &dir,
            &cameras[..1],
            &bounds[..1],
            &images[..1],
            1,
            BitDepth::Eight
        )
        .is_err()
    );
}

fn write_rows(path: &Path, rows: &[[f64; 17]]) {
    let mut file = std::fs::File::create(path).unwrap();
    let mut w = npyz::WriteOptions::<f64>::new()
        .default_dtype()
        .shape(&[rows.len() as u64, 17])
        .writer(&mut file)
        .begin_nd()
        .unwrap();
    for row in rows {
        w.extend(row.iter().copied()).unwrap();
    }
    w.finish().unwrap();
}

/// A valid two-image scene whose pieces the bad-input tests then break.
fn small_scene(root: &Path) -> [[f64; 17]; 2] {
    let (cameras, bounds) = common::arc_cameras(2, 8, 6, 5);
    let images: Vec<_> = (0..2).map(|k| common::pattern(8, 6, k)).collect();
    scenes::write_llff(root, &cameras, &bounds, &images, 1, BitDepth::Eight).unwrap();
    let mut rows = [[0.0; 17]; 2];
    for (row, (c, b)) in rows.iter_mut().zip(cameras.iter().zip(&bounds)) {
        let pose = LlffPose::from_camera(c, *b, 1.0).unwrap();
        let cols = [
            pose.axes.x_axis,
            pose.axes.y_axis,
            pose.axes.z_axis,
            pose.center,
            DVec3::new(pose.height, pose.width, pose.focal),
        ];
        for (ci, col) in cols.iter().enumerate() {
            for r in 0..3 {
                row[r * 5 + ci] = col[r];
            }
        }
        row[15] = b.near;
        row[16] = b.far;
    }
    rows
}

#[test]
fn bad_llff_input_names_the_file() {
    let tmp = tempfile::tempdir().unwrap();

    let missing = tmp.path().join("nowhere");
    let e = scenes::open(&missing, &options(1)).unwrap_err();
    assert!(
        matches!(e, SceneError::NotFound { .. }) && e.to_string().contains("nowhere"),
        "{e}"
    );

    // NaN in a pose.
    let nan = tmp.path().join("nan");
    let mut rows = small_scene(&nan);
    scenes::open(&nan, &options(1)).expect("the unbroken scene opens");
    rows[1][7] = f64::NAN;
    write_rows(&nan.join("poses_bounds.npy"), &rows);
    let e = scenes::open(&nan, &options(1)).unwrap_err();
    assert!(
        matches!(
            e,
            SceneError::NonFinite {
                row: 1,
                column: 7,
                ..
            }
        ),
        "{e}"
    );
    assert!(e.to_string().contains("nan/poses_bounds.npy"), "{e}");

    // Pose and image counts differ.
    let count = tmp.path().join("count");
    let rows = small_scene(&count);
    write_rows(
        &count.join("poses_bounds.npy"),
        &[rows[0], rows[1], rows[0]],
    );
    let e = scenes::open(&count, &options(1)).unwrap_err();
    let text = e.to_string();
    assert!(
        matches!(
            e,
            SceneError::CountMismatch {
                poses: 3,
                images: 2,
                ..
            }
        ),
        "{e}"
    );
    assert!(
        text.contains("3 poses") && text.contains("2 images"),
        "{text}"
    );

    // An image of another size.
    let sizes = tmp.path().join("sizes");
    small_scene(&sizes);
    let odd = sizes.join("images/img001.png");
    std::fs::remove_file(&odd).unwrap();
    scenes::images::write_png(&odd, &common::pattern(9, 6, 0), BitDepth::Eight).unwrap();
    let e = scenes::open(&sizes, &options(1)).unwrap_err();
    assert!(matches!(e, SceneError::ImageSizeMismatch { .. }), "{e}");
    assert!(e.to_string().contains("img001.png"), "{e}");

    // No images at all.
    let empty = tmp.path().join("empty");
    small_scene(&empty);
    for f in std::fs::read_dir(empty.join("images")).unwrap() {
        std::fs::remove_file(f.unwrap().path()).unwrap();
    }
    std::fs::write(empty.join("images/notes.txt"), "not an image").unwrap();
    let e = scenes::open(&empty, &options(1)).unwrap_err();
    assert!(
        matches!(e, SceneError::NoImages { .. }) && e.to_string().contains("empty/images"),
        "{e}"
    );

    // A missing downsample folder, with no images/ to shrink, lists what exists.
    let only2 = tmp.path().join("only2");
    small_scene(&only2);
    std::fs::rename(only2.join("images"), only2.join("images_2")).unwrap();
    let e = scenes::open(&only2, &options(4)).unwrap_err();
    assert!(
        e.to_string().contains("images_4") && e.to_string().contains("available: images_2"),
        "{e}"
    );

    // Wrong shape, bad bounds, garbage file.
    let shape = tmp.path().join("shape");
    small_scene(&shape);
    npyz::to_file_1d(shape.join("poses_bounds.npy"), vec![1.0f64; 17]).unwrap();
    let e = scenes::open(&shape, &options(1)).unwrap_err();
    assert!(e.to_string().contains("expected [N, 17]"), "{e}");
    let mut rows = small_scene(&tmp.path().join("bounds"));
    rows[0][15] = 5.0;
    rows[0][16] = 1.0;
    write_rows(&tmp.path().join("bounds/poses_bounds.npy"), &rows);
    let e = scenes::open(&tmp.path().join("bounds"), &options(1)).unwrap_err();
    assert!(
        e.to_string().contains("row 0") && e.to_string().contains("near"),
        "{e}"
    );
    std::fs::write(shape.join("poses_bounds.npy"), b"garbage").unwrap();
    let e = scenes::open(&shape, &options(1)).unwrap_err();
    assert!(e.to_string().contains("shape/poses_bounds.npy"), "{e}");
}

#[test]
fn f32_fortran_poses_read_the_same() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("f32");
    let rows = small_scene(&dir);
    let reference = llff::read_poses_bounds(&dir.join("poses_bounds.npy")).unwrap();
    let mut file = std::fs::File::create(dir.join("poses_bounds.npy")).unwrap();
    let mut w = npyz::WriteOptions::<f32>::new()
        .default_dtype()
        .order(npyz::Order::Fortran)
        .shape(&[2, 17])
        .writer(&mut file)
        .begin_nd()
        .unwrap();
    for c in 0..17 {
        for row in &rows {
            w.push(&(row[c] as f32)).unwrap();
        }
    }
    w.finish().unwrap();
    drop(file);
    let poses = llff::read_poses_bounds(&dir.join("poses_bounds.npy")).unwrap();
    for (a, b) in poses.iter().zip(&reference) {
        assert!((a.center - b.center).length() < 1e-5);
        assert!((a.axes.x_axis - b.axes.x_axis).length() < 1e-6);
        assert!((a.bounds.far - b.bounds.far).abs() < 1e-5);
    }
}
