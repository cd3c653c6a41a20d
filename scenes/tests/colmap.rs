//! COLMAP: binary and text agree, malformed files fail clearly, a COLMAP capture opens.

mod common;

use std::path::Path;

use glam::DVec3;
use scenes::colmap::{
    self, ColmapCamera, ColmapImage, ColmapModel, ColmapPoint, ModelFormat, Point2D, TrackElement,
};
use scenes::{
    BitDepth, CameraModel, CaptureFormat, OpenOptions, PointSource, Resolution, SceneError,
};

/// One camera of each supported model, three images, a few tracked points in front of them.
fn model() -> ColmapModel {
    let models = [
        (CameraModel::SimplePinhole, vec![90.0, 40.0, 30.0]),
        (CameraModel::Pinhole, vec![90.0, 91.5, 40.0, 30.0]),
        (CameraModel::SimpleRadial, vec![90.0, 40.0, 30.0, 0.0125]),
        (CameraModel::Radial, vec![90.0, 40.0, 30.0, 0.01, -0.002]),
        (
            CameraModel::OpenCv,
            vec![90.0, 91.0, 40.5, 29.5, 0.01, -0.002, 1e-4, -3e-4],
        ),
    ];
    let cameras = models
        .into_iter()
        .enumerate()
        .map(|(i, (model, params))| ColmapCamera {
            id: i as u32 + 1,
            model,
            width: 80,
            height: 60,
            params,
        })
        .collect();
    let (views, _) = common::arc_cameras(3, 80, 60, 11);
    let images: Vec<ColmapImage> = views
        .iter()
        .enumerate()
        .map(|(i, c)| {
            let mut im = ColmapImage::from_world_to_camera(
                10 + i as u32,
                [5, 3, 1][i],
                &format!("{}.png", c.name),
                &c.world_to_camera,
            );
            im.points2d = vec![
                Point2D {
                    xy: [1.25, 2.5],
                    point3d_id: 0,
                },
                Point2D {
                    xy: [10.0 / 3.0, 7.0],
                    point3d_id: -1,
                },
            ];
            im
        })
        .collect();
    let points = (0..40)
        .map(|k| {
            let t = k as f64 / 40.0;
            ColmapPoint {
                id: k,
                xyz: DVec3::new(t - 0.5, (t * 9.0).sin() * 0.4, (t * 5.0).cos() * 0.5),
                rgb: [k as u8, 200, 255 - k as u8],
                error: 0.1 + t,
                track: (0..3)
                    .map(|i| TrackElement {
                        image_id: 10 + i,
                        point2d_idx: k as u32,
                    })
                    .collect(),
            }
        })
        .collect();
    ColmapModel {
        cameras,
        images,
        points,
    }
}

#[test]
fn binary_and_text_readers_agree() {
    let tmp = tempfile::tempdir().unwrap();
    let (bin, txt) = (tmp.path().join("bin"), tmp.path().join("txt"));
    std::fs::create_dir_all(&bin).unwrap();
    std::fs::create_dir_all(&txt).unwrap();
    let original = model();
    colmap::write_model(&bin, &original, ModelFormat::Binary).unwrap();
    colmap::write_model(&txt, &original, ModelFormat::Text).unwrap();
    let from_bin = colmap::read_model(&bin).unwrap();
    let from_txt = colmap::read_model(&txt).unwrap();
    assert_eq!(from_bin, from_txt);
    assert_eq!(from_bin, original);

    // Intrinsics and kept distortion per model.
    let k = from_bin.cameras[4].intrinsics();
    assert_eq!((k.fx, k.fy, k.cx, k.cy), (90.0, 91.0, 40.5, 29.5));
    let d = k.distortion.unwrap();
    assert_eq!(
        (d.model, d.k1, d.k2, d.p1, d.p2),
        (CameraModel::OpenCv, 0.01, -0.002, 1e-4, -3e-4)
    );
    assert!(from_bin.cameras[0].intrinsics().distortion.is_none());
    assert!(from_bin.cameras[1].intrinsics().distortion.is_none());
    assert_eq!(
        from_bin.cameras[2].intrinsics().distortion.unwrap().k1,
        0.0125
    );
    assert_eq!(
        from_bin.cameras[3].intrinsics().distortion.unwrap().k2,
        -0.002
    );

    // Quaternion round trip gives back the pose.
    let (views, _) = common::arc_cameras(3, 80, 60, 11);
    for (im, view) in from_txt.images.iter().zip(&views) {
        let a = im.world_to_camera().to_mat4().to_cols_array();
        let b = view.world_to_camera.to_mat4().to_cols_array();
        assert!(a.iter().zip(&b).all(|(x, y)| (x - y).abs() < 1e-12));
    }
}

