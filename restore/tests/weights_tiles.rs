//! Weights files, tiled inference, a few training steps, input photos.

use aberration::PsfGrid;
use burn::tensor::{Device, Distribution, Tensor};
use restore::tiles::{Planes, round_up, tiled};
use restore::weights::{self, Header, PsfFingerprint};
use restore::{RestoreError, RestorerConfig, RestorerNet};

fn header(cfg: &RestorerConfig, psf: &PsfGrid) -> Header {
    Header {
        config: cfg.clone(),
        psf: PsfFingerprint::of(psf),
        trained_psf_px: None,
        family: None,
        provenance: serde_json::json!({"test": true}),
    }
}

fn psf_a() -> PsfGrid {
    PsfGrid::delta(3, 5)
}

fn psf_b() -> PsfGrid {
    let k = [0.0f32, 0.25, 0.5, 0.25, 0.0];
    let mut data = vec![];
    for _ in 0..9 * 3 {
        for y in 0..5 {
            for x in 0..5 {
                data.push(k[y] * k[x] * 4.0 / 4.0);
            }
        }
    }
    PsfGrid::from_planar(3, 5, data).unwrap()
}

fn outputs(net: &RestorerNet, x: &Tensor<4>) -> Vec<u32> {
    net.forward(x.clone())
        .try_into_vec_as::<f32>()
        .unwrap()
        .into_iter()
        .map(f32::to_bits)
        .collect()
}

#[test]
fn save_then_load_gives_bit_identical_outputs() {
    let device = Device::flex();
    device.seed(11);
    let cfg = RestorerConfig::tiny();
    let net = RestorerNet::new(&cfg, &device);
    let x = Tensor::<4>::random([1, 39, 32, 64], Distribution::Default, &device);
    let before = outputs(&net, &x);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("w.bin");
    weights::save(&net, &header(&cfg, &psf_a()), &path).unwrap();
    let (loaded, h) = weights::load(&path, &device, Some(&cfg), Some(&psf_a())).unwrap();
    assert_eq!(h.provenance["test"], true);
    assert_eq!(outputs(&loaded, &x), before);
    // A differently seeded network really differs (the comparison above can fail).
    device.seed(12);
    let other = RestorerNet::new(&cfg, &device);
    assert_ne!(outputs(&other, &x), before);
}

#[test]
fn weights_of_another_config_or_psf_grid_are_refused_naming_both() {
    let device = Device::flex();
    let cfg = RestorerConfig::tiny();
    let net = RestorerNet::new(&cfg, &device);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("tiny.bin");
    weights::save(&net, &header(&cfg, &psf_a()), &path).unwrap();
    let small = RestorerConfig::small();
    let e = weights::load(&path, &device, Some(&small), None)
        .err()
        .unwrap()
        .to_string();
    assert!(
        e.contains("tiny.bin") && e.contains("'tiny'") && e.contains("'small'"),
        "{e}"
    );
    let e = weights::load(&path, &device, None, Some(&psf_b()))
        .err()
        .unwrap()
        .to_string();
    assert!(
        e.contains("tiny.bin") && e.contains("trained for one 3x3 grid"),
        "{e}"
    );
    // Garbage and truncation: errors naming the file, no panic.
    let bytes = std::fs::read(&path).unwrap();
    for cut in [0, 10, 30, bytes.len() / 2, bytes.len() - 1] {
        std::fs::write(&path, &bytes[..cut]).unwrap();
        let e = weights::load(&path, &device, None, None).err().unwrap();
        assert!(matches!(e, RestoreError::Weights { .. }), "cut {cut}: {e}");
        assert!(e.to_string().contains("tiny.bin"));
    }
    // A header that claims another config than the record holds.
    let mut h = header(&small, &psf_a());
    h.config = small;
    weights::save(&net, &h, &path).unwrap();
    let e = weights::load(&path, &device, None, None)
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("do not fit config 'small'"), "{e}");
}

