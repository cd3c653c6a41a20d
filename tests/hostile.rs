//! Hostile input, generated here: truncations at many offsets, lying counts and shapes, wrong
//! dtypes and property types, NaN/Inf/huge/zero/negative values and outputs that alias inputs,
//! over every subcommand that reads a file and every file format. Each case runs the binary
//! and asserts: a non-zero exit that is not a panic (code 101, "panicked"), a message naming
//! the bad file or flag, and a working folder whose every file and folder (inputs included,
//! compared by checksum) is exactly as before: no output, no temporary file, no change.

mod common;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use common::cli::{ok as run_ok, procedural};

/// Every file (with the XXH3 of its bytes) and folder under `dir`.
fn snapshot(dir: &Path) -> BTreeMap<PathBuf, Option<u64>> {
    let mut out = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                out.insert(p.clone(), None);
                stack.push(p);
            } else {
                let bytes = std::fs::read(&p).unwrap();
                out.insert(p, Some(base::hash::xxh3(&bytes)));
            }
        }
    }
    out
}

fn s(p: &Path) -> String {
    p.to_str().unwrap().to_string()
}

/// Runs the cases against one working folder, counting them.
struct Suite {
    root: PathBuf,
    cases: usize,
    failures: Vec<String>,
}

impl Suite {
    fn new(root: &Path) -> Self {
        Suite {
            root: root.to_path_buf(),
            cases: 0,
            failures: Vec::new(),
        }
    }

    /// One hostile command line: it must fail cleanly, name one of `names`, and leave the
    /// working folder exactly as it was.
    fn case(&mut self, label: &str, args: &[String], names: &[&str]) {
        self.cases += 1;
        let before = snapshot(&self.root);
        let out = common::cli::metasplat().args(args).output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr).to_string();
        let after = snapshot(&self.root);
        if std::env::var_os("HOSTILE_VERBOSE").is_some() {
            eprintln!("{label}: {}", err.trim().replace('\n', " | "));
        }
        let mut problems = Vec::new();
        if out.status.success() {
            problems.push("exited 0".to_string());
        }
        if out.status.code() == Some(101) || err.contains("panicked") {
            problems.push("panicked".to_string());
        }
        if out.status.code().is_none() {
            problems.push(format!("killed by a signal ({:?})", out.status));
        }
        if !names.iter().any(|n| err.contains(n)) {
            problems.push(format!("the message names none of {names:?}"));
        }
        if before != after {
            let changed: Vec<String> = before
                .keys()
                .chain(after.keys())
                .filter(|k| before.get(*k) != after.get(*k))
                .map(|k| {
                    k.strip_prefix(&self.root)
                        .unwrap_or(k)
                        .display()
                        .to_string()
                })
                .collect();
            problems.push(format!("the folder changed: {changed:?}"));
        }
        if !problems.is_empty() {
            self.failures.push(format!(
                "{label}: metasplat {}\n  {}\n  stderr: {}",
                args.join(" "),
                problems.join("; "),
                err.trim()
            ));
        }
    }

    /// Writes `bytes` to `path` for the duration of `f` (the snapshot before each case
    /// includes it), then removes it.
    fn with_file(&mut self, path: &Path, bytes: &[u8], f: impl FnOnce(&mut Self)) {
        std::fs::write(path, bytes).unwrap();
        f(self);
        std::fs::remove_file(path).unwrap();
    }

    fn finish(self, what: &str) -> usize {
        assert!(
            self.failures.is_empty(),
            "{} of {} {what} cases failed:\n{}",
            self.failures.len(),
            self.cases,
            self.failures.join("\n")
        );
        eprintln!("{} hostile {what} cases refused cleanly", self.cases);
        self.cases
    }
}

fn args(v: &[&str]) -> Vec<String> {
    v.iter().map(|a| a.to_string()).collect()
}