fn expect_err(path: &Path, bytes: &[u8], read: fn(&Path) -> scenes::Result<()>) -> SceneError {
    std::fs::write(path, bytes).unwrap();
    let e = read(path).expect_err("malformed file must not parse");
    assert!(
        e.to_string().contains(&path.display().to_string()),
        "error lacks the file: {e}"
    );
    e
}

fn cameras_bin(p: &Path) -> scenes::Result<()> {
    colmap::binary::read_cameras(p).map(drop)
}
fn images_bin(p: &Path) -> scenes::Result<()> {
    colmap::binary::read_images(p).map(drop)
}
fn points_bin(p: &Path) -> scenes::Result<()> {
    colmap::binary::read_points3d(p).map(drop)
}

#[test]
fn malformed_binary_files_fail_clearly() {
    let tmp = tempfile::tempdir().unwrap();
    colmap::write_model(tmp.path(), &model(), ModelFormat::Binary).unwrap();
    let bad = tmp.path().join("bad.bin");
    for (name, read) in [
        (
            "cameras.bin",
            cameras_bin as fn(&Path) -> scenes::Result<()>,
        ),
        ("images.bin", images_bin),
        ("points3D.bin", points_bin),
    ] {
        let good = std::fs::read(tmp.path().join(name)).unwrap();
        read(&tmp.path().join(name)).unwrap();
        // Every truncation is an error, never a panic.
        for cut in 0..good.len() {
            let e = expect_err(&bad, &good[..cut], read);
            assert!(
                matches!(e, SceneError::Truncated { .. } | SceneError::Invalid { .. }),
                "{name} cut at {cut}: {e}"
            );
        }
        // A count larger than the records present.
        let mut more = good.clone();
        more[..8].copy_from_slice(
            &(u64::from_le_bytes(good[..8].try_into().unwrap()) + 1).to_le_bytes(),
        );
        let e = expect_err(&bad, &more, read);
        assert!(matches!(e, SceneError::Truncated { .. }), "{name}: {e}");
        // An absurd count must not try to allocate.
        let mut huge = good.clone();
        huge[..8].copy_from_slice(&u64::MAX.to_le_bytes());
        let e = expect_err(&bad, &huge, read);
        assert!(e.to_string().contains("declared"), "{name}: {e}");
        // A count smaller than the records present leaves trailing bytes.
        let mut fewer = good.clone();
        fewer[..8].copy_from_slice(
            &(u64::from_le_bytes(good[..8].try_into().unwrap()) - 1).to_le_bytes(),
        );
        let e = expect_err(&bad, &fewer, read);
        assert!(
            e.to_string().contains("count in the header is wrong"),
            "{name}: {e}"
        );
    }
    // Unknown camera model id (5 is OPENCV_FISHEYE, unsupported).
    let mut good = std::fs::read(tmp.path().join("cameras.bin")).unwrap();
    good[12..16].copy_from_slice(&5i32.to_le_bytes());
    let e = expect_err(&bad, &good, cameras_bin);
    assert!(matches!(e, SceneError::UnknownCameraModel { .. }), "{e}");
    assert!(e.to_string().contains("id 5"), "{e}");
}