#[test]
fn fine_tuning_loads_weights_under_another_residual_base_or_bank_k_but_not_another_network() {
    let device = Device::flex();
    device.seed(5);
    let cfg = RestorerConfig::tiny();
    let net = RestorerNet::new(&cfg, &device);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("tiny.bin");
    weights::save(&net, &header(&cfg, &psf_a()), &path).unwrap();
    let moved = RestorerConfig {
        residual_base: 2,
        adaptive_k: false,
        ..cfg.clone()
    };
    // Restoring under other switches is refused; fine-tuning takes them.
    assert!(weights::load(&path, &device, Some(&moved), None).is_err());
    let (tuned, h) = weights::load_into(&path, &device, &moved).unwrap();
    assert_eq!(h.config, cfg, "the header returned is the file's");
    // The same parameters, the output added to bank image 2 instead of 0: the two answers
    // differ by exactly those two images.
    let bank = Tensor::<4>::random([1, 39, 32, 32], Distribution::Default, &device);
    let (a, b) = (net.forward(bank.clone()), tuned.forward(bank.clone()));
    let shift = bank.clone().narrow(1, 6, 3) - bank.narrow(1, 0, 3);
    let err: f32 = (b - a - shift).abs().max().into_scalar();
    assert!(err < 1e-5, "{err}");
    let small = RestorerConfig::small();
    let e = weights::load_into(&path, &device, &small)
        .err()
        .unwrap()
        .to_string();
    assert!(
        e.contains("tiny.bin") && e.contains("'tiny'") && e.contains("'small'"),
        "{e}"
    );
}

/// `net` in the layout of version 3 (magic line, u64 header length, JSON header, burnpack
/// record, XXH3 of what precedes it), made here from burn's record as that version wrote it.
fn version_3(net: &RestorerNet, header: &Header) -> Vec<u8> {
    use burn::module::Module;
    let json = serde_json::to_vec(header).unwrap();
    let record = net.clone().into_record().into_bytes().unwrap();
    let mut bytes = b"METASPLAT-RESTORER 3\n".to_vec();
    bytes.extend_from_slice(&(json.len() as u64).to_le_bytes());
    bytes.extend_from_slice(&json);
    bytes.extend_from_slice(&record);
    let sum = base::hash::xxh3(&bytes);
    bytes.extend_from_slice(&sum.to_le_bytes());
    bytes
}

#[test]
fn a_flipped_byte_or_appended_bytes_are_refused_and_older_versions_still_load() {
    let device = Device::flex();
    let cfg = RestorerConfig::tiny();
    let net = RestorerNet::new(&cfg, &device);
    let x = Tensor::<4>::random([1, 39, 32, 32], Distribution::Default, &device);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("w.bin");
    weights::save(&net, &header(&cfg, &psf_a()), &path).unwrap();
    let good = std::fs::read(&path).unwrap();
    let (loaded, _) = weights::load(&path, &device, Some(&cfg), None).unwrap();
    assert_eq!(outputs(&loaded, &x), outputs(&net, &x));
    // A flip in the tensors' bytes (the middle, the last byte) is caught by the checksum; one
    // in the safetensors header is refused too; so are appended bytes. Each names the file.
    let n = good.len();
    for at in [n / 2, n - 1] {
        let mut bad = good.clone();
        bad[at] ^= 0x10;
        let e = weights::parse(&bad, &path).err().unwrap().to_string();
        assert!(
            e.contains("w.bin") && e.contains("checksum"),
            "byte {at}: {e}"
        );
    }
    for bad in [
        {
            let mut b = good.clone();
            b[40] ^= 0x10;
            b
        },
        [good.as_slice(), b"garbage"].concat(),
        good[..n - 3].to_vec(),
    ] {
        let e = weights::parse(&bad, &path).err().unwrap().to_string();
        assert!(
            e.contains("w.bin")
                && ["checksum", "damaged", "not a metasplat"]
                    .iter()
                    .any(|w| e.contains(w)),
            "{e}"
        );
    }
    // Version 3, as it was written, loads to the same network.
    let v3 = version_3(&net, &header(&cfg, &psf_a()));
    let (old, _) = weights::load_bytes(&v3, &path, &device, Some(&cfg), None).unwrap();
    assert_eq!(outputs(&old, &x), outputs(&net, &x));
    let m = v3.len();
    let mut bad = v3.clone();
    bad[m / 2] ^= 0x10;
    assert!(weights::parse(&bad, &path).is_err());
    // Version 2: the same body under its magic line, ending in its FNV-1a, still reads, and
    // a flip in it is still caught.
    let mut v2 = v3[..m - 8].to_vec();
    v2[..21].copy_from_slice(b"METASPLAT-RESTORER 2\n");
    let sum = base::hash::fnv1a64(&v2);
    v2.extend_from_slice(&sum.to_le_bytes());
    assert!(weights::load_bytes(&v2, &path, &device, Some(&cfg), None).is_ok());
    v2[m / 2] ^= 0x10;
    assert!(weights::parse(&v2, &path).is_err());
    // Version 1: the same bytes without the checksum and with the old magic line.
    let mut v1 = v3[..m - 8].to_vec();
    v1[..21].copy_from_slice(b"METASPLAT-RESTORER 1\n");
    let (h, _) = weights::parse(&v1, &path).unwrap();
    assert_eq!(h.config.name, "tiny");
}