/// A version 1 `.npy` file with the given header dict (padded as numpy pads it) and data.
fn npy(dict: &str, data: &[u8]) -> Vec<u8> {
    let mut header = dict.to_string();
    while !(10 + header.len() + 1).is_multiple_of(64) {
        header.push(' ');
    }
    header.push('\n');
    let mut out = b"\x93NUMPY\x01\x00".to_vec();
    out.extend_from_slice(&(header.len() as u16).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    out.extend_from_slice(data);
    out
}

fn f32s(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

fn f64s(v: &[f64]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

/// Truncation points spread over a file of `len` bytes, the first and last included.
fn cuts(len: usize, n: usize) -> Vec<usize> {
    let mut c: Vec<usize> = (0..n).map(|i| i * len / n).collect();
    c.push(len - 1);
    c.dedup();
    c
}

/// A 3×3 grid of 5×5 PSFs, file layout `(G·G, K, K, 3)`, every value positive.
fn psf_values() -> Vec<f32> {
    (0..9 * 25 * 3).map(|i| 1.0 + (i % 7) as f32).collect()
}

fn psf_dict(shape: &str) -> String {
    format!("{{'descr': '<f4', 'fortran_order': False, 'shape': {shape}, }}")
}

/// A tiny LLFF capture made by the binary: 5 views of 32×24 with `sparse/0/points3D.txt`.
fn llff_scene(dir: &Path) -> PathBuf {
    let scene = dir.join("llff");
    procedural(&scene, 32, 24, 5);
    scene
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let p = e.unwrap().path();
        let q = to.join(p.file_name().unwrap());
        if p.is_dir() {
            copy_dir(&p, &q);
        } else {
            std::fs::copy(&p, &q).unwrap();
        }
    }
}

#[test]
fn hostile_psf_files_and_photos() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let photo = d.join("photo.png");
    image::RgbImage::from_fn(24, 16, |x, y| {
        image::Rgb([(x * 10) as u8, (y * 15) as u8, 90])
    })
    .save(&photo)
    .unwrap();
    let scene = llff_scene(d);
    let good_psf = d.join("psf.npy");
    let values = psf_values();
    std::fs::write(&good_psf, npy(&psf_dict("(9, 5, 5, 3)"), &f32s(&values))).unwrap();
    let out_png = d.join("out.png");
    let bad = d.join("bad.npy");
    let good = std::fs::read(&good_psf).unwrap();

    let mut variants: Vec<(String, Vec<u8>)> = vec![("empty".into(), vec![])];
    for cut in cuts(good.len(), 9) {
        variants.push((format!("cut at {cut}"), good[..cut].to_vec()));
    }
    let data = f32s(&values);
    let with = |f: &dyn Fn(&mut Vec<f32>)| {
        let mut v = values.clone();
        f(&mut v);
        f32s(&v)
    };
    let shaped = |shape: &str, data: &[u8]| npy(&psf_dict(shape), data);
    variants.extend([
        (
            "u64::MAX PSFs".into(),
            shaped("(18446744073709551615, 5, 5, 3)", &data),
        ),
        (
            "K*K overflows".into(),
            shaped("(1, 4294967296, 4294967296, 3)", &data),
        ),
        (
            "product overflows".into(),
            shaped("(4294967296, 4294967296, 4294967296, 3)", &data),
        ),
        (
            "100 GB claimed".into(),
            shaped("(100, 10000, 10000, 3)", &data),
        ),
        (
            "16 PSFs claimed, 9 held".into(),
            shaped("(16, 5, 5, 3)", &data),
        ),
        (
            "4 PSFs claimed, 9 held".into(),
            shaped("(4, 5, 5, 3)", &data),
        ),
        (
            "trailing bytes".into(),
            [good.clone(), vec![0; 12]].concat(),
        ),
        (
            "8 PSFs, not a square grid".into(),
            shaped("(8, 5, 5, 3)", &data[..8 * 75 * 4]),
        ),
        ("non-square PSFs".into(), shaped("(9, 5, 3, 5)", &data)),
        (
            "4 channels".into(),
            shaped("(9, 5, 5, 4)", &f32s(&[1.0; 9 * 25 * 4])),
        ),
        ("zero-size PSFs".into(), shaped("(9, 0, 0, 3)", &[])),
        ("1-D".into(), shaped("(675,)", &data)),
        ("scalar".into(), shaped("()", &data[..4])),
        (
            "int32".into(),
            npy(
                "{'descr': '<i4', 'fortran_order': False, 'shape': (9, 5, 5, 3), }",
                &data,
            ),
        ),
        (
            "float16".into(),
            npy(
                "{'descr': '<f2', 'fortran_order': False, 'shape': (9, 5, 5, 3), }",
                &data[..1350],
            ),
        ),
        (
            "uint8".into(),
            npy(
                "{'descr': '|u1', 'fortran_order': False, 'shape': (9, 5, 5, 3), }",
                &data[..675],
            ),
        ),
        (
            "object".into(),
            npy(
                "{'descr': '|O', 'fortran_order': False, 'shape': (9, 5, 5, 3), }",
                &data,
            ),
        ),
        (
            "Fortran order".into(),
            npy(
                "{'descr': '<f4', 'fortran_order': True, 'shape': (9, 5, 5, 3), }",
                &data,
            ),
        ),
        ("negative shape".into(), shaped("(-9, 5, 5, 3)", &data)),
        (
            "broken dict".into(),
            npy("{'descr': '<f4', 'shape': (9, 5", &data),
        ),
        ("not a .npy".into(), std::fs::read(&photo).unwrap()),
        ("version 9".into(), {
            let mut b = good.clone();
            b[6] = 9;
            b
        }),
        ("header length past the end".into(), {
            let mut b = good.clone();
            b[8] = 0xff;
            b[9] = 0xff;
            b
        }),
        (
            "NaN".into(),
            shaped("(9, 5, 5, 3)", &with(&|v| v[100] = f32::NAN)),
        ),
        (
            "+Inf".into(),
            shaped("(9, 5, 5, 3)", &with(&|v| v[7] = f32::INFINITY)),
        ),
        (
            "all zero".into(),
            shaped("(9, 5, 5, 3)", &f32s(&[0.0; 675])),
        ),
        (
            "negative sum".into(),
            shaped(
                "(9, 5, 5, 3)",
                &with(&|v| v.iter_mut().for_each(|x| *x = -*x)),
            ),
        ),
        (
            "large negative lobe".into(),
            shaped("(9, 5, 5, 3)", &with(&|v| v[3] = -40.0)),
        ),
    ]);
    let mut suite = Suite::new(d);
    let (b, o, ph) = (s(&bad), s(&out_png), s(&photo));
    for (label, bytes) in &variants {
        suite.with_file(&bad, bytes, |suite| {
            suite.case(
                label,
                &args(&["psf", "show", &b, "--out", &o]),
                &["bad.npy"],
            );
            suite.case(
                label,
                &args(&["aberrate", "--psf", &b, "--in", &ph, "--out", &o]),
                &["bad.npy"],
            );
        });
    }
    // The other readers of a PSF grid, on a few of the variants.
    for (label, bytes) in variants.iter().step_by(6) {
        suite.with_file(&bad, bytes, |suite| {
            suite.case(
                label,
                &args(&["deconvolve", "--psf", &b, "--in", &ph, "--out", &o]),
                &["bad.npy"],
            );
            suite.case(
                label,
                &args(&[
                    "scene",
                    "aberrate",
                    "--scene",
                    &s(&scene),
                    "--psf",
                    &b,
                    "--out",
                    &s(&d.join("abr")),
                    "--downsample",
                    "1",
                ]),
                &["bad.npy"],
            );
        });
    }
    // Photos: empty, truncated, not an image.
    let png = std::fs::read(&photo).unwrap();
    let bad_png = d.join("bad.png");
    let gp = s(&good_psf);
    for (label, bytes) in [
        ("empty photo", vec![]),
        ("truncated photo", png[..png.len() / 2].to_vec()),
        ("photo header only", png[..40].to_vec()),
        ("text as photo", b"hello".to_vec()),
        ("photo claiming 60000x60000 px", png_claiming(60000, 60000)),
        // Within every side limit, but gigabytes once decoded.
        ("photo claiming 13000x13000 px", png_claiming(13000, 13000)),
        ("photo claiming 12000x9000 px", png_claiming(12000, 9000)),
    ] {
        suite.with_file(&bad_png, &bytes, |suite| {
            for command in ["aberrate", "deconvolve"] {
                suite.case(
                    &format!("{command}: {label}"),
                    &args(&[command, "--psf", &gp, "--in", &s(&bad_png), "--out", &o]),
                    &["bad.png"],
                );
            }
        });
    }
    // Outputs that alias inputs.
    suite.case(
        "alias",
        &args(&["psf", "show", &gp, "--out", &gp]),
        &["--out"],
    );
    suite.case(
        "alias",
        &args(&["aberrate", "--psf", &gp, "--in", &ph, "--out", &ph]),
        &["--out"],
    );
    suite.case(
        "alias",
        &args(&["deconvolve", "--psf", &gp, "--in", &ph, "--out", &gp]),
        &["--out"],
    );
    suite.finish("PSF and photo");
}

/// The LLFF and COLMAP captures a scene command reads; each case damages one file of a copy.
#[test]
fn hostile_captures() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let llff = llff_scene(d);
    let capture = scenes::open(
        &llff,
        &scenes::OpenOptions {
            resolution: scenes::Resolution::Downsample(1),
            ..Default::default()
        },
    )
    .unwrap();
    // The same capture as a COLMAP model (binary and text): one SIMPLE_RADIAL camera.
    let cam = &capture.cameras[0];
    let model = scenes::colmap::ColmapModel {
        cameras: vec![scenes::colmap::ColmapCamera {
            id: 1,
            model: scenes::CameraModel::SimpleRadial,
            width: cam.width as u64,
            height: cam.height as u64,
            params: vec![cam.fx, cam.cx, cam.cy, 0.0],
        }],
        images: capture
            .cameras
            .iter()
            .enumerate()
            .map(|(i, c)| {
                scenes::colmap::ColmapImage::from_world_to_camera(
                    i as u32 + 1,
                    1,
                    &format!("{}.png", c.name),
                    &c.world_to_camera,
                )
            })
            .collect(),
        points: capture
            .points
            .positions
            .iter()
            .enumerate()
            .map(|(i, p)| scenes::colmap::ColmapPoint {
                id: i as u64 + 1,
                xyz: *p,
                rgb: [100, 120, 140],
                error: 0.5,
                track: vec![],
            })
            .collect(),
    };
    let colmap_bin = d.join("colmap_bin");
    let colmap_txt = d.join("colmap_txt");
    for (dir, format) in [
        (&colmap_bin, scenes::colmap::ModelFormat::Binary),
        (&colmap_txt, scenes::colmap::ModelFormat::Text),
    ] {
        copy_dir(&llff.join("images"), &dir.join("images"));
        std::fs::create_dir_all(dir.join("sparse/0")).unwrap();
        scenes::colmap::write_model(&dir.join("sparse/0"), &model, format).unwrap();
    }
    let out = d.join("out");
    let psf = d.join("psf.npy");
    std::fs::write(&psf, npy(&psf_dict("(9, 5, 5, 3)"), &f32s(&psf_values()))).unwrap();
    let commands = |scene: &Path| -> Vec<Vec<String>> {
        vec![
            args(&["scene", "info", &s(scene), "--downsample", "1"]),
            args(&[
                "experiment",
                "llff",
                "--scene",
                &s(scene),
                "--out",
                &s(&out),
                "--psf",
                &s(&psf),
                "--iters",
                "3",
                "--downsample",
                "1",
                "--device",
                "cpu",
            ]),
            args(&[
                "train",
                "--scene",
                &s(scene),
                "--out",
                &s(&out),
                "--mode",
                "plain",
                "--downsample",
                "1",
                "--iters",
                "3",
                "--device",
                "cpu",
            ]),
        ]
    };
    for scene in [&llff, &colmap_bin, &colmap_txt] {
        for c in commands(scene) {
            run_ok(&c);
            std::fs::remove_dir_all(&out).ok();
        }
    }

    let mut suite = Suite::new(d);
    let work = d.join("work");
    // Runs every command on a copy of `scene` with `file` replaced by `bytes`.
    let damage = |suite: &mut Suite, scene: &Path, file: &str, label: &str, bytes: &[u8]| {
        copy_dir(scene, &work);
        std::fs::write(work.join(file), bytes).unwrap();
        let name = Path::new(file).file_name().unwrap().to_str().unwrap();
        for c in commands(&work) {
            suite.case(label, &c, &[name]);
        }
        std::fs::remove_dir_all(&work).unwrap();
    };

    // poses_bounds.npy
    let poses = std::fs::read(llff.join("poses_bounds.npy")).unwrap();
    let rows = base::npy::read_f64(&llff.join("poses_bounds.npy"))
        .unwrap()
        .values;
    let dict =
        |shape: &str| format!("{{'descr': '<f8', 'fortran_order': False, 'shape': {shape}, }}");
    let with = |col: usize, v: f64| {
        let mut r = rows.clone();
        for row in 0..5 {
            r[row * 17 + col] = v;
        }
        npy(&dict("(5, 17)"), &f64s(&r))
    };
    let mut pose_variants: Vec<(String, Vec<u8>)> = vec![("empty".into(), vec![])];
    for cut in cuts(poses.len(), 6) {
        pose_variants.push((format!("cut at {cut}"), poses[..cut].to_vec()));
    }
    pose_variants.extend([
        (
            "16 columns".into(),
            npy(&dict("(5, 16)"), &f64s(&rows[..80])),
        ),
        (
            "4 rows for 5 images".into(),
            npy(&dict("(4, 17)"), &f64s(&rows[..68])),
        ),
        (
            "huge row count".into(),
            npy(&dict("(1152921504606846976, 17)"), &f64s(&rows)),
        ),
        (
            "overflowing shape".into(),
            npy(&dict("(18446744073709551615, 17)"), &f64s(&rows)),
        ),
        (
            "trailing bytes".into(),
            [poses.clone(), vec![7; 8]].concat(),
        ),
        ("NaN centre".into(), with(3, f64::NAN)),
        ("Inf near".into(), with(15, f64::INFINITY)),
        ("NaN focal".into(), with(14, f64::NAN)),
        ("zero focal".into(), with(14, 0.0)),
        ("tiny focal".into(), with(14, 1e-20)),
        ("huge focal".into(), with(14, 1e30)),
        ("0x0 camera".into(), {
            let mut r = rows.clone();
            for row in 0..5 {
                r[row * 17 + 4] = 0.0;
                r[row * 17 + 9] = 0.0;
            }
            npy(&dict("(5, 17)"), &f64s(&r))
        }),
        ("images far smaller than the poses say".into(), {
            let mut r = rows.clone();
            for row in 0..5 {
                r[row * 17 + 4] *= 1000.0;
                r[row * 17 + 9] *= 1000.0;
                r[row * 17 + 14] *= 1000.0;
            }
            npy(&dict("(5, 17)"), &f64s(&r))
        }),
        ("far before near".into(), with(16, 0.5)),
        // Valid numbers that cannot train: an infinite extent, depths beyond f32.
        ("one camera at 1e15".into(), {
            let mut r = rows.clone();
            r[3] = 1e15;
            npy(&dict("(5, 17)"), &f64s(&r))
        }),
        ("translations 1e200".into(), with(8, 1e200)),
        ("near 1e-300".into(), with(15, 1e-300)),
        ("far 1e300".into(), with(16, 1e300)),
        ("negative near".into(), with(15, -1.0)),
        (
            "int64".into(),
            npy(
                "{'descr': '<i8', 'fortran_order': False, 'shape': (5, 17), }",
                &f64s(&rows),
            ),
        ),
    ]);
    for (label, bytes) in &pose_variants {
        damage(&mut suite, &llff, "poses_bounds.npy", label, bytes);
    }
    // Images of the capture.
    let png = std::fs::read(llff.join("images/view002.png")).unwrap();
    let mut tiny_png = Vec::new();
    image::RgbImage::new(1, 1)
        .write_to(
            &mut std::io::Cursor::new(&mut tiny_png),
            image::ImageFormat::Png,
        )
        .unwrap();
    for (label, bytes) in [
        ("empty image", vec![]),
        ("truncated image", png[..png.len() / 3].to_vec()),
        ("1x1 image", tiny_png.clone()),
    ] {
        damage(&mut suite, &llff, "images/view002.png", label, &bytes);
    }

    // COLMAP binary files.
    let cameras = std::fs::read(colmap_bin.join("sparse/0/cameras.bin")).unwrap();
    let camera_with = |at: usize, bytes: &[u8]| {
        let mut c = cameras.clone();
        c[at..at + bytes.len()].copy_from_slice(bytes);
        c
    };
    // Layout: count (8), id (4), model (4), width (8), height (8), f, cx, cy, k (8 each).
    let mut camera_variants: Vec<(String, Vec<u8>)> = vec![("empty".into(), vec![])];
    for cut in cuts(cameras.len(), 5) {
        camera_variants.push((format!("cut at {cut}"), cameras[..cut].to_vec()));
    }
    camera_variants.extend([
        (
            "u64::MAX cameras".into(),
            camera_with(0, &u64::MAX.to_le_bytes()),
        ),
        (
            "2 cameras, 1 held".into(),
            camera_with(0, &2u64.to_le_bytes()),
        ),
        ("model 99".into(), camera_with(12, &99i32.to_le_bytes())),
        ("width 0".into(), camera_with(16, &0u64.to_le_bytes())),
        ("0x0".into(), camera_with(16, &[0; 16])),
        (
            "width 2^40".into(),
            camera_with(16, &(1u64 << 40).to_le_bytes()),
        ),
        ("NaN focal".into(), camera_with(32, &f64::NAN.to_le_bytes())),
        (
            "tiny focal".into(),
            camera_with(32, &1e-20f64.to_le_bytes()),
        ),
        ("huge focal".into(), camera_with(32, &1e30f64.to_le_bytes())),
        (
            "negative focal".into(),
            camera_with(32, &(-30.0f64).to_le_bytes()),
        ),
        (
            "Inf principal point".into(),
            camera_with(40, &f64::INFINITY.to_le_bytes()),
        ),
        (
            "absurd distortion".into(),
            camera_with(56, &1e6f64.to_le_bytes()),
        ),
        (
            "NaN distortion".into(),
            camera_with(56, &f64::NAN.to_le_bytes()),
        ),
        (
            "trailing bytes".into(),
            [cameras.clone(), vec![1, 2, 3]].concat(),
        ),
    ]);
    for (label, bytes) in &camera_variants {
        damage(
            &mut suite,
            &colmap_bin,
            "sparse/0/cameras.bin",
            label,
            bytes,
        );
    }
    let images = std::fs::read(colmap_bin.join("sparse/0/images.bin")).unwrap();
    // Layout per image: id (4), q (32), t (24), camera (4), name, NUL, point count (8).
    let image_with = |at: usize, bytes: &[u8]| {
        let mut c = images.clone();
        c[at..at + bytes.len()].copy_from_slice(bytes);
        c
    };
    let mut image_variants: Vec<(String, Vec<u8>)> = vec![];
    for cut in cuts(images.len(), 5) {
        image_variants.push((format!("cut at {cut}"), images[..cut].to_vec()));
    }
    let name_end = 8 + 64 + images[8 + 64..].iter().position(|&b| b == 0).unwrap();
    image_variants.extend([
        (
            "u64::MAX images".into(),
            image_with(0, &u64::MAX.to_le_bytes()),
        ),
        (
            "NaN quaternion".into(),
            image_with(12, &f64::NAN.to_le_bytes()),
        ),
        ("zero quaternion".into(), image_with(12, &[0; 32])),
        (
            "Inf translation".into(),
            image_with(44, &f64::INFINITY.to_le_bytes()),
        ),
        ("missing camera".into(), image_with(68, &7u32.to_le_bytes())),
        (
            "u64::MAX points".into(),
            image_with(name_end + 1, &u64::MAX.to_le_bytes()),
        ),
        ("name without NUL".into(), {
            let mut c = images[..name_end].to_vec();
            c.extend_from_slice(b"xxxx");
            c
        }),
    ]);
    for (label, bytes) in &image_variants {
        damage(&mut suite, &colmap_bin, "sparse/0/images.bin", label, bytes);
    }
    let points = std::fs::read(colmap_bin.join("sparse/0/points3D.bin")).unwrap();
    // Layout per point: id (8), xyz (24), rgb (3), error (8), track length (8), track.
    let point_with = |at: usize, bytes: &[u8]| {
        let mut c = points.clone();
        c[at..at + bytes.len()].copy_from_slice(bytes);
        c
    };
    let mut point_variants: Vec<(String, Vec<u8>)> = vec![];
    for cut in cuts(points.len(), 5).into_iter().skip(1) {
        point_variants.push((format!("cut at {cut}"), points[..cut].to_vec()));
    }
    point_variants.extend([
        (
            "u64::MAX points".into(),
            point_with(0, &u64::MAX.to_le_bytes()),
        ),
        ("NaN point".into(), point_with(16, &f64::NAN.to_le_bytes())),
        (
            "Inf point".into(),
            point_with(8 + 51 + 24, &f64::NEG_INFINITY.to_le_bytes()),
        ),
        ("huge point".into(), point_with(16, &1e300f64.to_le_bytes())),
        (
            "u64::MAX track".into(),
            point_with(8 + 43, &u64::MAX.to_le_bytes()),
        ),
    ]);
    for (label, bytes) in &point_variants {
        damage(
            &mut suite,
            &colmap_bin,
            "sparse/0/points3D.bin",
            label,
            bytes,
        );
    }

    // COLMAP text files.
    let cam_txt = std::fs::read_to_string(colmap_txt.join("sparse/0/cameras.txt")).unwrap();
    let cam_line = cam_txt.lines().last().unwrap().to_string();
    let fields: Vec<&str> = cam_line.split_whitespace().collect();
    let camera_line = |i: usize, v: &str| {
        let mut f = fields.clone();
        f[i] = v;
        format!("{}\n", f.join(" "))
    };
    for (label, text) in [
        ("width 0", camera_line(2, "0")),
        ("negative width", camera_line(2, "-32")),
        ("width 2^40", camera_line(2, "1099511627776")),
        ("nan focal", camera_line(4, "nan")),
        ("inf focal", camera_line(4, "inf")),
        ("tiny focal", camera_line(4, "1e-20")),
        ("absurd distortion", camera_line(7, "1e9")),
        ("model FISHEYE", camera_line(1, "FISHEYE")),
        (
            "missing parameter",
            format!("{}\n", fields[..fields.len() - 1].join(" ")),
        ),
        ("garbage", "\u{0}\u{1}binary\n".to_string()),
        ("camera id used twice", format!("{cam_txt}{cam_line}\n")),
    ] {
        damage(
            &mut suite,
            &colmap_txt,
            "sparse/0/cameras.txt",
            label,
            text.as_bytes(),
        );
    }
    let pts_txt = std::fs::read_to_string(colmap_txt.join("sparse/0/points3D.txt")).unwrap();
    let first_point = pts_txt
        .lines()
        .find(|l| !l.starts_with('#'))
        .unwrap()
        .to_string();
    for (label, replacement) in [
        ("nan point", "nan"),
        ("inf point", "inf"),
        ("huge point", "1e308"),
    ] {
        let mut f: Vec<&str> = first_point.split_whitespace().collect();
        f[1] = replacement;
        let text = pts_txt.replace(&first_point, &f.join(" "));
        damage(
            &mut suite,
            &colmap_txt,
            "sparse/0/points3D.txt",
            label,
            text.as_bytes(),
        );
    }
    // A photo whose header claims gigabytes, in each layout.
    for scene in [&llff, &colmap_txt, &colmap_bin] {
        let file = format!("images/{}.png", capture.cameras[0].name);
        damage(
            &mut suite,
            scene,
            &file,
            "photo claiming 12000x9000 px",
            &png_claiming(12000, 9000),
        );
    }
    let img_txt = std::fs::read_to_string(colmap_txt.join("sparse/0/images.txt")).unwrap();
    let first_name = format!("{}.png", capture.cameras[0].name);
    let second_name = format!("{}.png", capture.cameras[1].name);
    let absolute = s(&colmap_txt.join("images").join(&first_name));
    for (label, text) in [
        ("image line cut short", img_txt.replace(" 1 view", " view")),
        ("nan quaternion", img_txt.replacen("\n1 ", "\n1 nan ", 1)),
        // Names that leave the image folder, even where they lead to a real photo.
        (
            "image name with ..",
            img_txt.replace(&first_name, &format!("../images/{first_name}")),
        ),
        (
            "absolute image name",
            img_txt.replace(&format!(" {first_name}"), &format!(" {absolute}")),
        ),
        (
            "image name used twice",
            img_txt.replace(&second_name, &first_name),
        ),
        ("image id used twice", img_txt.replacen("\n2 ", "\n1 ", 1)),
        ("camera at 1e200", {
            // The translation's first component of the first image line.
            let line = img_txt
                .lines()
                .find(|l| l.starts_with("1 "))
                .unwrap()
                .to_string();
            let mut f: Vec<&str> = line.split_whitespace().collect();
            f[5] = "1e200";
            img_txt.replace(&line, &f.join(" "))
        }),
    ] {
        damage(
            &mut suite,
            &colmap_txt,
            "sparse/0/images.txt",
            label,
            text.as_bytes(),
        );
    }
    // A capture output inside the capture.
    for c in [
        args(&[
            "train",
            "--scene",
            &s(&llff),
            "--out",
            &s(&llff.join("run")),
            "--downsample",
            "1",
        ]),
        args(&[
            "render",
            "--ply",
            &s(&llff.join("sparse/0/points3D.txt")),
            "--scene",
            &s(&llff),
            "--out",
            &s(&llff.join("images")),
        ]),
    ] {
        suite.case("alias", &c, &["--out", "points3D.txt"]);
    }
    // Two images of one stem (a.png, a.jpg): their renders would share a name.
    let first = format!("{}.png", capture.cameras[0].name);
    let last = format!("{}.png", capture.cameras[4].name);
    let jpg = format!("{}.jpg", capture.cameras[0].name);
    let decoded = image::open(llff.join("images").join(&first)).unwrap();
    for scene in [&llff, &colmap_txt] {
        copy_dir(scene, &work);
        decoded.save(work.join("images").join(&jpg)).unwrap();
        if scene == &llff {
            // Five photos for the five poses.
            std::fs::remove_file(work.join("images").join(&last)).unwrap();
        } else {
            let text = std::fs::read_to_string(work.join("sparse/0/images.txt")).unwrap();
            std::fs::write(
                work.join("sparse/0/images.txt"),
                text.replace(&format!(" {last}"), &format!(" {jpg}")),
            )
            .unwrap();
        }
        for c in commands(&work) {
            suite.case("two images of one stem", &c, &[&jpg]);
        }
        std::fs::remove_dir_all(&work).unwrap();
    }
    // A list naming one run twice.
    for (flag, extra) in [
        ("--modes", ["--modes", "plain,plain"]),
        ("--budgets", ["--budgets", "100,100"]),
    ] {
        let sub = if flag == "--modes" { "llff" } else { "budget" };
        suite.case(
            "a run named twice",
            &args(&[
                "experiment",
                sub,
                "--scene",
                &s(&llff),
                "--out",
                &s(&out),
                "--iters",
                "3",
                "--downsample",
                "1",
                "--device",
                "cpu",
                extra[0],
                extra[1],
            ]),
            &[flag],
        );
    }
    suite.finish("capture");
}

