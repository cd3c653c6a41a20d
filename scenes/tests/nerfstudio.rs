//! nerfstudio's transforms.json: the cameras of a capture written in nerfstudio's convention
//! (OpenGL axes, camera-to-world, shared intrinsics) read back as the same cameras, at full
//! and at reduced resolution; names that leave the capture and broken matrices refused.

mod common;

use std::path::Path;

use scenes::{BitDepth, CaptureFormat, OpenOptions, Resolution};
use serde_json::json;

/// Writes `dir` as ns-process-data would: `images/` (and `images_2/` at half size) and
/// `transforms.json` for `cameras`.
fn write_capture(dir: &Path, cameras: &[scenes::Camera], extra: serde_json::Value) {
    std::fs::create_dir_all(dir.join("images")).unwrap();
    std::fs::create_dir_all(dir.join("images_2")).unwrap();
    let mut frames = Vec::new();
    for (k, c) in cameras.iter().enumerate() {
        let name = format!("{}.png", c.name);
        scenes::images::write_png(
            &dir.join("images").join(&name),
            &common::pattern(c.width, c.height, k),
            BitDepth::Eight,
        )
        .unwrap();
        scenes::images::write_png(
            &dir.join("images_2").join(&name),
            &common::pattern(c.width / 2, c.height / 2, k),
            BitDepth::Eight,
        )
        .unwrap();
        // OpenCV camera-to-world with the camera's y and z axes flipped: OpenGL's.
        let c2w = c.camera_to_world();
        let r = c2w.rotation;
        let (x, y, z, t) = (r.x_axis, -r.y_axis, -r.z_axis, c2w.translation);
        frames.push(json!({
            "file_path": format!("images/{name}"),
            "transform_matrix": [
                [x.x, y.x, z.x, t.x],
                [x.y, y.y, z.y, t.y],
                [x.z, y.z, z.z, t.z],
                [0.0, 0.0, 0.0, 1.0],
            ],
        }));
    }
    let c = &cameras[0];
    let mut doc = json!({
        "camera_model": "OPENCV",
        "fl_x": c.fx, "fl_y": c.fy, "cx": c.cx, "cy": c.cy,
        "w": c.width, "h": c.height,
        "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0,
        "frames": frames,
    });
    if let (Some(d), Some(e)) = (doc.as_object_mut(), extra.as_object()) {
        for (k, v) in e {
            d.insert(k.clone(), v.clone());
        }
    }
    std::fs::write(dir.join("transforms.json"), doc.to_string()).unwrap();
}

fn open(dir: &Path, downsample: u32) -> scenes::Result<scenes::Capture> {
    scenes::open(
        dir,
        &OpenOptions {
            resolution: Resolution::Downsample(downsample),
            ..OpenOptions::default()
        },
    )
}

#[test]
fn a_capture_written_as_transforms_json_reads_back_as_the_same_cameras() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("ns");
    let (cameras, _) = common::arc_cameras(6, 80, 60, 3);
    write_capture(&dir, &cameras, json!({}));
    let capture = open(&dir, 1).unwrap();
    assert_eq!(capture.format, CaptureFormat::Nerfstudio);
    assert_eq!(capture.len(), cameras.len());
    for (a, b) in capture.cameras.iter().zip(&cameras) {
        assert_eq!(
            (a.name.as_str(), a.width, a.height),
            (b.name.as_str(), b.width, b.height)
        );
        assert_eq!((a.fx, a.fy, a.cx, a.cy), (b.fx, b.fy, b.cx, b.cy));
        let (p, q) = (a.world_to_camera.to_mat4(), b.world_to_camera.to_mat4());
        let worst = (p - q)
            .to_cols_array()
            .iter()
            .fold(0.0f64, |m, v| m.max(v.abs()));
        assert!(worst < 1e-9, "{}: poses differ by {worst}", a.name);
        assert!(a.distortion.is_none());
    }
    // Each camera sees the rig's centre in front of it, within its bounds.
    for (c, b) in capture.cameras.iter().zip(&capture.bounds) {
        assert!(b.near > 0.0 && b.far > b.near);
        let centre = capture
            .cameras
            .iter()
            .map(|c| c.camera_to_world().translation)
            .sum::<glam::DVec3>()
            / capture.len() as f64;
        let depth = c.project(centre).map(|p| p.depth).unwrap_or(-1.0);
        assert!(depth > b.near && depth < b.far, "{}: depth {depth}", c.name);
    }
    // images_2/: the same cameras at half the size.
    let half = open(&dir, 2).unwrap();
    for (a, b) in half.cameras.iter().zip(&cameras) {
        assert_eq!((a.width, a.height), (b.width / 2, b.height / 2));
        assert!((a.fx - b.fx / 2.0).abs() < 1e-12 && (a.cy - b.cy / 2.0).abs() < 1e-12);
    }
}

