//! Fuzzing every file parser with proptest for a fixed budget: random bytes and mutations of
//! valid files (byte flips, truncations, inserted bytes) must give `Ok` or an error, never a
//! panic (a panic fails the test) and never hold more than [`MAX_HELD`] at once while parsing
//! (the inputs are a few kB; the readers check sizes against the file and `base::limits`
//! before reserving, so a lying header must not size an allocation, and a count that grows a
//! buffer piece by piece must stop where the file's bytes do). The watching allocator also
//! refuses any single request above `base::alloc_watch::HARD_LIMIT`, so a reader that escapes
//! the bound fails its case rather than exhausting the machine.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// The most a parse of these small inputs may hold at once, every allocation of the case
/// together (a valid file's parse holds well under a megabyte).
const MAX_HELD: usize = 64 << 20;

#[global_allocator]
static ALLOCATOR: base::alloc_watch::Watching = base::alloc_watch::Watching;

use base::alloc_watch::on_this_thread;

use proptest::prelude::*;

/// Cases per parser and strategy: small enough for CI (the whole file runs in seconds).
const CASES: u32 = 256;

fn config() -> ProptestConfig {
    ProptestConfig {
        cases: CASES,
        failure_persistence: None,
        ..ProptestConfig::default()
    }
}

/// A mutation of a valid file.
#[derive(Clone, Debug)]
enum Mutation {
    Flip { at: usize, mask: u8 },
    Truncate { at: usize },
    Insert { at: usize, bytes: Vec<u8> },
    Overwrite { at: usize, bytes: Vec<u8> },
}

fn mutation() -> impl Strategy<Value = Vec<Mutation>> {
    let one = prop_oneof![
        (any::<usize>(), 1u8..=255).prop_map(|(at, mask)| Mutation::Flip { at, mask }),
        any::<usize>().prop_map(|at| Mutation::Truncate { at }),
        (any::<usize>(), prop::collection::vec(any::<u8>(), 1..9))
            .prop_map(|(at, bytes)| Mutation::Insert { at, bytes }),
        // Overwrites with large counts and special floats hit header fields.
        (
            any::<usize>(),
            prop_oneof![
                Just(u64::MAX.to_le_bytes().to_vec()),
                Just((1u64 << 40).to_le_bytes().to_vec()),
                Just(u32::MAX.to_le_bytes().to_vec()),
                Just(0u64.to_le_bytes().to_vec()),
                Just(f64::NAN.to_le_bytes().to_vec()),
                Just(f32::INFINITY.to_le_bytes().to_vec()),
                Just(b"9999999999".to_vec()),
                Just(b"nan".to_vec()),
            ]
        )
            .prop_map(|(at, bytes)| Mutation::Overwrite { at, bytes }),
    ];
    prop::collection::vec(one, 1..4)
}

fn apply(valid: &[u8], mutations: &[Mutation]) -> Vec<u8> {
    let mut b = valid.to_vec();
    for m in mutations {
        let n = b.len().max(1);
        match m {
            Mutation::Flip { at, mask } => {
                if !b.is_empty() {
                    b[at % n] ^= mask;
                }
            }
            Mutation::Truncate { at } => b.truncate(at % n),
            Mutation::Insert { at, bytes } => {
                let at = at % (b.len() + 1);
                b.splice(at..at, bytes.iter().copied());
            }
            Mutation::Overwrite { at, bytes } => {
                let at = at % n;
                for (i, x) in bytes.iter().enumerate() {
                    if let Some(slot) = b.get_mut(at + i) {
                        *slot = *x;
                    }
                }
            }
        }
    }
    b
}

/// Valid files of every format, made once.
struct Valid {
    dir: tempfile::TempDir,
    psf: Vec<u8>,
    poses: Vec<u8>,
    cameras_bin: Vec<u8>,
    images_bin: Vec<u8>,
    points_bin: Vec<u8>,
    cameras_txt: Vec<u8>,
    images_txt: Vec<u8>,
    points_txt: Vec<u8>,
    record: Vec<u8>,
    checkpoint: Vec<u8>,
    weights: Vec<u8>,
    ply: Vec<u8>,
    glb: Vec<u8>,
    gltf: Vec<u8>,
    spz: Vec<u8>,
}