/// A weights file is a safetensors file other tools read: every parameter a named f32
/// tensor, the header and the format in its metadata. Another safetensors file is refused as
/// not ours.
#[test]
fn weights_are_a_safetensors_file_with_the_header_in_its_metadata() {
    let device = Device::flex();
    let cfg = RestorerConfig::tiny();
    let net = RestorerNet::new(&cfg, &device);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("w.safetensors");
    weights::save(&net, &header(&cfg, &psf_a()), &path).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    let file = safetensors::SafeTensors::deserialize(&bytes).unwrap();
    let (_, meta) = safetensors::SafeTensors::read_metadata(&bytes).unwrap();
    let meta = meta.metadata().clone().unwrap();
    assert_eq!(meta["format"], "metasplat-restorer 4");
    let h: Header = serde_json::from_str(&meta["metasplat"]).unwrap();
    assert_eq!(h.config.name, "tiny");
    let values: usize = file
        .tensors()
        .iter()
        .map(|(name, t)| {
            assert_eq!(t.dtype(), safetensors::Dtype::F32, "{name}");
            t.shape().iter().product::<usize>()
        })
        .sum();
    use burn::module::Module;
    assert_eq!(values, net.num_params());
    // Someone else's safetensors file.
    let other = safetensors::serialize(
        file.tensors().into_iter().take(1),
        Some(std::collections::HashMap::new()),
    )
    .unwrap();
    let e = weights::parse(&other, &path).err().unwrap().to_string();
    assert!(
        e.contains("w.safetensors") && e.contains("not a metasplat"),
        "{e}"
    );
}

/// `net` with one weight tensor multiplied by `value` (NaN or infinity).
fn poisoned(net: RestorerNet, value: f32) -> RestorerNet {
    use burn::module::{Module, ModuleMapper, Param};
    struct Poison(usize, f32);
    impl ModuleMapper for Poison {
        fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
            self.0 += 1;
            if self.0 == 3 {
                let v = self.1;
                param.map(|t| t.mul_scalar(v))
            } else {
                param
            }
        }
    }
    net.map(&mut Poison(0, value))
}

#[test]
fn weights_with_a_non_finite_value_are_neither_written_nor_loaded() {
    use burn::module::Module;
    let device = Device::flex();
    let cfg = RestorerConfig::tiny();
    let dir = tempfile::tempdir().unwrap();
    for value in [f32::NAN, f32::INFINITY] {
        let net = poisoned(RestorerNet::new(&cfg, &device), value);
        assert_eq!(weights::non_finite_tensors(&net), 1, "{value}");
        let path = dir.path().join("w.bin");
        let e = weights::save(&net, &header(&cfg, &psf_a()), &path)
            .unwrap_err()
            .to_string();
        assert!(e.contains("w.bin") && e.contains("not written"), "{e}");
        assert!(!path.exists(), "a refused save left a file");
        // The same weights as a version 1 file (no checksum to refuse them on): refused at
        // load for what they hold.
        let json = serde_json::to_vec(&header(&cfg, &psf_a())).unwrap();
        let record = net.clone().into_record().into_bytes().unwrap();
        let mut v1 = b"METASPLAT-RESTORER 1\n".to_vec();
        v1.extend_from_slice(&(json.len() as u64).to_le_bytes());
        v1.extend_from_slice(&json);
        v1.extend_from_slice(&record);
        let e = weights::load_bytes(&v1, &path, &device, Some(&cfg), None)
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("NaN or infinite"), "{e}");
    }
    // The network unpoisoned loads from the same construction.
    let net = RestorerNet::new(&cfg, &device);
    assert_eq!(weights::non_finite_tensors(&net), 0);
}