#[test]
fn transforms_json_that_lies_is_refused_naming_the_frame() {
    let tmp = tempfile::tempdir().unwrap();
    let (cameras, _) = common::arc_cameras(3, 40, 30, 5);
    let case = |name: &str, edit: &dyn Fn(&mut serde_json::Value)| {
        let dir = tmp.path().join(name);
        write_capture(&dir, &cameras, json!({}));
        let path = dir.join("transforms.json");
        let mut doc: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
        edit(&mut doc);
        std::fs::write(&path, doc.to_string()).unwrap();
        open(&dir, 1)
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default()
    };
    let e = case("outside", &|d| {
        d["frames"][1]["file_path"] = "../x.png".into()
    });
    assert!(
        e.contains("frame 1") && e.contains("leaves the capture"),
        "{e}"
    );
    let e = case("missing", &|d| {
        d["frames"][0]["file_path"] = "images/none.png".into()
    });
    assert!(e.contains("none.png"), "{e}");
    let e = case("mirror", &|d| {
        d["frames"][2]["transform_matrix"][0][0] =
            json!(-d["frames"][2]["transform_matrix"][0][0].as_f64().unwrap());
        d["frames"][2]["transform_matrix"][1][0] =
            json!(-d["frames"][2]["transform_matrix"][1][0].as_f64().unwrap());
        d["frames"][2]["transform_matrix"][2][0] =
            json!(-d["frames"][2]["transform_matrix"][2][0].as_f64().unwrap());
    });
    assert!(e.contains("frame 2") && e.contains("mirrored"), "{e}");
    let e = case("nan", &|d| {
        d["frames"][0]["transform_matrix"][1][3] = json!("nan")
    });
    assert!(e.contains("frame 0") && e.contains("finite"), "{e}");
    let e = case("fisheye", &|d| d["camera_model"] = "OPENCV_FISHEYE".into());
    assert!(e.contains("OPENCV_FISHEYE"), "{e}");
    let e = case("no focal", &|d| {
        d.as_object_mut().unwrap().remove("fl_x");
    });
    assert!(e.contains("fl_x"), "{e}");
    // A number written as a string is named as such, not reported missing.
    let e = case("string width", &|d| d["w"] = "64".into());
    assert!(e.contains("w is \"64\", not a number"), "{e}");
    // w and h of another aspect than the photos': refused, not stretched.
    let e = case("aspect", &|d| {
        d["w"] = json!(d["w"].as_f64().unwrap() * 1.25)
    });
    assert!(e.contains("aspect differs") && e.contains("frame 0"), "{e}");
    // Two frames of one photo: both frames and the file are named.
    let e = case("same photo", &|d| {
        d["frames"][2]["file_path"] = d["frames"][0]["file_path"].clone()
    });
    assert!(
        e.contains("transforms.json") && e.contains("frame 2") && e.contains("photo of frame 0"),
        "{e}"
    );
    // An r⁸ radial term, and a model that is not a name: refused, not ignored.
    let e = case("k4", &|d| d["k4"] = json!(0.01));
    assert!(e.contains("k4") && e.contains("not modelled"), "{e}");
    // Coefficients in bounds that fold the image before its corners: refused, not undistorted
    // into mirrored content.
    let e = case("folds", &|d| d["k1"] = json!(-4.0));
    assert!(
        e.contains("frame 0") && e.contains("folds the image"),
        "{e}"
    );
    let e = case("model number", &|d| d["camera_model"] = json!(5));
    assert!(e.contains("camera_model is 5"), "{e}");
    // Distortion is kept, for reporting, as COLMAP's is; k3 is the r⁶ radial term.
    let dir = tmp.path().join("distorted");
    write_capture(&dir, &cameras, json!({"k1": 0.02, "k3": 0.003}));
    let c = open(&dir, 1).unwrap();
    assert_eq!(c.cameras[0].distortion.unwrap().k1, 0.02);
    assert_eq!(
        c.cameras[0].distortion.unwrap().rational,
        [0.003, 0.0, 0.0, 0.0]
    );
    assert!(c.distortion_source.unwrap().ends_with("transforms.json"));
}