/// PLY, GLB, glTF and SPZ splat files, read by `export` and `render`.
#[test]
fn hostile_splat_files() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let g = splat::synthetic::random_box_scene(3, 40, 1);
    splat::formats::ply::write_ply(d.join("good.ply"), &g).unwrap();
    let ply = std::fs::read(d.join("good.ply")).unwrap();
    let glb = splat::formats::glb::to_glb(&g).unwrap();
    let spz = splat::formats::spz::to_spz(&g).unwrap();
    let gltf = splat::formats::glb::to_gltf(&g).unwrap();
    let out = d.join("out");
    let mut suite = Suite::new(d);
    let header_end = ply.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
    let header = String::from_utf8(ply[..header_end].to_vec()).unwrap();
    let body = &ply[header_end..];
    let reheader =
        |from: &str, to: &str| [header.replace(from, to).into_bytes(), body.to_vec()].concat();
    let mut variants: Vec<(String, &str, Vec<u8>)> = vec![("empty".into(), "ply", vec![])];
    for cut in cuts(ply.len(), 10).into_iter().skip(1) {
        variants.push((format!("PLY cut at {cut}"), "ply", ply[..cut].to_vec()));
    }
    let nan_body = {
        let mut b = body.to_vec();
        b[0..4].copy_from_slice(&f32::NAN.to_le_bytes());
        b
    };
    // Finite, but squared beyond f32: every projection of it would be infinite.
    variants.push(("PLY position 3e38".into(), "ply", {
        let mut b = body.to_vec();
        b[0..4].copy_from_slice(&3e38f32.to_le_bytes());
        [header.clone().into_bytes(), b].concat()
    }));
    // Finite, but beyond what a render or a loss can sum without overflowing (a colour of
    // 1e38 made training fail blaming the capture): refused at read, naming the splat.
    for (label, edit) in [
        (
            "PLY base colour 1e38",
            (|g: &mut splat::Gaussians| g.sh_dc[4].x = 1e38) as fn(&mut _),
        ),
        ("PLY higher SH 1e38", |g| g.sh_rest[5].y = -1e38),
        ("PLY rotation 1e38", |g| g.rotations[4][2] = 1e38),
        ("PLY zero rotation", |g| g.rotations[4] = [0.0; 4]),
        ("PLY opacity logit 1e38", |g| g.logit_opacities[4] = 1e38),
    ] {
        let mut h = g.clone();
        edit(&mut h);
        let path = d.join("huge.ply");
        splat::formats::ply::write_ply(&path, &h).unwrap();
        variants.push((label.into(), "ply", std::fs::read(&path).unwrap()));
        std::fs::remove_file(&path).unwrap();
    }
    variants.extend([
        (
            "vertex count 41".into(),
            "ply",
            reheader("element vertex 40", "element vertex 41"),
        ),
        (
            "vertex count 39".into(),
            "ply",
            reheader("element vertex 40", "element vertex 39"),
        ),
        (
            "vertex count 2^62".into(),
            "ply",
            reheader("element vertex 40", "element vertex 4611686018427387904"),
        ),
        (
            "vertex count 0".into(),
            "ply",
            reheader("element vertex 40", "element vertex 0"),
        ),
        (
            "uchar opacity".into(),
            "ply",
            reheader("property float opacity", "property uchar opacity"),
        ),
        (
            "double x".into(),
            "ply",
            reheader("property float x", "property double x"),
        ),
        (
            "list property".into(),
            "ply",
            reheader("property float x", "property list uchar float x"),
        ),
        ("no x".into(), "ply", reheader("property float x\n", "")),
        (
            "big endian".into(),
            "ply",
            reheader("binary_little_endian", "binary_big_endian"),
        ),
        (
            "NaN position".into(),
            "ply",
            [header.clone().into_bytes(), nan_body].concat(),
        ),
        (
            "not a PLY".into(),
            "ply",
            b"solid cube\nendsolid\n".to_vec(),
        ),
        (
            "ascii garbage".into(),
            "ply",
            reheader("binary_little_endian", "ascii"),
        ),
    ]);
    for cut in cuts(glb.len(), 8).into_iter().skip(1) {
        variants.push((format!("GLB cut at {cut}"), "glb", glb[..cut].to_vec()));
    }
    // The JSON chunk starts at byte 20; the binary chunk holds plain floats, which a flip
    // changes into other plain floats, so only the structure is flipped.
    for at in [0, 8, 13, 24, 40, 60] {
        let mut b = glb.clone();
        b[at] ^= 0x5a;
        variants.push((format!("GLB byte {at} flipped"), "glb", b));
    }
    variants.push(("GLB length lies".into(), "glb", {
        let mut b = glb.clone();
        b[8..12].copy_from_slice(&u32::MAX.to_le_bytes());
        b
    }));
    for cut in cuts(spz.len(), 6).into_iter().skip(1) {
        variants.push((format!("SPZ cut at {cut}"), "spz", spz[..cut].to_vec()));
    }
    variants.push(("SPZ not gzip".into(), "spz", b"NGSP not really".to_vec()));
    variants.push(("SPZ gzip of zeros".into(), "spz", gzip_of_zeros()));
    variants.push(("SPZ version 3 uncompressed".into(), "spz", {
        let mut raw = Vec::new();
        std::io::Read::read_to_end(&mut flate2::read::GzDecoder::new(&spz[..]), &mut raw).unwrap();
        raw
    }));
    variants.push(("SPZ declaring 50 million splats".into(), "spz", {
        let mut raw = Vec::new();
        std::io::Read::read_to_end(&mut flate2::read::GzDecoder::new(&spz[..]), &mut raw).unwrap();
        raw[8..12].copy_from_slice(&50_000_000u32.to_le_bytes());
        let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
        std::io::Write::write_all(&mut e, &raw).unwrap();
        e.finish().unwrap()
    }));
    // GLB structure and values, each against the part of the glTF specification it breaks.
    let (doc, bin) = glb_parts(&glb);
    // Taken apart and put together again, the file still reads: each case below breaks
    // only what it names.
    splat::formats::glb::parse_glb(Path::new("whole.glb"), &glb_from(&doc, &bin)).unwrap();
    let accessor_of = |doc: &serde_json::Value, attr: &str| {
        doc["meshes"][0]["primitives"][0]["attributes"][attr]
            .as_u64()
            .unwrap() as usize
    };
    let ext = "KHR_gaussian_splatting";
    // The first value of an attribute's accessor set to `v`.
    let first_value = |attr: &str, v: f32| {
        let a = accessor_of(&doc, attr);
        let view = doc["accessors"][a]["bufferView"].as_u64().unwrap() as usize;
        let at = doc["bufferViews"][view]["byteOffset"].as_u64().unwrap_or(0) as usize
            + doc["accessors"][a]["byteOffset"].as_u64().unwrap_or(0) as usize;
        let mut b = bin.clone();
        b[at..at + 4].copy_from_slice(&v.to_le_bytes());
        glb_from(&doc, &b)
    };
    let edited = |f: &dyn Fn(&mut serde_json::Value)| {
        let mut d = doc.clone();
        f(&mut d);
        glb_from(&d, &bin)
    };
    let pos = accessor_of(&doc, "POSITION");
    let pos_view = doc["accessors"][pos]["bufferView"].as_u64().unwrap() as usize;
    for (label, bytes) in [
        ("GLB NaN position", first_value("POSITION", f32::NAN)),
        (
            "GLB infinite rotation",
            first_value(&format!("{ext}:ROTATION"), f32::INFINITY),
        ),
        (
            "GLB NaN opacity",
            first_value(&format!("{ext}:OPACITY"), f32::NAN),
        ),
        (
            "GLB NaN SH",
            first_value(&format!("{ext}:SH_DEGREE_0_COEF_0"), f32::NAN),
        ),
        ("GLB zero scale", first_value(&format!("{ext}:SCALE"), 0.0)),
        (
            "GLB opacity above 1",
            first_value(&format!("{ext}:OPACITY"), 1.5),
        ),
        (
            "GLB byteOffset that wraps",
            edited(&|d| d["bufferViews"][pos_view]["byteOffset"] = (u64::MAX - 3).into()),
        ),
        (
            "GLB accessor type VEC2 for POSITION",
            edited(&|d| d["accessors"][pos]["type"] = "VEC2".into()),
        ),
        (
            "GLB buffer view shorter than its accessor",
            edited(&|d| d["bufferViews"][pos_view]["byteLength"] = 12.into()),
        ),
        (
            "GLB buffer view without byteLength",
            edited(&|d| {
                d["bufferViews"][pos_view]
                    .as_object_mut()
                    .unwrap()
                    .remove("byteLength");
            }),
        ),
        (
            "GLB sparse accessor",
            edited(&|d| {
                d["accessors"][pos]["sparse"] = serde_json::json!({"count": 1,
                    "indices": {"bufferView": 0, "componentType": 5125},
                    "values": {"bufferView": 0}})
            }),
        ),
        (
            "GLB unknown required extension",
            edited(&|d| {
                d["extensionsRequired"] = serde_json::json!(["KHR_draco_mesh_compression"])
            }),
        ),
        (
            "GLB node translation",
            edited(&|d| d["nodes"][0]["translation"] = serde_json::json!([1.0, 0.0, 0.0])),
        ),
        (
            "GLB parent node scale",
            edited(&|d| {
                d["nodes"]
                    .as_array_mut()
                    .unwrap()
                    .push(serde_json::json!({"children": [0], "scale": [2.0, 2.0, 2.0]}))
            }),
        ),
        (
            "GLB linear colours",
            edited(&|d| {
                d["meshes"][0]["primitives"][0]["extensions"]["KHR_gaussian_splatting"]["colorSpace"] =
                    "lin_rec709_display".into()
            }),
        ),
        (
            "GLB box kernel",
            edited(&|d| {
                d["meshes"][0]["primitives"][0]["extensions"]["KHR_gaussian_splatting"]["kernel"] =
                    "box".into()
            }),
        ),
        (
            "GLB triangles",
            edited(&|d| d["meshes"][0]["primitives"][0]["mode"] = 4.into()),
        ),
        (
            "GLB two splat primitives",
            edited(&|d| {
                let p = d["meshes"][0]["primitives"][0].clone();
                d["meshes"][0]["primitives"].as_array_mut().unwrap().push(p);
            }),
        ),
        (
            "GLB unused buffer view beyond the buffer",
            edited(&|d| {
                d["bufferViews"].as_array_mut().unwrap().push(
                    serde_json::json!({"buffer": 0, "byteOffset": bin.len(), "byteLength": 64}),
                )
            }),
        ),
        (
            "GLB COLOR_0 accessor beyond its view",
            edited(&|d| {
                let a = d["meshes"][0]["primitives"][0]["attributes"]["COLOR_0"]
                    .as_u64()
                    .unwrap() as usize;
                d["accessors"][a]["byteOffset"] = (1u64 << 40).into();
            }),
        ),
        (
            "GLB unused accessor of an unknown type",
            edited(&|d| {
                d["accessors"].as_array_mut().unwrap().push(
                    serde_json::json!({"bufferView": 0, "componentType": 5126, "count": 1, "type": "VEC5"}),
                )
            }),
        ),
        (
            "GLB buffer longer than the chunk",
            edited(&|d| d["buffers"][0]["byteLength"] = (bin.len() + 64).into()),
        ),
    ] {
        variants.push((label.into(), "glb", bytes));
    }
    for (label, text) in [
        ("glTF cut", gltf[..gltf.len() / 2].to_string()),
        (
            "glTF count lies",
            gltf.replacen("\"count\":40", "\"count\":4000000000", 1),
        ),
        (
            "glTF external buffer",
            gltf.replacen("data:application/octet-stream;base64,", "other.bin#", 1),
        ),
    ] {
        variants.push((label.into(), "gltf", text.into_bytes()));
    }
    for (label, ext, bytes) in &variants {
        let bad = d.join(format!("bad.{ext}"));
        let name = format!("bad.{ext}");
        let target = if *ext == "ply" { "glb" } else { "ply" };
        suite.with_file(&bad, bytes, |suite| {
            suite.case(
                label,
                &args(&[
                    "export",
                    "--in",
                    &s(&bad),
                    "--out",
                    &s(&out.with_extension(target)),
                ]),
                &[&name],
            );
            suite.case(
                label,
                &args(&[
                    "render",
                    "--ply",
                    &s(&bad),
                    "--out",
                    &s(&out),
                    "--orbit",
                    "2",
                    "--width",
                    "16",
                    "--height",
                    "12",
                    "--device",
                    "cpu",
                ]),
                &[&name],
            );
        });
    }
    // A valid scene whose splat lies beyond SPZ's fixed point: the export names the splat,
    // and the folder it would have made for the file is not left behind.
    let mut far = g.clone();
    far.means[4].x = 3000.0;
    let far_ply = d.join("far.ply");
    splat::formats::ply::write_ply(&far_ply, &far).unwrap();
    suite.case(
        "SPZ export beyond the fixed point",
        &args(&[
            "export",
            "--in",
            &s(&far_ply),
            "--out",
            &s(&d.join("new").join("far.spz")),
        ]),
        &["splat 4 at"],
    );
    std::fs::remove_file(&far_ply).unwrap();
    suite.finish("splat file");
}