/// A local stand-in for the network: 3×3 zero-padded box filter of the first three planes.
fn box3(x: &Planes) -> Planes {
    let (h, w) = (x.h, x.w);
    let mut data = vec![0.0; 3 * h * w];
    for c in 0..3 {
        for y in 0..h as isize {
            for xx in 0..w as isize {
                let mut s = 0.0;
                for dy in -1..=1 {
                    for dx in -1..=1 {
                        let (yy, x2) = (y + dy, xx + dx);
                        if (0..h as isize).contains(&yy) && (0..w as isize).contains(&x2) {
                            s += x.data[(c * h + yy as usize) * w + x2 as usize];
                        }
                    }
                }
                data[(c * h + y as usize) * w + xx as usize] = s / 9.0;
            }
        }
    }
    Planes { c: 3, h, w, data }
}

#[test]
fn tiled_inference_equals_whole_image_inference_inside_tile_interiors() {
    let (h, w) = (70, 101);
    let mut rng = 12345u64;
    let data: Vec<f32> = (0..39 * h * w)
        .map(|_| {
            rng = rng
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (rng >> 40) as f32 / (1u64 << 24) as f32
        })
        .collect();
    let x = Planes { c: 39, h, w, data }.padded(round_up(h, 32), round_up(w, 32));
    assert_eq!((x.h, x.w), (96, 128));
    let whole = box3(&x);
    let (tile, overlap) = (64, 32);
    let t = tiled(&x, tile, overlap, |p| Ok::<_, ()>(box3(p))).unwrap();
    // Tile starts are 0 and 32 (rows) and 0, 32, 64 (columns); a pixel is interior when it
    // is more than one pixel from every inner tile edge.
    let inner_edges = |n: usize| -> Vec<usize> {
        let s = restore::tiles::starts(n, tile, overlap);
        s.iter()
            .flat_map(|&a| [a, a + tile])
            .filter(|&e| e > 0 && e < n)
            .collect()
    };
    let (ey, ex) = (inner_edges(x.h), inner_edges(x.w));
    let far = |p: usize, edges: &[usize]| edges.iter().all(|&e| p + 1 < e || p > e);
    let mut worst: f32 = 0.0;
    let mut near_edge_diff: f32 = 0.0;
    for c in 0..3 {
        for y in 0..x.h {
            for xx in 0..x.w {
                let i = (c * x.h + y) * x.w + xx;
                let d = (t.data[i] - whole.data[i]).abs();
                if far(y, &ey) && far(xx, &ex) {
                    worst = worst.max(d);
                } else {
                    near_edge_diff = near_edge_diff.max(d);
                }
            }
        }
    }
    assert!(worst < 1e-4, "{worst}");
    // The stand-in does see tile edges: without blending weights these would show.
    assert!(near_edge_diff > 0.0);
    // Padding mirrors the image (half-sample symmetric) and keeps the original in place.
    assert_eq!(x.cropped(h, w).data[..w], x.data[..w]);
}