/// A point cloud as `ns-process-data` writes it (binary, float positions, 8-bit colours), or
/// in ASCII with double positions; `header_extra` goes before `end_header`.
fn cloud_ply(points: &[([f64; 3], [u8; 3])], ascii: bool, header_extra: &str) -> Vec<u8> {
    let (format, real) = if ascii {
        ("ascii", "double")
    } else {
        ("binary_little_endian", "float")
    };
    let mut out = format!(
        "ply\nformat {format} 1.0\nelement vertex {}\nproperty {real} x\nproperty {real} y\nproperty {real} z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n{header_extra}end_header\n",
        points.len()
    )
    .into_bytes();
    for (p, c) in points {
        if ascii {
            out.extend(format!("{} {} {} {} {} {}\n", p[0], p[1], p[2], c[0], c[1], c[2]).bytes());
        } else {
            for v in p {
                out.extend((*v as f32).to_le_bytes());
            }
            out.extend(c);
        }
    }
    out
}

/// `ply_file_path` names the initial points: read in binary and ASCII as written, reported
/// as their file, and kept by the aberrated copy (which is LLFF) in COLMAP's points file.
#[test]
fn ply_file_path_gives_the_initial_points_and_the_aberrated_copy_keeps_them() {
    let tmp = tempfile::tempdir().unwrap();
    let (cameras, _) = common::arc_cameras(4, 40, 30, 7);
    let points: Vec<([f64; 3], [u8; 3])> = (0..50)
        .map(|i| {
            let t = i as f64 * 0.37;
            (
                [t.sin() * 0.5, t.cos() * 0.25, 0.1 * t - 1.0],
                [(i * 5) as u8, 255 - i as u8, 128],
            )
        })
        .collect();
    for ascii in [false, true] {
        let dir = tmp.path().join(if ascii { "ascii" } else { "binary" });
        write_capture(&dir, &cameras, json!({"ply_file_path": "sparse_pc.ply"}));
        std::fs::write(dir.join("sparse_pc.ply"), cloud_ply(&points, ascii, "")).unwrap();
        let capture = open(&dir, 1).unwrap();
        assert!(
            matches!(&capture.point_source, scenes::PointSource::Sparse(p) if p.ends_with("sparse_pc.ply"))
        );
        assert_eq!(capture.points.len(), points.len());
        for ((xyz, rgb), (p, c)) in points
            .iter()
            .zip(capture.points.positions.iter().zip(&capture.points.colors))
        {
            let tol = if ascii { 1e-12 } else { 1e-6 };
            assert!((glam::DVec3::from_array(*xyz) - *p).abs().max_element() < tol);
            for k in 0..3 {
                assert!((rgb[k] as f32 / 255.0 - c[k]).abs() < 1e-6);
            }
        }
        if ascii {
            continue;
        }
        let psf = tmp.path().join("psf.npy");
        let (grid, _) =
            aberration::optics::simulate_grid(&aberration::optics::SimConfig::small(9), &|_, _| {})
                .unwrap();
        grid.save_npy(&psf).unwrap();
        let abr = tmp.path().join("aberrated");
        scenes::make_aberrated(
            &capture,
            &psf,
            &abr,
            &scenes::AberrateOptions::default(),
            &|| {},
        )
        .unwrap();
        let copy = open(&abr, 1).unwrap();
        assert!(matches!(copy.point_source, scenes::PointSource::Sparse(_)));
        assert_eq!(copy.points.positions, capture.points.positions);
        assert_eq!(copy.points.colors, capture.points.colors);
    }
}