fn valid() -> &'static Valid {
    static V: OnceLock<Valid> = OnceLock::new();
    V.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let read = |p: &Path| std::fs::read(p).unwrap();

        let psf = d.join("psf.npy");
        aberration::PsfGrid::delta(2, 3).save_npy(&psf).unwrap();

        // A 3-view capture, trained 4 steps for a checkpoint.
        let o = metasplat::splats::procedural::ProceduralOptions {
            width: 16,
            height: 12,
            views: 3,
            seed: 1,
        };
        let scene = metasplat::splats::procedural::write_capture(&d.join("scene"), &o).unwrap();
        let options = metasplat::settings::DataOptions {
            downsample: 1,
            ..Default::default()
        };
        let mode = metasplat::train::config::Mode::Plain;
        let data = metasplat::train::data::load(&scene, mode, &options).unwrap();
        let settings = metasplat::settings::TrainSettings {
            mode,
            iters: metasplat::settings::Iters::Steps(4),
            eval_every: Some(0),
            checkpoint_every: Some(4),
            ..Default::default()
        };
        let cfg = metasplat::train::config::TrainConfig::build(&settings, 0, &data);
        let ckpt = d.join("checkpoint.bin");
        metasplat::train::train(
            &cfg,
            &data,
            &metasplat::splats::device::Device::Cpu,
            Some(&ckpt),
            false,
            &mut |_| {},
        )
        .unwrap();

        let capture = scenes::open(
            &scene,
            &scenes::OpenOptions {
                resolution: scenes::Resolution::Downsample(1),
                ..Default::default()
            },
        )
        .unwrap();
        let c = &capture.cameras[0];
        let model = scenes::colmap::ColmapModel {
            cameras: vec![scenes::colmap::ColmapCamera {
                id: 1,
                model: scenes::CameraModel::SimpleRadial,
                width: c.width as u64,
                height: c.height as u64,
                params: vec![c.fx, c.cx, c.cy, 0.01],
            }],
            images: capture
                .cameras
                .iter()
                .enumerate()
                .map(|(i, cam)| {
                    let mut im = scenes::colmap::ColmapImage::from_world_to_camera(
                        i as u32 + 1,
                        1,
                        &format!("{}.png", cam.name),
                        &cam.world_to_camera,
                    );
                    im.points2d.push(scenes::colmap::Point2D {
                        xy: [3.0, 4.0],
                        point3d_id: 1,
                    });
                    im
                })
                .collect(),
            points: (0..3)
                .map(|i| scenes::colmap::ColmapPoint {
                    id: i + 1,
                    xyz: capture.points.positions[i as usize],
                    rgb: [1, 2, 3],
                    error: 0.1,
                    track: vec![scenes::colmap::TrackElement {
                        image_id: 1,
                        point2d_idx: 0,
                    }],
                })
                .collect(),
        };
        for format in [
            scenes::colmap::ModelFormat::Binary,
            scenes::colmap::ModelFormat::Text,
        ] {
            scenes::colmap::write_model(d, &model, format).unwrap();
        }

        // Restorer weights, version 2: the shipped header, a short stand-in record.
        let shipped = read(&Path::new(env!("CARGO_MANIFEST_DIR")).join("restore/weights/tiny.bin"));
        let n = u64::from_le_bytes(shipped[21..29].try_into().unwrap()) as usize;
        let mut weights = b"METASPLAT-RESTORER 2\n".to_vec();
        weights.extend_from_slice(&shipped[21..29 + n]);
        weights.extend_from_slice(&[7; 64]);
        let sum = base::hash::fnv1a64(&weights);
        weights.extend_from_slice(&sum.to_le_bytes());

        let g = splat::synthetic::random_box_scene(2, 12, 1);
        let ply = d.join("g.ply");
        splat::formats::ply::write_ply(&ply, &g).unwrap();
        let record = serde_json::json!({
            "psf": "psf.npy", "mode": "tiled", "sensor_px": null,
            "noise_gaussian_sigma": 0.01, "noise_poisson_scale": 0.0, "seed": 0,
            "width": 16, "height": 12, "images": 3, "source": "scene"
        });
        Valid {
            psf: read(&psf),
            poses: read(&scene.join("poses_bounds.npy")),
            cameras_bin: read(&d.join("cameras.bin")),
            images_bin: read(&d.join("images.bin")),
            points_bin: read(&d.join("points3D.bin")),
            cameras_txt: read(&d.join("cameras.txt")),
            images_txt: read(&d.join("images.txt")),
            points_txt: read(&d.join("points3D.txt")),
            record: record.to_string().into_bytes(),
            checkpoint: read(&ckpt),
            weights,
            ply: read(&ply),
            glb: splat::formats::glb::to_glb(&g).unwrap(),
            gltf: splat::formats::glb::to_gltf(&g).unwrap().into_bytes(),
            spz: splat::formats::spz::to_spz(&g).unwrap(),
            dir,
        }
    })
}

/// A fresh file holding `bytes`, named `name`, in a folder of its own (so parallel cases
/// never share a file).
fn file(name: &str, bytes: &[u8]) -> (tempfile::TempDir, PathBuf) {
    let dir = tempfile::tempdir_in(valid().dir.path()).unwrap();
    let path = dir.path().join(name);
    std::fs::write(&path, bytes).unwrap();
    (dir, path)
}