#[test]
fn photos_with_alpha_or_16_bits_load_as_rgb_in_unit_range() {
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (40u32, 36u32);
    let rgba = image::RgbaImage::from_fn(w, h, |x, y| {
        image::Rgba([(x * 6) as u8, (y * 7) as u8, 200, (x + y) as u8])
    });
    let p8 = dir.path().join("alpha.png");
    rgba.save(&p8).unwrap();
    let rgb16 = image::ImageBuffer::<image::Rgb<u16>, Vec<u16>>::from_fn(w, h, |x, y| {
        image::Rgb([(x * 1600) as u16, (y * 1800) as u16, 65535])
    });
    let p16 = dir.path().join("deep.png");
    rgb16.save(&p16).unwrap();
    let a = restore::data::load_photo(&p8, 32).unwrap();
    assert_eq!((a.width, a.height), (40, 36));
    assert!(
        (a.get(10, 3, 0) - 60.0 / 255.0).abs() < 1e-6
            && (a.get(10, 3, 2) - 200.0 / 255.0).abs() < 1e-6
    );
    let d = restore::data::load_photo(&p16, 32).unwrap();
    assert!((d.get(10, 3, 0) - 16000.0 / 65535.0).abs() < 1e-6 && d.get(0, 0, 2) == 1.0);
    // Smaller than a training crop: refused naming the file.
    let e = restore::data::load_photo(&p8, 64)
        .err()
        .unwrap()
        .to_string();
    assert!(
        e.contains("alpha.png") && e.contains("smaller than the 64px"),
        "{e}"
    );
}

#[test]
fn a_header_knows_which_blur_scales_its_network_saw() {
    let mut h = header(&RestorerConfig::tiny(), &psf_a());
    assert!(h.fits_psf_px(19), "no record: trusted");
    h.trained_psf_px = Some([50, 57]);
    for (px, fits) in [
        (57, true),
        (45, true),
        (40, true),
        (39, false),
        (19, false),
        (71, true),
        (72, false),
    ] {
        assert_eq!(h.fits_psf_px(px), fits, "{px}");
    }
}

#[test]
fn tiling_that_the_network_cannot_take_is_refused() {
    let cfg = RestorerConfig::tiny();
    let device = Device::flex();
    let m = cfg.multiple();
    let r = || {
        restore::Restorer::new(
            RestorerNet::new(&cfg, &device),
            header(&cfg, &psf_a()),
            device.clone(),
        )
    };
    for (tile, overlap) in [(m + 1, 0), (0, 0), (2 * m, m)] {
        let err = r().with_tiling(tile, overlap).err().expect("refused");
        assert!(
            err.to_string().contains(&format!("multiple of {m}")),
            "{err}"
        );
    }
    let ok = r().with_tiling(2 * m, m / 2).unwrap();
    assert_eq!((ok.tile, ok.overlap), (2 * m, m / 2));
}

/// A 3×3 grid of Gaussians, `w` times wider per colour than the reference widths, widening
/// towards the corners: one lens of a made-up family.
fn lens(w: [f64; 3]) -> PsfGrid {
    let (g, k) = (3usize, 21usize);
    let c = (k / 2) as f64;
    let mut data = vec![];
    for cell in 0..g * g {
        let r = ((cell / g) as f64 - 1.0).hypot((cell % g) as f64 - 1.0);
        for (ch, w) in w.iter().enumerate() {
            let sigma = w * (1.2 + 0.5 * ch as f64) * (1.0 + 0.15 * r);
            let kernel: Vec<f32> = (0..k * k)
                .map(|i| {
                    let (y, x) = ((i / k) as f64 - c, (i % k) as f64 - c);
                    (-(x * x + y * y) / (2.0 * sigma * sigma)).exp() as f32
                })
                .collect();
            let s: f32 = kernel.iter().sum();
            data.extend(kernel.iter().map(|v| v / s));
        }
    }
    PsfGrid::from_planar(g, k, data).unwrap()
}