/// A `ply_file_path` that leaves the capture, is missing, or holds a cloud that lies is
/// refused naming the file and the problem.
#[test]
fn a_bad_ply_file_path_is_refused_naming_the_file() {
    let tmp = tempfile::tempdir().unwrap();
    let (cameras, _) = common::arc_cameras(3, 40, 30, 5);
    let good = [
        ([0.0, 0.0, -1.0], [1u8, 2, 3]),
        ([0.5, 0.5, -2.0], [4, 5, 6]),
    ];
    let case = |name: &str, file: &str, bytes: Vec<u8>| {
        let dir = tmp.path().join(name);
        write_capture(&dir, &cameras, json!({"ply_file_path": file}));
        if !bytes.is_empty() {
            std::fs::write(dir.join("points.ply"), bytes).unwrap();
        }
        open(&dir, 1)
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default()
    };
    let e = case("outside", "../points.ply", Vec::new());
    assert!(
        e.contains("ply_file_path") && e.contains("leaves the capture"),
        "{e}"
    );
    let e = case("missing", "points.ply", Vec::new());
    assert!(
        e.contains("points.ply") && e.contains("ply_file_path"),
        "{e}"
    );
    let mut cut = cloud_ply(&good, false, "");
    cut.truncate(cut.len() - 4);
    let e = case("cut", "points.ply", cut);
    assert!(e.contains("points.ply") && e.contains("truncated"), "{e}");
    let lying = String::from_utf8(cloud_ply(&good, true, ""))
        .unwrap()
        .replace("element vertex 2", "element vertex 2000000000");
    let e = case("count", "points.ply", lying.into_bytes());
    assert!(e.contains("points.ply") && e.contains("2000000000"), "{e}");
    let lying = String::from_utf8(cloud_ply(&good, true, ""))
        .unwrap()
        .replace("element vertex 2", "element vertex 2000");
    let e = case("more", "points.ply", lying.into_bytes());
    assert!(e.contains("points.ply") && e.contains("truncated"), "{e}");
    let e = case(
        "nan",
        "points.ply",
        cloud_ply(&[good[0], ([0.0, f64::NAN, 1.0], [0, 0, 0])], false, ""),
    );
    assert!(
        e.contains("points.ply") && e.contains("point 1") && e.contains("finite"),
        "{e}"
    );
    let partial = String::from_utf8(cloud_ply(&good, true, ""))
        .unwrap()
        .replace("property uchar blue\n", "")
        .replace(" 3\n", "\n")
        .replace(" 6\n", "\n");
    let e = case("partial colour", "points.ply", partial.into_bytes());
    assert!(e.contains("red, green and blue"), "{e}");
    let twice = String::from_utf8(cloud_ply(&good, true, "property uchar red\n")).unwrap();
    let e = case("twice", "points.ply", twice.into_bytes());
    assert!(e.contains("twice"), "{e}");
    let e = case("not ply", "points.ply", b"solid mesh\n".to_vec());
    assert!(e.contains("points.ply") && e.contains("not a PLY"), "{e}");
    let dir = tmp.path().join("number");
    write_capture(&dir, &cameras, json!({"ply_file_path": 3}));
    let e = open(&dir, 1).err().unwrap().to_string();
    assert!(e.contains("ply_file_path is 3"), "{e}");
}