/// A valid PNG whose header claims `width`x`height` RGB pixels while holding a few bytes.
fn png_claiming(width: u32, height: u32) -> Vec<u8> {
    let chunk = |kind: &[u8], data: &[u8]| {
        let mut crc = flate2::Crc::new();
        crc.update(kind);
        crc.update(data);
        let mut c = (data.len() as u32).to_be_bytes().to_vec();
        c.extend_from_slice(kind);
        c.extend_from_slice(data);
        c.extend_from_slice(&crc.sum().to_be_bytes());
        c
    };
    let mut ihdr = width.to_be_bytes().to_vec();
    ihdr.extend_from_slice(&height.to_be_bytes());
    ihdr.extend_from_slice(&[8, 2, 0, 0, 0]);
    let mut idat = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
    std::io::Write::write_all(&mut idat, &[0; 100]).unwrap();
    let mut png = b"\x89PNG\r\n\x1a\n".to_vec();
    png.extend(chunk(b"IHDR", &ihdr));
    png.extend(chunk(b"IDAT", &idat.finish().unwrap()));
    png.extend(chunk(b"IEND", &[]));
    png
}

/// The JSON document and the binary chunk of a GLB file.
fn glb_parts(glb: &[u8]) -> (serde_json::Value, Vec<u8>) {
    let json_len = u32::from_le_bytes(glb[12..16].try_into().unwrap()) as usize;
    let doc = serde_json::from_slice(&glb[20..20 + json_len]).unwrap();
    let bin_at = 20 + json_len;
    let bin_len = u32::from_le_bytes(glb[bin_at..bin_at + 4].try_into().unwrap()) as usize;
    (doc, glb[bin_at + 8..bin_at + 8 + bin_len].to_vec())
}