#[test]
fn malformed_text_files_fail_clearly() {
    let tmp = tempfile::tempdir().unwrap();
    let p = tmp.path().join("cameras.txt");
    let read = |text: &str| {
        std::fs::write(&p, text).unwrap();
        colmap::text::read_cameras(&p).unwrap_err().to_string()
    };
    let e = read("# c\n1 OPENCV_FISHEYE 10 10 1 2 3 4 5 6 7 8\n");
    assert!(
        e.contains("unsupported camera model OPENCV_FISHEYE") && e.contains("cameras.txt"),
        "{e}"
    );
    let e = read("1 PINHOLE 10 10 1 2 3\n");
    assert!(
        e.contains("cameras.txt:1") && e.contains("missing parameter 3"),
        "{e}"
    );
    let e = read("\n1 PINHOLE 10 ten 1 2 3 4\n");
    assert!(e.contains("cameras.txt:2") && e.contains("height"), "{e}");
    let e = read("1 SIMPLE_PINHOLE 10 10 1 2 3 4\n");
    assert!(e.contains("extra"), "{e}");

    let p = tmp.path().join("images.txt");
    std::fs::write(&p, "1 1 0 0 0 0 0 0 1 a.png\n1.0 2.0\n").unwrap();
    let e = colmap::text::read_images(&p).unwrap_err().to_string();
    assert!(e.contains("images.txt:2") && e.contains("triples"), "{e}");
    let p = tmp.path().join("points3D.txt");
    std::fs::write(&p, "1 0 0 0 1 2 3 0.5 4\n").unwrap();
    let e = colmap::text::read_points3d(&p).unwrap_err().to_string();
    assert!(e.contains("points3D.txt:1") && e.contains("odd"), "{e}");
}

#[test]
fn colmap_capture_opens_with_scaled_intrinsics_and_point_bounds() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().join("scene");
    let sparse = root.join("sparse/0");
    std::fs::create_dir_all(&sparse).unwrap();
    std::fs::create_dir_all(root.join("images_2")).unwrap();
    let mut m = model();
    m.cameras.truncate(3);
    m.images.truncate(2);
    // Image 0 uses camera 5, dropped above: the reader must say so.
    colmap::write_model(&sparse, &m, ModelFormat::Text).unwrap();
    let e = scenes::open(&root, &OpenOptions::default()).unwrap_err();
    assert!(e.to_string().contains("refers to camera 5"), "{e}");

    m.images[0].camera_id = 3;
    colmap::write_model(&sparse, &m, ModelFormat::Text).unwrap();
    for im in &m.images {
        let path = root.join("images_2").join(&im.name);
        scenes::images::write_png(&path, &common::pattern(40, 30, 0), BitDepth::Eight).unwrap();
    }
    let options = OpenOptions {
        resolution: Resolution::Downsample(2),
        llffhold: 0,
        ..OpenOptions::default()
    };
    let capture = scenes::open(&root, &options).unwrap();
    assert_eq!(capture.format, CaptureFormat::Colmap(ModelFormat::Text));
    assert_eq!(capture.len(), 2);
    assert_eq!(
        (capture.split.train.len(), capture.split.test.len()),
        (2, 0)
    );
    assert_eq!(capture.downsample, 2.0);
    let c = &capture.cameras[0];
    assert_eq!(c.name, "img000");
    assert_eq!(
        (c.width, c.height, c.fx, c.cx, c.cy),
        (40, 30, 45.0, 20.0, 15.0)
    );
    assert_eq!(c.distortion.unwrap().k1, 0.0125);
    assert!(
        capture
            .distortion_source
            .as_ref()
            .unwrap()
            .ends_with("cameras.txt")
    );
    assert_eq!(capture.points.len(), 40);
    assert!(matches!(capture.point_source, PointSource::Sparse(_)));
    assert_eq!(
        capture.points.colors[3],
        [3.0 / 255.0, 200.0 / 255.0, 252.0 / 255.0]
    );
    for (camera, b) in capture.cameras.iter().zip(&capture.bounds) {
        let depths: Vec<f64> = m
            .points
            .iter()
            .filter_map(|p| camera.project(p.xyz))
            .map(|p| p.depth)
            .collect();
        let (lo, hi) = depths
            .iter()
            .fold((f64::MAX, f64::MIN), |(l, h), &d| (l.min(d), h.max(d)));
        assert!(
            b.near >= lo && b.near < lo + 0.01 * (hi - lo),
            "near {} vs {lo}",
            b.near
        );
        assert!(
            b.far <= hi && b.far > hi - 0.01 * (hi - lo),
            "far {} vs {hi}",
            b.far
        );
    }
    let summary = capture.summary().to_string();
    assert!(
        summary.contains("COLMAP sparse model, text") && summary.contains("40x30"),
        "{summary}"
    );

    // A points file that is a folder is named, not replaced by random points.
    let points = sparse.join("points3D.txt");
    let kept = std::fs::read(&points).unwrap();
    std::fs::remove_file(&points).unwrap();
    std::fs::create_dir(&points).unwrap();
    let e = scenes::open(&root, &options).unwrap_err().to_string();
    assert!(e.contains("points3D.txt"), "{e}");
    std::fs::remove_dir(&points).unwrap();
    std::fs::write(&points, kept).unwrap();

    // A listed image that is missing is named.
    std::fs::remove_file(root.join("images_2/img001.png")).unwrap();
    let e = scenes::open(&root, &options).unwrap_err();
    assert!(
        matches!(e, SceneError::NotFound { .. }) && e.to_string().contains("img001.png"),
        "{e}"
    );
}