#[test]
fn weights_of_a_lens_family_load_for_its_grids_and_refuse_others_saying_both() {
    let device = Device::flex();
    let cfg = RestorerConfig::tiny();
    let net = RestorerNet::new(&cfg, &device);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("family.bin");
    let members = [lens([0.9, 1.0, 1.1]), lens([1.1, 1.0, 0.9])];
    let family = restore::coverage::Family {
        drawn: serde_json::json!({"focal_percent": 5}),
        envelope: restore::coverage::Envelope::of(&members).unwrap(),
    };
    let mut h = header(&cfg, &members[0]);
    h.trained_psf_px = Some([15, 140]);
    h.family = Some(family.clone());
    weights::save(&net, &h, &path).unwrap();
    // The header round-trips with its family and range.
    let (back, _) = weights::read(&path).unwrap();
    assert_eq!(back.family.as_ref(), Some(&family));
    assert_eq!(back.trained_psf_px, Some([15, 140]));
    assert_eq!(back.served_psf_px(), Some([12, 175]));
    // A lens between the two members loads, not only the one its fingerprint names.
    let inside = lens([1.0, 1.0, 1.0]);
    assert!(!back.psf.names(&inside));
    let why = back.serves(&inside).unwrap();
    assert!(why.contains("inside the lens family"), "{why}");
    assert!(weights::load(&path, &device, None, Some(&inside)).is_ok());
    // Another lens is refused naming the file, what the weights cover and what the grid is.
    for (other, says) in [
        (lens([0.5, 1.0, 2.0]), "width"),
        (PsfGrid::delta(3, 21), "window"),
        (PsfGrid::delta(5, 21), "5x5"),
    ] {
        let e = weights::load(&path, &device, None, Some(&other))
            .err()
            .unwrap()
            .to_string();
        assert!(
            e.contains("family.bin")
                && e.contains("family of 3x3 lenses")
                && e.contains("focal_percent")
                && e.contains("this grid is")
                && e.contains(says),
            "{e}"
        );
    }
    // Weights of one grid name that grid when refusing another.
    let e = header(&cfg, &members[0]).serves(&inside).unwrap_err();
    assert!(
        e.contains("one 3x3 grid of 21 px") && e.contains("this grid is 3x3 of 21 px"),
        "{e}"
    );
    // A header written before families (no key) reads as one grid.
    let json = serde_json::to_value(header(&cfg, &members[0])).unwrap();
    assert!(json.get("family").is_none());
    let old: Header = serde_json::from_value(json).unwrap();
    assert!(old.family.is_none());
}

/// Thirteen random "Wiener images" of a `w`×`h` photo.
fn random_bank(w: usize, h: usize, seed: u64) -> Vec<aberration::Image> {
    use rand::{RngExt, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    (0..aberration::wiener::BANK_SIZE)
        .map(|_| aberration::Image {
            width: w,
            height: h,
            data: (0..3 * w * h).map(|_| rng.random::<f32>()).collect(),
        })
        .collect()
}

#[test]
fn an_eight_member_ensemble_answers_a_mirrored_or_turned_photo_with_its_answer_turned_alike() {
    use restore::ensemble::members;
    let cfg = RestorerConfig::tiny();
    let device = Device::flex();
    device.seed(5);
    let m = cfg.multiple();
    let r = restore::Restorer::new(
        RestorerNet::new(&cfg, &device),
        header(&cfg, &psf_a()),
        device.clone(),
    );
    // One square tile with no padding, so that only the network's own asymmetry is left.
    let bank = random_bank(m, m, 3);
    let gap = |r: &restore::Restorer, s: &restore::ensemble::Symmetry| {
        let turned: Vec<_> = bank.iter().map(|b| s.apply(b)).collect();
        let a = s.apply(&r.restore_bank(&bank));
        let b = r.restore_bank(&turned);
        a.data
            .iter()
            .zip(&b.data)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0f32, f32::max)
    };
    let single_worst = members(8)[1..]
        .iter()
        .map(|s| gap(&r, s))
        .fold(0.0, f32::max);
    // The random network alone is far from equivariant (so the check below can fail)...
    assert!(single_worst > 1e-2, "{single_worst}");
    let r8 = r.with_ensemble(8).unwrap();
    for s in members(8) {
        // ...and the mean over the whole group is, up to the order of the sum.
        assert!(gap(&r8, s) < 1e-5, "{s:?}: {}", gap(&r8, s));
    }
    // The mean stays in the unit range.
    let one = r8.restore_bank(&bank);
    assert!(one.data.iter().all(|v| (0.0..=1.0).contains(v)));
}