/// A GLB file of `doc` and `bin`, padded as the container requires.
fn glb_from(doc: &serde_json::Value, bin: &[u8]) -> Vec<u8> {
    let mut json = serde_json::to_vec(doc).unwrap();
    while !json.len().is_multiple_of(4) {
        json.push(b' ');
    }
    let mut bin = bin.to_vec();
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    let total = 12 + 8 + json.len() + 8 + bin.len();
    let mut out = b"glTF".to_vec();
    out.extend(2u32.to_le_bytes());
    out.extend((total as u32).to_le_bytes());
    out.extend((json.len() as u32).to_le_bytes());
    out.extend(b"JSON");
    out.extend(json);
    out.extend((bin.len() as u32).to_le_bytes());
    out.extend(b"BIN\0");
    out.extend(bin);
    out
}

/// A gzip stream of 16 zero bytes (one stored block), so the SPZ reader meets a header
/// that is all zeros rather than a gzip error.
fn gzip_of_zeros() -> Vec<u8> {
    let data = [0u8; 16];
    let mut out = vec![0x1f, 0x8b, 8, 0, 0, 0, 0, 0, 0, 0xff];
    out.push(1); // final stored block
    out.extend_from_slice(&(data.len() as u16).to_le_bytes());
    out.extend_from_slice(&(!(data.len() as u16)).to_le_bytes());
    out.extend_from_slice(&data);
    // CRC-32 of 16 zero bytes and the length.
    out.extend_from_slice(&0x8ecc_1cb0u32.to_le_bytes());
    out.extend_from_slice(&(data.len() as u32).to_le_bytes());
    out
}