/// Every parser on `bytes` as the file it is meant for; results are ignored, panics and
/// holding more than [`MAX_HELD`] are not.
fn parse_as(kind: &str, bytes: &[u8]) {
    valid();
    let ((), usage) = on_this_thread(|| parse_unwatched(kind, bytes));
    assert!(
        usage.peak <= MAX_HELD,
        "parsing {} bytes as {kind} held {} bytes at once (largest request {})",
        bytes.len(),
        usage.peak,
        usage.largest
    );
}

fn parse_unwatched(kind: &str, bytes: &[u8]) {
    match kind {
        "npy" => {
            let (_d, p) = file("psf.npy", bytes);
            let _ = aberration::PsfGrid::load_npy(&p);
            let _ = base::npy::read_f64(&p);
        }
        "poses" => {
            let (_d, p) = file("poses_bounds.npy", bytes);
            let _ = scenes::llff::read_poses_bounds(&p);
        }
        "cameras.bin" | "images.bin" | "points3D.bin" | "cameras.txt" | "images.txt"
        | "points3D.txt" => {
            let (_d, p) = file(kind, bytes);
            let _ = match kind.split('.').next().unwrap() {
                "cameras" => scenes::colmap::read_cameras(&p).map(|_| ()),
                "images" => scenes::colmap::read_images(&p).map(|_| ()),
                _ => scenes::colmap::read_points3d(&p).map(|_| ()),
            };
        }
        "record" => {
            let (d, _p) = file("aberration.json", bytes);
            let _ = scenes::AberrationRecord::read(d.path());
        }
        "checkpoint" => {
            let (_d, p) = file("checkpoint.bin", bytes);
            let _ = metasplat::train::checkpoint::load(&p);
        }
        "weights" => {
            let _ = restore::weights::parse(bytes, Path::new("w.bin"));
        }
        "ply" => {
            let _ = splat::formats::ply::parse_ply(Path::new("f.ply"), bytes);
        }
        "glb" => {
            let _ = splat::formats::glb::parse_glb(Path::new("f.glb"), bytes);
        }
        "gltf" => {
            let (_d, p) = file("f.gltf", bytes);
            let _ = splat::formats::glb::read_gltf(&p);
        }
        "spz" => {
            let _ = splat::formats::spz::parse_spz(Path::new("f.spz"), bytes);
        }
        other => panic!("no parser {other}"),
    }
}

const KINDS: [&str; 15] = [
    "npy",
    "poses",
    "cameras.bin",
    "images.bin",
    "points3D.bin",
    "cameras.txt",
    "images.txt",
    "points3D.txt",
    "record",
    "checkpoint",
    "weights",
    "ply",
    "glb",
    "gltf",
    "spz",
];

fn valid_bytes(kind: &str) -> &'static [u8] {
    let v = valid();
    match kind {
        "npy" => &v.psf,
        "poses" => &v.poses,
        "cameras.bin" => &v.cameras_bin,
        "images.bin" => &v.images_bin,
        "points3D.bin" => &v.points_bin,
        "cameras.txt" => &v.cameras_txt,
        "images.txt" => &v.images_txt,
        "points3D.txt" => &v.points_txt,
        "record" => &v.record,
        "checkpoint" => &v.checkpoint,
        "weights" => &v.weights,
        "ply" => &v.ply,
        "glb" => &v.glb,
        "gltf" => &v.gltf,
        "spz" => &v.spz,
        other => panic!("no file {other}"),
    }
}

#[test]
fn the_valid_files_parse() {
    for kind in KINDS {
        let bytes = valid_bytes(kind);
        let name = match kind {
            "npy" => "psf.npy",
            "poses" => "poses_bounds.npy",
            "record" => "aberration.json",
            "checkpoint" => "checkpoint.bin",
            "weights" => "w.bin",
            "ply" | "glb" | "gltf" | "spz" => &format!("f.{kind}"),
            colmap => colmap,
        };
        let (d, p) = file(name, bytes);
        let ok = match kind {
            "npy" => aberration::PsfGrid::load_npy(&p).is_ok(),
            "poses" => scenes::llff::read_poses_bounds(&p).is_ok(),
            "cameras.bin" | "cameras.txt" => scenes::colmap::read_cameras(&p).is_ok(),
            "images.bin" | "images.txt" => scenes::colmap::read_images(&p).is_ok(),
            "points3D.bin" | "points3D.txt" => scenes::colmap::read_points3d(&p).is_ok(),
            "record" => {
                std::fs::write(d.path().join("aberration.json"), bytes).unwrap();
                matches!(scenes::AberrationRecord::read(d.path()), Ok(Some(_)))
            }
            "checkpoint" => metasplat::train::checkpoint::load(&p).is_ok(),
            "weights" => restore::weights::parse(bytes, &p).is_ok(),
            "ply" => splat::formats::ply::parse_ply(&p, bytes).is_ok(),
            "glb" => splat::formats::glb::parse_glb(&p, bytes).is_ok(),
            "gltf" => splat::formats::glb::read_gltf(&p).is_ok(),
            "spz" => splat::formats::spz::parse_spz(&p, bytes).is_ok(),
            other => panic!("no parser {other}"),
        };
        assert!(ok, "the valid {kind} does not parse");
    }
}