#[test]
fn repeated_ids_and_names_and_names_leaving_the_image_folder_are_refused_in_both_formats() {
    let tmp = tempfile::tempdir().unwrap();
    for format in [ModelFormat::Binary, ModelFormat::Text] {
        // Apart: a folder with both prefers the binary files.
        let dir = &tmp.path().join(format.extension());
        std::fs::create_dir_all(dir).unwrap();
        let err = |m: &ColmapModel| {
            colmap::write_model(dir, m, format).unwrap();
            colmap::read_model(dir).unwrap_err().to_string()
        };
        let mut m = model();
        m.cameras[1].id = m.cameras[0].id;
        let e = err(&m);
        assert!(e.contains("camera id 1 is used"), "{format:?}: {e}");
        let mut m = model();
        m.images[2].id = m.images[0].id;
        let e = err(&m);
        assert!(e.contains("image id 10 is used"), "{format:?}: {e}");
        let mut m = model();
        m.images[1].name = m.images[0].name.clone();
        let e = err(&m);
        assert!(
            e.contains(&format!("image name {:?} is used", m.images[0].name)),
            "{format:?}: {e}"
        );
        for name in ["../img000.png", "sub/../../img000.png", "/tmp/img000.png"] {
            let mut m = model();
            m.images[0].name = name.into();
            let e = err(&m);
            assert!(
                e.contains(name) && e.contains("only files inside the capture"),
                "{format:?}: {e}"
            );
        }
        // Where each repeat is: both lines of a text file, both records of a binary one.
        let mut m = model();
        m.images[1].name = m.images[0].name.clone();
        colmap::write_model(dir, &m, format).unwrap();
        let e = colmap::read_model(dir).unwrap_err().to_string();
        match format {
            ModelFormat::Text => assert!(e.contains("first on line"), "{e}"),
            ModelFormat::Binary => assert!(e.contains("records 0 and 1"), "{e}"),
        }
        // A name with two spaces (and one in a folder) is kept as written.
        let mut m = model();
        m.images[0].name = "a  b.png".into();
        m.images[1].name = "sub/c d.png".into();
        colmap::write_model(dir, &m, format).unwrap();
        let back = colmap::read_model(dir).unwrap();
        assert_eq!(back.images[0].name, "a  b.png", "{format:?}");
        assert_eq!(back.images[1].name, "sub/c d.png", "{format:?}");
    }
}