/// nerfstudio's `camera_path.json`: each keyframe's camera-to-world (row-major, OpenGL axes)
/// reads back as the camera it was written from, its `fov` as the vertical field; broken
/// keyframes are named.
#[test]
fn a_camera_path_reads_back_as_its_cameras() {
    let tmp = tempfile::tempdir().unwrap();
    let (cameras, _) = common::arc_cameras(4, 80, 60, 9);
    let keys: Vec<serde_json::Value> = cameras
        .iter()
        .map(|c| {
            let m = c.camera_to_world();
            let r = m.rotation;
            let (x, y, z, t) = (r.x_axis, -r.y_axis, -r.z_axis, m.translation);
            json!({"camera_to_world": [x.x, y.x, z.x, t.x, x.y, y.y, z.y, t.y, x.z, y.z, z.z, t.z, 0.0, 0.0, 0.0, 1.0], "fov": 50.0})
        })
        .collect();
    let path = tmp.path().join("camera_path.json");
    let write = |doc: serde_json::Value| std::fs::write(&path, doc.to_string()).unwrap();
    write(json!({"render_width": 80, "render_height": 60, "fps": 24, "camera_path": keys}));
    let read = scenes::nerfstudio::read_camera_path(&path).unwrap();
    assert_eq!(read.fps, 24.0);
    assert_eq!(read.cameras.len(), 4);
    let f = 30.0 / 25f64.to_radians().tan();
    for (a, b) in read.cameras.iter().zip(&cameras) {
        assert_eq!((a.width, a.height), (80, 60));
        assert!((a.fy - f).abs() < 1e-9 && (a.fx - f).abs() < 1e-9);
        let (p, q) = (a.world_to_camera.to_mat4(), b.world_to_camera.to_mat4());
        let worst = (p - q)
            .to_cols_array()
            .iter()
            .fold(0.0f64, |m, v| m.max(v.abs()));
        assert!(worst < 1e-9, "poses differ by {worst}");
    }
    let refused = |doc: serde_json::Value| {
        write(doc);
        scenes::nerfstudio::read_camera_path(&path)
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default()
    };
    let mut bad_fov = keys.clone();
    bad_fov[1]["fov"] = json!(0.0);
    let e = refused(json!({"render_width": 80, "render_height": 60, "camera_path": bad_fov}));
    assert!(e.contains("camera_path[1]") && e.contains("fov"), "{e}");
    let mut mirrored = keys.clone();
    mirrored[2]["camera_to_world"][0] = json!(-mirrored[2]["camera_to_world"][0].as_f64().unwrap());
    mirrored[2]["camera_to_world"][4] = json!(-mirrored[2]["camera_to_world"][4].as_f64().unwrap());
    mirrored[2]["camera_to_world"][8] = json!(-mirrored[2]["camera_to_world"][8].as_f64().unwrap());
    let e = refused(json!({"render_width": 80, "render_height": 60, "camera_path": mirrored}));
    assert!(
        e.contains("camera_path[2]") && e.contains("mirrored"),
        "{e}"
    );
    let e = refused(json!({"render_width": 4, "render_height": 60, "camera_path": keys}));
    assert!(e.contains("render_width"), "{e}");
    // A projective last row, and cameras the renderer does not draw: refused, not drawn as
    // perspective frames.
    let mut projective = keys.clone();
    projective[0]["camera_to_world"][14] = json!(0.5);
    let e = refused(json!({"render_width": 80, "render_height": 60, "camera_path": projective}));
    assert!(
        e.contains("camera_path[0]") && e.contains("last row"),
        "{e}"
    );
    for kind in ["fisheye", "equirectangular"] {
        let e = refused(
            json!({"render_width": 80, "render_height": 60, "camera_type": kind, "camera_path": keys}),
        );
        assert!(e.contains("camera_type") && e.contains(kind), "{e}");
    }
    write(
        json!({"render_width": 80, "render_height": 60, "camera_type": "perspective", "camera_path": keys}),
    );
    assert!(scenes::nerfstudio::read_camera_path(&path).is_ok());
    let e = refused(json!({"render_width": 80, "render_height": 60, "camera_path": []}));
    assert!(
        e.contains("camera_path.json") && e.contains("no camera_path"),
        "{e}"
    );
}

#[test]
fn a_frames_mask_path_is_its_mask_at_every_downsample() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("ns");
    let (cameras, _) = common::arc_cameras(3, 80, 60, 3);
    write_capture(&dir, &cameras, json!({}));
    // Full-size masks/ named by each frame (black left quarter), as ns-process-data writes.
    let path = dir.join("transforms.json");
    let mut doc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    std::fs::create_dir_all(dir.join("masks")).unwrap();
    for frame in doc["frames"].as_array_mut().unwrap() {
        let name = Path::new(frame["file_path"].as_str().unwrap())
            .file_name()
            .unwrap()
            .to_str()
            .unwrap()
            .to_string();
        image::GrayImage::from_fn(80, 60, |x, _| image::Luma([if x < 20 { 0 } else { 255 }]))
            .save(dir.join("masks").join(&name))
            .unwrap();
        frame["mask_path"] = json!(format!("masks/{name}"));
    }
    std::fs::write(&path, doc.to_string()).unwrap();
    let full = open(&dir, 1).unwrap();
    assert!(full.summary().to_string().contains("mask_path"));
    let m = full.load_mask(0).unwrap().unwrap();
    assert_eq!((m[19], m[20]), (0.0, 1.0));
    // At half size: shrunk from masks/ (left 10 of 40 black) ...
    let half = open(&dir, 2).unwrap();
    let m = half.load_mask(0).unwrap().unwrap();
    assert_eq!(m.len(), 40 * 30);
    assert_eq!((m[9], m[10]), (0.0, 1.0));
    // ... or read from masks_2/ where that copy exists (left 5 black here, to tell them apart).
    std::fs::create_dir_all(dir.join("masks_2")).unwrap();
    for e in std::fs::read_dir(dir.join("masks")).unwrap() {
        let name = e.unwrap().file_name();
        image::GrayImage::from_fn(40, 30, |x, _| image::Luma([if x < 5 { 0 } else { 255 }]))
            .save(dir.join("masks_2").join(name))
            .unwrap();
    }
    let m = open(&dir, 2).unwrap().load_mask(0).unwrap().unwrap();
    assert_eq!((m[4], m[5]), (0.0, 1.0));
    // A mask_path that leaves the capture, names nothing, or is not a string: refused naming
    // the frame.
    for (bad, says) in [
        (json!("../outside.png"), "leaves the capture"),
        (json!("masks/none.png"), "none.png"),
        (json!(7), "not a file name"),
    ] {
        let mut d = doc.clone();
        d["frames"][1]["mask_path"] = bad;
        std::fs::write(&path, d.to_string()).unwrap();
        let e = open(&dir, 1).map(|_| ()).unwrap_err().to_string();
        assert!(e.contains(says), "{e}");
    }
}