/// Files a run writes and reads back: checkpoints, restorer weights, `aberration.json`.
#[test]
fn hostile_run_files() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let scene = llff_scene(d);
    let run = d.join("run");
    let train = |out: &Path, extra: &[&str]| {
        let mut a = args(&[
            "train",
            "--scene",
            &s(&scene),
            "--out",
            &s(out),
            "--mode",
            "plain",
            "--downsample",
            "1",
            "--iters",
            "6",
            "--checkpoint-every",
            "3",
            "--spiral",
            "2",
            "--device",
            "cpu",
        ]);
        a.extend(extra.iter().map(|x| x.to_string()));
        a
    };
    run_ok(&train(&run, &[]));
    let ckpt = std::fs::read(run.join("checkpoint.bin")).unwrap();
    let mut suite = Suite::new(d);
    let mut variants: Vec<(String, Vec<u8>)> = vec![("empty".into(), vec![])];
    for cut in cuts(ckpt.len(), 6).into_iter().skip(1) {
        variants.push((format!("cut at {cut}"), ckpt[..cut].to_vec()));
    }
    for at in [3, 20, 200, ckpt.len() / 2, ckpt.len() - 3] {
        let mut b = ckpt.clone();
        b[at] ^= 0x04;
        variants.push((format!("byte {at} flipped"), b));
    }
    variants.push((
        "trailing bytes".into(),
        [ckpt.clone(), vec![0; 16]].concat(),
    ));
    for (label, bytes) in &variants {
        let copy = d.join("run2");
        copy_dir(&run, &copy);
        std::fs::write(copy.join("checkpoint.bin"), bytes).unwrap();
        suite.case(label, &train(&copy, &["--resume"]), &["checkpoint.bin"]);
        std::fs::remove_dir_all(&copy).unwrap();
    }
    // The run resumed on another capture with the same flags: one camera moved.
    let other = d.join("other_scene");
    copy_dir(&scene, &other);
    let poses_path = other.join("poses_bounds.npy");
    let mut poses = scenes::llff::read_poses_bounds(&poses_path).unwrap();
    poses[0].center.x += 0.05;
    scenes::llff::write_poses_bounds(&poses_path, &poses).unwrap();
    let mut resume_other = train(&run, &["--resume"]);
    let at = resume_other.iter().position(|a| a == "--scene").unwrap();
    resume_other[at + 1] = s(&other);
    suite.case("resume on another capture", &resume_other, &["capture"]);
    std::fs::remove_dir_all(&other).unwrap();

    // Restorer weights: versions 3 (XXH3) and 2 (FNV-1a) made from the shipped version 1 file.
    let shipped_path = Path::new(env!("CARGO_MANIFEST_DIR")).join("restore/weights/tiny.bin");
    let shipped = std::fs::read(&shipped_path).unwrap();
    let versioned = |magic: &[u8], sum: fn(&[u8]) -> u64| {
        let mut v = shipped.clone();
        v[..21].copy_from_slice(magic);
        let sum = sum(&v);
        v.extend_from_slice(&sum.to_le_bytes());
        v
    };
    let v3 = versioned(b"METASPLAT-RESTORER 3\n", base::hash::xxh3);
    let v2 = versioned(b"METASPLAT-RESTORER 2\n", base::hash::fnv1a64);
    // Version 4 (safetensors) as `restorer train` writes it now, from the same network.
    let v4 = {
        let device = restore::Compute::Cpu.device().unwrap();
        let (net, header) = restore::weights::load(&shipped_path, &device, None, None).unwrap();
        let path = d.join("v4.safetensors");
        restore::weights::save(&net, &header, &path).unwrap();
        std::fs::read(&path).unwrap()
    };
    let photo = d.join("photo.png");
    image::RgbImage::from_fn(32, 32, |x, y| {
        image::Rgb([(x * 7) as u8, (y * 7) as u8, 50])
    })
    .save(&photo)
    .unwrap();
    let psf = d.join("psf.npy");
    std::fs::write(&psf, npy(&psf_dict("(9, 5, 5, 3)"), &f32s(&psf_values()))).unwrap();
    let bad = d.join("bad.bin");
    let mut weights: Vec<(String, Vec<u8>)> = vec![("empty".into(), vec![])];
    for (version, v) in [("", &v3), ("version 2, ", &v2), ("version 4, ", &v4)] {
        for cut in [10, 21, 29, 200, v.len() / 2, v.len() - 1] {
            weights.push((format!("{version}cut at {cut}"), v[..cut].to_vec()));
        }
        for at in [25, 100, v.len() / 3, v.len() - 20] {
            let mut b = v.clone();
            b[at] ^= 0x01;
            weights.push((format!("{version}byte {at} flipped"), b));
        }
        weights.push((
            format!("{version}trailing bytes"),
            [v.clone(), b"more".to_vec()].concat(),
        ));
    }
    weights.push(("header length lies".into(), {
        let mut b = v3.clone();
        b[21..29].copy_from_slice(&u64::MAX.to_le_bytes());
        b
    }));
    for (label, bytes) in &weights {
        suite.with_file(&bad, bytes, |suite| {
            suite.case(
                label,
                &args(&[
                    "restore",
                    "--weights",
                    &s(&bad),
                    "--psf",
                    &s(&psf),
                    "--in",
                    &s(&photo),
                    "--out",
                    &s(&d.join("restored.png")),
                ]),
                &["bad.bin"],
            );
        });
    }
    // aberration.json of an aberrated capture.
    let abr = d.join("abr");
    run_ok(&args(&[
        "scene",
        "aberrate",
        "--scene",
        &s(&scene),
        "--psf",
        &s(&psf),
        "--out",
        &s(&abr),
        "--downsample",
        "1",
    ]));
    for (label, bytes) in weights.iter().step_by(4) {
        suite.with_file(&bad, bytes, |suite| {
            suite.case(
                label,
                &args(&[
                    "train",
                    "--scene",
                    &s(&abr),
                    "--out",
                    &s(&d.join("run3")),
                    "--mode",
                    "restored",
                    "--downsample",
                    "1",
                    "--iters",
                    "3",
                    "--restorer",
                    &s(&bad),
                    "--device",
                    "cpu",
                ]),
                &["bad.bin"],
            );
        });
    }

    let record = std::fs::read_to_string(abr.join("aberration.json")).unwrap();
    let json: serde_json::Value = serde_json::from_str(&record).unwrap();
    let edit = |key: &str, v: serde_json::Value| {
        let mut j = json.clone();
        j[key] = v;
        j.to_string()
    };
    let work = d.join("abr2");
    for (label, text) in [
        ("not JSON", "{\"psf\": ".to_string()),
        ("mode foo", edit("mode", "foo".into())),
        ("sensor_px 0", edit("sensor_px", 0.into())),
        ("sensor_px 2^40", edit("sensor_px", (1u64 << 40).into())),
        (
            "negative noise",
            edit("noise_gaussian_sigma", (-1.0).into()),
        ),
        ("psf missing", edit("psf", "nowhere.npy".into())),
        // The photos went through another PSF file than the one beside them.
        (
            "psf checksum",
            edit("psf_checksum", "xxh3:0123456789abcdef".into()),
        ),
        (
            "psf checksum as records before XXH3 wrote it",
            edit("psf_checksum", "0123456789abcdef".into()),
        ),
        // More photos than were made through the lens.
        ("images 1", edit("images", 1.into())),
        // Beyond f32: named as written, not as inf.
        ("noise 1e300", edit("noise_poisson_scale", 1e300.into())),
        ("psf string is a number", edit("psf", 7.into())),
    ] {
        copy_dir(&abr, &work);
        std::fs::write(work.join("aberration.json"), &text).unwrap();
        suite.case(
            label,
            &args(&[
                "train",
                "--scene",
                &s(&work),
                "--out",
                &s(&d.join("run4")),
                "--mode",
                "aware",
                "--downsample",
                "1",
                "--iters",
                "3",
                "--restorer",
                "wiener",
                "--device",
                "cpu",
            ]),
            &["aberration.json", "nowhere.npy"],
        );
        std::fs::remove_dir_all(&work).unwrap();
    }
    // The restorer's own commands: a bad PSF grid, a damaged photo among good ones, bad weights.
    let photos = d.join("photos");
    let val = d.join("val");
    for (i, dir) in [&photos, &photos, &photos, &val].into_iter().enumerate() {
        std::fs::create_dir_all(dir).unwrap();
        image::RgbImage::from_fn(80, 80, |x, y| {
            image::Rgb([(x * 3) as u8, (y * 3) as u8, 40 * i as u8])
        })
        .save(dir.join(format!("p{i}.png")))
        .unwrap();
    }
    let bad_npy = d.join("bad.npy");
    let bad_png = photos.join("p9.png");
    let restorer_train = |psf: &Path| {
        args(&[
            "restorer",
            "train",
            "--images",
            &s(&photos),
            "--val",
            &s(&val),
            "--psf",
            &s(psf),
            "--config",
            "tiny",
            "--out",
            &s(&d.join("w.bin")),
            "--steps",
            "1",
            "--batch",
            "1",
        ])
    };
    suite.with_file(&bad_npy, &std::fs::read(&psf).unwrap()[..100], |suite| {
        suite.case(
            "restorer train, cut PSF",
            &restorer_train(&bad_npy),
            &["bad.npy"],
        );
        suite.case(
            "restorer eval, cut PSF",
            &args(&[
                "restorer",
                "eval",
                "--weights",
                &s(&shipped_path),
                "--psf",
                &s(&bad_npy),
                "--val",
                &s(&val),
                "--out",
                &s(&d.join("evalout")),
            ]),
            &["bad.npy"],
        );
    });
    suite.with_file(&bad_png, b"\x89PNG\r\n\x1a\n truncated", |suite| {
        suite.case(
            "restorer train, damaged photo",
            &restorer_train(&psf),
            &["p9.png"],
        );
    });
    for (label, bytes) in weights.iter().step_by(3) {
        suite.with_file(&bad, bytes, |suite| {
            suite.case(
                label,
                &args(&[
                    "restorer",
                    "eval",
                    "--weights",
                    &s(&bad),
                    "--psf",
                    &s(&psf),
                    "--val",
                    &s(&val),
                    "--out",
                    &s(&d.join("evalout")),
                ]),
                &["bad.bin"],
            );
        });
    }

    // Sizes and values from flags, refused before any allocation or output.
    let o = s(&d.join("flagged"));
    // Two photo folders for `restorer train`.
    let images = d.join("photos_train");
    let val = d.join("photos_val");
    for folder in [&images, &val] {
        std::fs::create_dir_all(folder).unwrap();
        std::fs::copy(&photo, folder.join("a.png")).unwrap();
    }
    let restorer_train = |extra: &[&str], images: &str, val: &str| {
        let mut a = args(&[
            "restorer",
            "train",
            "--images",
            images,
            "--val",
            val,
            "--psf",
            &s(&psf),
            "--out",
            &o,
            "--steps",
            "1",
        ]);
        a.extend(extra.iter().map(|x| x.to_string()));
        a
    };
    // `psf simulate` with the flags under test.
    let simulating = |extra: &[&str]| {
        let mut a = args(&["psf", "simulate", "--out", &o]);
        a.extend(extra.iter().map(|x| x.to_string()));
        a
    };
    let flagged = |flag: &str, value: &str| {
        args(&[
            "train",
            "--scene",
            &s(&scene),
            "--out",
            &o,
            "--mode",
            "plain",
            flag,
            value,
        ])
    };
    // An experiment whose ceiling run would be refused (its folder holds a run) refuses
    // before it makes the PSF grid or the aberrated copy.
    let exp = d.join("exp");
    std::fs::create_dir_all(exp.join("run_clean")).unwrap();
    std::fs::write(exp.join("run_clean/point_cloud.ply"), b"a run").unwrap();
    // A folder of the user's: the demo would replace its psf.npy.
    let grid = s(&d.join("grid.npy"));
    let mine = d.join("mine");
    std::fs::create_dir_all(&mine).unwrap();
    std::fs::write(mine.join("psf.npy"), b"my grid").unwrap();
    // An experiment folder whose aberrated copy was made with another noise seed.
    let exp2 = d.join("exp2");
    copy_dir(&abr, &exp2.join("aberrated"));
    for (flag, c) in [
        ("--out", args(&["demo", "--quick", "--out", &s(&mine)])),
        (
            "--seed 0, not 3",
            args(&[
                "experiment",
                "llff",
                "--scene",
                &s(&scene),
                "--out",
                &s(&exp2),
                "--seed",
                "3",
                "--ceiling",
                "false",
                "--iters",
                "2",
                "--downsample",
                "1",
                "--device",
                "cpu",
            ]),
        ),
        // Settings the mode never reads.
        ("--lambda", flagged("--lambda", "0.5")),
        ("--restorer", flagged("--restorer", "nothing.bin")),
        // A folder where a file is due and the other way round.
        (
            "--out",
            restorer_train(&[], &s(&images), &s(&val))
                .into_iter()
                .map(|a| if a == o { s(d) } else { a })
                .collect(),
        ),
        ("--images", restorer_train(&[], &s(&photo), &s(&val))),
        (
            "--out",
            args(&["psf", "show", &s(&psf), "--out", &s(&d.join("p.npy"))]),
        ),
        (
            "--width",
            args(&[
                "render",
                "--in",
                &s(&photo),
                "--scene",
                &s(&scene),
                "--out",
                &o,
                "--width",
                "100",
            ]),
        ),
        (
            "run_clean",
            args(&[
                "experiment",
                "llff",
                "--scene",
                &s(&scene),
                "--out",
                &s(&exp),
                "--iters",
                "2",
                "--downsample",
                "1",
                "--device",
                "cpu",
            ]),
        ),
        ("--fft-size", simulating(&["--fft-size", "100000"])),
        ("--grid", simulating(&["--grid", "100000"])),
        // Flags each in range whose product is not.
        (
            "--sensor-pitch-um",
            simulating(&["--sensor-pitch-um", "1e20"]),
        ),
        (
            "--sensor-pitch-um",
            simulating(&["--sensor-pitch-um", "1e6"]),
        ),
        ("--size", simulating(&["--grid", "33", "--size", "1023"])),
        ("--size", simulating(&["--grid", "33", "--size", "400"])),
        ("--aperture-um", simulating(&["--aperture-um", "1e-300"])),
        // Optics that describe no imaging system: no light in the crop, or a flat PSF.
        ("--focal-um", simulating(&["--focal-um", "1e300"])),
        ("--focal-um", simulating(&["--focal-um", "1e-6"])),
        // Mis-calibrated hardware that is no hardware.
        (
            "--sensor-offset-um",
            simulating(&["--sensor-offset-um", "-2000"]),
        ),
        ("--rotation-deg", simulating(&["--rotation-deg", "inf"])),
        ("--focal-scale", simulating(&["--focal-scale", "1e-6"])),
        ("--focal-scale", simulating(&["--focal-scale", "-1"])),
        ("--refine-psf", flagged("--refine-psf", "warp")),
        ("--refine-psf", flagged("--refine-psf", "blind")),
        (
            "--errors",
            args(&[
                "experiment",
                "psf-mismatch",
                "--scene",
                &s(&scene),
                "--out",
                &o,
                "--errors",
                "focal:0",
            ]),
        ),
        (
            "--errors",
            args(&[
                "experiment",
                "psf-mismatch",
                "--scene",
                &s(&scene),
                "--out",
                &o,
                "--errors",
                "tilt:3",
            ]),
        ),
        (
            "--sensor-pitch-um",
            simulating(&["--sensor-pitch-um", "1e-9"]),
        ),
        (
            "--width",
            args(&["scene", "procedural", "--out", &o, "--width", "100000"]),
        ),
        ("--spiral", flagged("--spiral", "4294967296")),
        ("--lambda", flagged("--lambda", "NaN")),
        ("--iters", flagged("--iters", "0")),
        ("--max-sh-degree", flagged("--max-sh-degree", "9")),
        ("--max-splats", flagged("--max-splats", "0")),
        ("--llffhold", flagged("--llffhold", "1")),
        ("--downsample", flagged("--downsample", "0")),
        // A downsample that leaves a few pixels a side.
        ("--downsample", flagged("--downsample", "16")),
        ("--checkpoint-every", flagged("--checkpoint-every", "0")),
        (
            "--llffhold",
            args(&["scene", "info", &s(&scene), "--llffhold", "1"]),
        ),
        (
            "--downsample",
            args(&["scene", "info", &s(&scene), "--downsample", "0"]),
        ),
        ("--iters", args(&["demo", "--out", &o, "--iters", "0"])),
        (
            "--k",
            args(&[
                "deconvolve",
                "--psf",
                &s(&psf),
                "--in",
                &s(&photo),
                "--out",
                &o,
                "--k",
                "3e38",
            ]),
        ),
        (
            "--lr",
            restorer_train(&["--lr", "1e308"], &s(&images), &s(&val)),
        ),
        (
            "--val-crop",
            restorer_train(&["--val-crop", "1"], &s(&images), &s(&val)),
        ),
        ("--val", restorer_train(&[], &s(&images), &s(&images))),
        // A batch no machine holds is refused before a photo is read, not killed by the system.
        (
            "--batch",
            restorer_train(
                &["--config", "paper", "--batch", "1024"],
                &s(&images),
                &s(&val),
            ),
        ),
        (
            "--sensor-px",
            args(&[
                "restore",
                "--weights",
                &s(&bad),
                "--psf",
                &s(&psf),
                "--in",
                &s(&photo),
                "--out",
                &o,
                "--sensor-px",
                "0",
            ]),
        ),
        // Every output checked before the first is written: a picture that cannot be
        // written (or that is the grid itself) used to leave the grid behind, or replace it.
        (
            "--picture",
            args(&["psf", "simulate", "--out", &grid, "--picture", &grid]),
        ),
        (
            "--picture",
            args(&[
                "psf",
                "simulate",
                "--out",
                &grid,
                "--picture",
                &s(&d.join("missing/p.png")),
            ]),
        ),
        (
            "--out",
            args(&[
                "deconvolve",
                "--psf",
                &s(&psf),
                "--in",
                &s(&photo),
                "--bank",
                &s(&d.join("bank")),
                "--out",
                &s(&d.join("missing/d.png")),
            ]),
        ),
        ("--out", args(&["psf", "simulate", "--out", &s(d)])),
        (
            "--out",
            args(&["psf", "simulate", "--out", &s(&d.join("g.png"))]),
        ),
        // Aberrating an aberrated capture would make its blurred photos the clean images.
        (
            "--scene",
            args(&[
                "scene",
                "aberrate",
                "--scene",
                &s(&abr),
                "--psf",
                &s(&psf),
                "--out",
                &o,
                "--downsample",
                "1",
            ]),
        ),
        // A weights file's problem names its flag, not the capture.
        (
            "--restorer",
            args(&[
                "train",
                "--scene",
                &s(&abr),
                "--out",
                &o,
                "--mode",
                "restored",
                "--downsample",
                "1",
                "--restorer",
                &s(&d.join("missing.bin")),
                "--device",
                "cpu",
            ]),
        ),
        // An image named .jpg would hold PNG bytes: refused before any work.
        (
            "--out",
            args(&[
                "aberrate",
                "--psf",
                &s(&psf),
                "--in",
                &s(&photo),
                "--out",
                &s(&d.join("a.jpg")),
            ]),
        ),
        (
            "--out",
            args(&[
                "deconvolve",
                "--psf",
                &s(&psf),
                "--in",
                &s(&photo),
                "--out",
                &s(&d.join("d.jpeg")),
            ]),
        ),
        // A bad PSF file for the maker is the flag's problem, not the output's.
        (
            "--psf",
            args(&[
                "scene",
                "aberrate",
                "--scene",
                &s(&scene),
                "--psf",
                &s(&photo),
                "--out",
                &o,
                "--downsample",
                "1",
            ]),
        ),
        // A file where a folder is due, and a folder where a file is due, say so.
        (
            "is a file, not a capture folder",
            args(&["train", "--scene", &s(&photo), "--out", &o]),
        ),
        (
            "is a folder, not a splat file",
            args(&[
                "train",
                "--scene",
                &s(&abr),
                "--out",
                &o,
                "--downsample",
                "1",
                "--init",
                &s(&abr),
            ]),
        ),
    ] {
        suite.case("flag", &c, &[flag]);
    }
    suite.finish("run file");
}