#[test]
fn an_ensemble_size_other_than_1_2_4_or_8_is_refused() {
    let cfg = RestorerConfig::tiny();
    let device = Device::flex();
    let r = || {
        restore::Restorer::new(
            RestorerNet::new(&cfg, &device),
            header(&cfg, &psf_a()),
            device.clone(),
        )
    };
    for n in [0, 3, 16] {
        let err = r().with_ensemble(n).err().expect("refused").to_string();
        assert!(
            err.contains(&format!("ensemble of {n}")) && err.contains("1, 2, 4 or 8"),
            "{err}"
        );
    }
    assert_eq!(r().with_ensemble(4).unwrap().ensemble, 4);
}

/// Every float parameter's values, in visiting order.
fn parameter_values(net: &RestorerNet) -> Vec<Vec<f32>> {
    use burn::module::{Module, ModuleVisitor, Param};
    struct Collect(Vec<Vec<f32>>);
    impl ModuleVisitor for Collect {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            self.0.push(param.val().try_into_vec_as::<f32>().unwrap());
        }
    }
    let mut c = Collect(Vec::new());
    net.visit(&mut c);
    c.0
}

#[test]
fn the_average_of_networks_is_their_parameter_mean_and_refuses_unlike_members() {
    let device = Device::flex();
    let cfg = RestorerConfig::tiny();
    let dir = tempfile::tempdir().unwrap();
    let mut paths = vec![];
    let mut nets = vec![];
    for (i, seed) in [3u64, 4, 5].into_iter().enumerate() {
        device.seed(seed);
        let net = RestorerNet::new(&cfg, &device);
        let path = dir.path().join(format!("w{i}.bin"));
        let mut h = header(&cfg, &psf_a());
        h.trained_psf_px = Some([85, 140]);
        h.provenance = serde_json::json!({ "member": i });
        weights::save(&net, &h, &path).unwrap();
        paths.push(path);
        nets.push(net);
    }
    let (mean, h) = restore::average::average(&paths, &device).unwrap();
    let members: Vec<Vec<Vec<f32>>> = nets.iter().map(parameter_values).collect();
    let got = parameter_values(&mean);
    assert_eq!(got.len(), members[0].len());
    for (t, values) in got.iter().enumerate() {
        for (j, &v) in values.iter().enumerate() {
            let sum: f64 = members.iter().map(|m| f64::from(m[t][j])).sum();
            assert_eq!(v, (sum / 3.0) as f32, "parameter {t}, value {j}");
        }
    }
    // Not one of the members: the mean's answers differ from each.
    let x = Tensor::<4>::random([1, 39, 32, 32], Distribution::Default, &device);
    for net in &nets {
        assert_ne!(outputs(net, &x), outputs(&mean, &x));
    }
    assert_eq!(h.trained_psf_px, Some([85, 140]));
    let recorded = h.provenance["average_of"].as_array().unwrap();
    assert_eq!(recorded.len(), 3);
    assert_eq!(recorded[2]["provenance"]["member"], 2);
    // Saved, it loads for the first member's grid and restores as in memory.
    let out = dir.path().join("mean.bin");
    weights::save(&mean, &h, &out).unwrap();
    let (loaded, _) = weights::load(&out, &device, Some(&cfg), Some(&psf_a())).unwrap();
    assert_eq!(outputs(&loaded, &x), outputs(&mean, &x));

    // Refused, naming the member: another bank K, another scale range, one file alone.
    let fixed = cfg.clone().with_ablations(None, true, None).unwrap();
    let other = dir.path().join("fixed.bin");
    weights::save(&nets[0], &header(&fixed, &psf_a()), &other).unwrap();
    let e = restore::average::average(&[paths[0].clone(), other.clone()], &device)
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("fixed.bin") && e.contains("config"), "{e}");
    let wide = dir.path().join("wide.bin");
    let mut h = header(&cfg, &psf_a());
    h.trained_psf_px = Some([15, 140]);
    weights::save(&nets[1], &h, &wide).unwrap();
    let e = restore::average::average(&[paths[0].clone(), wide], &device)
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("wide.bin") && e.contains("scales"), "{e}");
    let e = restore::average::average(&paths[..1], &device)
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("two or more"), "{e}");
}