/// The aberrated copy of a distorted capture without masks of its own carries the border
/// undistortion leaves as masks, and its record says that is all they are (not an object's
/// outline); a capture with masks of its own says otherwise.
#[test]
fn a_copys_record_says_when_its_masks_are_only_the_undistortion_border() {
    let tmp = tempfile::tempdir().unwrap();
    let (cameras, _) = common::arc_cameras(4, 40, 30, 7);
    let psf = tmp.path().join("psf.npy");
    let (grid, _) =
        aberration::optics::simulate_grid(&aberration::optics::SimConfig::small(9), &|_, _| {})
            .unwrap();
    grid.save_npy(&psf).unwrap();
    for own_masks in [false, true] {
        let dir = tmp.path().join(format!("src_{own_masks}"));
        write_capture(&dir, &cameras, json!({"k1": 0.2}));
        if own_masks {
            std::fs::create_dir(dir.join("masks")).unwrap();
            for c in &cameras {
                let white = scenes::Photo {
                    width: c.width,
                    height: c.height,
                    data: vec![1.0; (c.width * c.height * 3) as usize],
                };
                scenes::images::write_png(
                    &dir.join("masks").join(format!("{}.png", c.name)),
                    &white,
                    BitDepth::Eight,
                )
                .unwrap();
            }
        }
        let capture = open(&dir, 1).unwrap();
        assert!(capture.undistorted());
        assert_eq!(capture.has_own_masks(), own_masks);
        let abr = tmp.path().join(format!("abr_{own_masks}"));
        scenes::make_aberrated(
            &capture,
            &psf,
            &abr,
            &scenes::AberrateOptions::default(),
            &|| {},
        )
        .unwrap();
        let record = scenes::AberrationRecord::read(&abr).unwrap().unwrap();
        assert_eq!(record.composited_over, Some([0.0; 3]));
        assert_eq!(record.masks_from_undistortion, !own_masks);
        assert!(
            open(&abr, 1).unwrap().has_own_masks(),
            "the copy carries its masks"
        );
    }
}

/// Frames whose photos are in another folder than `images/`, with no `images_N/` copies: a
/// downsample reads them as named and shrinks them at load, as for `images/`.
#[test]
fn frames_in_another_folder_are_shrunk_at_a_downsample() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("ns");
    let (cameras, _) = common::arc_cameras(3, 80, 60, 3);
    write_capture(&dir, &cameras, json!({}));
    std::fs::remove_dir_all(dir.join("images_2")).unwrap();
    std::fs::rename(dir.join("images"), dir.join("frames")).unwrap();
    let path = dir.join("transforms.json");
    let text = std::fs::read_to_string(&path)
        .unwrap()
        .replace("images/", "frames/");
    std::fs::write(&path, text).unwrap();
    let c = open(&dir, 2).unwrap();
    assert_eq!(c.len(), 3);
    assert_eq!((c.cameras[0].width, c.cameras[0].height), (40, 30));
    let photo = c.load_image(0).unwrap();
    assert_eq!((photo.width, photo.height), (40, 30));
}