/// Outputs aimed at the files a command reads through links and model files: photo folders
/// shared by a link (the usual way to share a data set), captures reached through a linked
/// folder, and a run's own `--init`. Every case must refuse naming `--out` and leave every
/// file, the shared photos included, as it was.
#[cfg(unix)]
#[test]
fn hostile_outputs_over_linked_inputs() {
    use std::os::unix::fs::symlink;
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let scene = llff_scene(d);
    // A capture whose photos live elsewhere, linked in.
    let shared = d.join("shared/photos");
    std::fs::create_dir_all(d.join("shared")).unwrap();
    let linked = d.join("linked");
    std::fs::create_dir_all(&linked).unwrap();
    copy_dir(&scene.join("images"), &shared);
    std::fs::copy(
        scene.join("poses_bounds.npy"),
        linked.join("poses_bounds.npy"),
    )
    .unwrap();
    symlink(&shared, linked.join("images")).unwrap();
    // The same capture reached through a linked folder.
    let alias = d.join("alias");
    symlink(&linked, &alias).unwrap();
    let psf = d.join("psf.npy");
    std::fs::write(&psf, npy(&psf_dict("(9, 5, 5, 3)"), &f32s(&psf_values()))).unwrap();
    let run = d.join("run");
    let train = |scene: &Path, out: &Path, extra: &[&str]| {
        let mut a = args(&[
            "train",
            "--scene",
            &s(scene),
            "--out",
            &s(out),
            "--mode",
            "plain",
            "--downsample",
            "1",
            "--iters",
            "4",
            "--spiral",
            "0",
            "--device",
            "cpu",
        ]);
        a.extend(extra.iter().map(|x| x.to_string()));
        a
    };
    run_ok(&train(&scene, &run, &[]));
    let ply = run.join("point_cloud.ply");
    let mut suite = Suite::new(d);
    let render = |scene: &Path, out: &Path| {
        args(&[
            "render",
            "--ply",
            &s(&ply),
            "--scene",
            &s(scene),
            "--out",
            &s(out),
            "--downsample",
            "1",
            "--device",
            "cpu",
        ])
    };
    for (label, scene, out) in [
        ("render onto linked photos", &linked, shared.clone()),
        ("render onto the photos' parent", &linked, d.join("shared")),
        ("render through an aliased capture", &alias, shared.clone()),
        (
            "render into the link itself",
            &linked,
            linked.join("images"),
        ),
        ("render into the aliased capture", &linked, alias.join("x")),
    ] {
        suite.case(label, &render(scene, &out), &["--out"]);
    }
    for (label, out) in [
        ("train onto linked photos", shared.clone()),
        ("train into the photos' parent", d.join("shared")),
    ] {
        suite.case(label, &train(&linked, &out, &[]), &["--out"]);
    }
    suite.case(
        "aberrate onto linked photos",
        &args(&[
            "scene",
            "aberrate",
            "--scene",
            &s(&alias),
            "--psf",
            &s(&psf),
            "--out",
            &s(&shared.join("abr")),
            "--downsample",
            "1",
        ]),
        &["--out"],
    );
    // A run replacing the splats it starts from.
    suite.case(
        "--init inside --out",
        &train(&scene, &run, &["--init", &s(&ply), "--overwrite"]),
        &["--out", "--init"],
    );
    // A start larger than the run's budget.
    suite.case(
        "--init above the budget",
        &train(
            &scene,
            &d.join("run2"),
            &["--init", &s(&ply), "--max-splats", "1"],
        ),
        &["--max-splats"],
    );
    suite.finish("linked-input");
}