#[test]
fn a_lying_size_does_not_size_an_allocation() {
    // An SPZ header declaring 50 million splats of degree 3 in a few hundred bytes.
    let g = splat::synthetic::random_box_scene(2, 12, 3);
    let spz = splat::formats::spz::to_spz(&g).unwrap();
    let mut raw = Vec::new();
    std::io::Read::read_to_end(&mut flate2_decode(&spz), &mut raw).unwrap();
    raw[8..12].copy_from_slice(&50_000_000u32.to_le_bytes());
    parse_as("spz", &flate2_encode(&raw));
}

proptest! {
    #![proptest_config(config())]

    #[test]
    fn random_bytes_never_panic(kind in prop::sample::select(KINDS.to_vec()),
                                bytes in prop::collection::vec(any::<u8>(), 0..512)) {
        parse_as(kind, &bytes);
    }

    #[test]
    fn random_bytes_after_a_valid_header_never_panic(
        kind in prop::sample::select(KINDS.to_vec()),
        keep in 0usize..200,
        tail in prop::collection::vec(any::<u8>(), 0..256),
    ) {
        let valid = valid_bytes(kind);
        let mut bytes = valid[..keep.min(valid.len())].to_vec();
        bytes.extend(tail);
        parse_as(kind, &bytes);
    }
}

/// The shipped weights (version 1: no checksum, so a damaged record reaches burn's reader).
fn shipped_weights() -> &'static [u8] {
    static W: OnceLock<Vec<u8>> = OnceLock::new();
    W.get_or_init(|| {
        std::fs::read(Path::new(env!("CARGO_MANIFEST_DIR")).join("restore/weights/tiny.bin"))
            .unwrap()
    })
}

proptest! {
    // Each case builds a network, so fewer cases.
    #![proptest_config(ProptestConfig { cases: 24, ..config() })]

    /// Mutations of the record's first 4 kB (its header and first tensors) in a file
    /// without a checksum: loading gives a network or an error naming the file, never a panic.
    #[test]
    fn mutated_weight_records_never_panic(m in mutation()) {
        let bytes = shipped_weights();
        let n = u64::from_le_bytes(bytes[21..29].try_into().unwrap()) as usize;
        let (head, record) = bytes.split_at(29 + n);
        let region = record.len().min(4096);
        let mut damaged = head.to_vec();
        damaged.extend(apply(&record[..region], &m));
        damaged.extend_from_slice(&record[region..]);
        let device = restore::Compute::Cpu.device().unwrap();
        let (loaded, usage) = on_this_thread(|| {
            restore::weights::load_bytes(&damaged, Path::new("w.bin"), &device, None, None)
                .map(|_| ())
        });
        if let Err(e) = loaded {
            prop_assert!(e.to_string().contains("w.bin"), "{e}");
        }
        prop_assert!(usage.peak <= MAX_HELD, "loading held {} bytes at once", usage.peak);
    }
}

// One property per format, so each gets its own budget of mutations.
macro_rules! mutations_of {
    ($($name:ident => $kind:expr),* $(,)?) => {
        proptest! {
            #![proptest_config(config())]
            $(
                #[test]
                fn $name(m in mutation()) {
                    parse_as($kind, &apply(valid_bytes($kind), &m));
                }
            )*
        }
    };
}

mutations_of! {
    mutated_npy_never_panics => "npy",
    mutated_poses_bounds_never_panics => "poses",
    mutated_cameras_bin_never_panics => "cameras.bin",
    mutated_images_bin_never_panics => "images.bin",
    mutated_points3d_bin_never_panics => "points3D.bin",
    mutated_cameras_txt_never_panics => "cameras.txt",
    mutated_images_txt_never_panics => "images.txt",
    mutated_points3d_txt_never_panics => "points3D.txt",
    mutated_aberration_json_never_panics => "record",
    mutated_checkpoint_never_panics => "checkpoint",
    mutated_weights_never_panics => "weights",
    mutated_ply_never_panics => "ply",
    mutated_glb_never_panics => "glb",
    mutated_gltf_never_panics => "gltf",
    mutated_spz_never_panics => "spz",
}

fn flate2_decode(bytes: &[u8]) -> flate2::read::GzDecoder<&[u8]> {
    flate2::read::GzDecoder::new(bytes)
}

fn flate2_encode(raw: &[u8]) -> Vec<u8> {
    use std::io::Write;
    let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
    e.write_all(raw).unwrap();
    e.finish().unwrap()
}