/// One writer per run folder: while a run trains, a second `train` into the same folder (with
/// `--overwrite` too) is refused naming the process that holds it, and the lock goes with
/// the holder, even when the holder is killed.
#[test]
fn a_run_folder_has_one_writer() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let scene = llff_scene(d);
    let run = d.join("run");
    let train = |iters: &str, extra: &[&str]| {
        let mut a = args(&[
            "train",
            "--scene",
            &s(&scene),
            "--out",
            &s(&run),
            "--mode",
            "plain",
            "--downsample",
            "1",
            "--iters",
            iters,
            "--spiral",
            "0",
            "--device",
            "cpu",
        ]);
        a.extend(extra.iter().map(|x| x.to_string()));
        a
    };
    let mut first = common::cli::metasplat()
        .args(train("1000000", &[]))
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let lock = run.join(base::lock::LOCK_FILE);
    let holder = format!("process {}", first.id());
    let start = std::time::Instant::now();
    while !std::fs::read_to_string(&lock).is_ok_and(|t| t.contains(&holder)) {
        assert!(
            start.elapsed().as_secs() < 120,
            "the first run never took its folder"
        );
        assert!(
            first.try_wait().unwrap().is_none(),
            "the first run ended early"
        );
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    for extra in [&[][..], &["--overwrite"][..]] {
        let out = common::cli::metasplat()
            .args(train("5", extra))
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "a second writer ran: {err}");
        assert!(
            err.contains(&holder) || err.contains("already holds a run"),
            "{extra:?}: {err}"
        );
        assert_ne!(out.status.code(), Some(101), "{err}");
    }
    // Nor does a render put frames into the folder while the run writes it.
    let ply = d.join("start.ply");
    splat::formats::ply::write_ply(&ply, &splat::synthetic::random_box_scene(3, 40, 1)).unwrap();
    let out = common::cli::metasplat()
        .args(args(&[
            "render",
            "--in",
            &s(&ply),
            "--out",
            &s(&run),
            "--orbit",
            "2",
            "--width",
            "32",
            "--height",
            "24",
            "--device",
            "cpu",
        ]))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains(&holder), "{err}");
    assert!(
        !run.join("orbit000.png").exists(),
        "a frame landed in the run folder"
    );
    assert!(first.try_wait().unwrap().is_none(), "the first run ended");
    first.kill().unwrap();
    first.wait().unwrap();
    // The killed holder's lock is gone with it: the folder can be replaced.
    run_ok(&train("5", &["--overwrite"]));
    assert!(run.join("point_cloud.ply").is_file());
    assert!(!lock.exists(), "the lock file stays after the run");
}
