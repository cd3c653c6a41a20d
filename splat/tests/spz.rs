//! SPZ both ways: values within the format's quantisation, renders close, bad files refused.

mod common;

use common::{random_scene, test_camera};
use glam::Vec3;
use splat::formats::spz::{parse_spz, read_spz, to_spz, write_spz};
use splat::{RenderSettings, render};

#[test]
fn round_trip_is_within_the_quantisation() {
    let dir = tempfile::tempdir().unwrap();
    for deg in 0..=3 {
        let g = random_scene(60 + deg as u64, 400, deg, (0.02, 0.3), 1.2);
        let path = dir.path().join(format!("s{deg}.spz"));
        write_spz(&path, &g).unwrap();
        let back = read_spz(&path).unwrap();
        assert_eq!((back.len(), back.sh_degree), (g.len(), deg));
        for i in 0..g.len() {
            // 12 fractional bits: half a step.
            assert!((back.means[i] - g.means[i]).abs().max_element() <= 0.5 / 4096.0 + 1e-6);
            // Log scale in steps of 1/16.
            assert!(
                (back.log_scales[i] - g.log_scales[i]).abs().max_element() <= 0.5 / 16.0 + 1e-6
            );
            let (a, b) = (
                splat::model::sigmoid(back.logit_opacities[i]),
                splat::model::sigmoid(g.logit_opacities[i]),
            );
            assert!((a - b).abs() <= 0.5 / 255.0 + 1e-6, "opacity {a} vs {b}");
            assert!(
                (back.sh_dc[i] - g.sh_dc[i]).abs().max_element() <= 0.5 / (255.0 * 0.15) + 1e-5
            );
            // Smallest three at 9 bits: the rotation angle moves by well under a degree.
            let q = g.rotations[i];
            let len = q.iter().map(|v| v * v).sum::<f32>().sqrt();
            let dot: f32 = back.rotations[i]
                .iter()
                .zip(q)
                .map(|(a, b)| a * b / len)
                .sum();
            assert!(
                dot.abs() > 0.9999,
                "rotation {:?} vs {q:?}",
                back.rotations[i]
            );
        }
        for (a, b) in back.sh_rest.iter().zip(&g.sh_rest) {
            let clamped = b.clamp(Vec3::splat(-1.0), Vec3::splat(127.0 / 128.0));
            assert!((*a - clamped).abs().max_element() <= 0.5 / 128.0 + 1e-6);
        }
        let cam = test_camera(48, 36, 40.0);
        let s = RenderSettings {
            sh_degree: deg,
            background: Vec3::new(0.1, 0.2, 0.3),
            antialiased: false,
        };
        let p = base::psnr_rgb(
            &render(&back, &cam, &s).unwrap().color,
            &render(&g, &cam, &s).unwrap().color,
        )
        .unwrap();
        assert!(p >= 38.0, "degree {deg}: {p} dB");
    }
}

#[test]
fn bad_files_are_refused_with_the_problem() {
    let p = std::path::Path::new("scene.spz");
    let g = random_scene(5, 50, 1, (0.05, 0.2), 1.0);
    let bytes = to_spz(&g).unwrap();
    for cut in [0, 5, 10, bytes.len() / 2, bytes.len() - 1] {
        let err = parse_spz(p, &bytes[..cut]).unwrap_err().to_string();
        assert!(err.contains("scene.spz"), "{err}");
    }
    let mut rng = base::SplitMix64::new(2);
    for _ in 0..300 {
        let mut b = bytes.clone();
        for _ in 0..3 {
            let i = (rng.next_u64() % b.len() as u64) as usize;
            b[i] = rng.next_u64() as u8;
        }
        let _ = parse_spz(p, &b);
    }
    // A hostile header: a billion splats in a tiny file is refused before any allocation.
    let mut raw = Vec::new();
    raw.extend(0x5053_474e_u32.to_le_bytes());
    raw.extend(3u32.to_le_bytes());
    raw.extend(1_000_000_000u32.to_le_bytes());
    raw.extend([0u8, 12, 0, 0]);
    let mut enc = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
    std::io::Write::write_all(&mut enc, &raw).unwrap();
    let err = parse_spz(p, &enc.finish().unwrap())
        .unwrap_err()
        .to_string();
    assert!(err.contains("1000000000"), "{err}");
    // Version 4 headers that lie are refused with what is wrong.
    let v4 = to_v4(&to_spz(&g).unwrap());
    for (bytes, says) in [
        (v4[..20].to_vec(), "truncated"),
        (with(&v4, 15, &[9]), "streams"),
        (
            with(&v4, 16, &1_000_000u32.to_le_bytes()),
            "table of contents",
        ),
        (
            with(&v4, 8, &(g.len() as u32 + 1).to_le_bytes()),
            "splats need",
        ),
        (with(&v4, 32, &u64::MAX.to_le_bytes()), "past the end"),
        (v4[..v4.len() - 3].to_vec(), "past the end"),
    ] {
        let err = parse_spz(p, &bytes).unwrap_err().to_string();
        assert!(err.contains(says), "expected '{says}': {err}");
    }
    // Positions beyond 24-bit fixed point are refused on writing.
    let mut far = g.clone();
    far.means[0].x = 1e4;
    assert!(to_spz(&far).is_err());
}

/// `bytes` with `patch` written at `at`.
fn with(bytes: &[u8], at: usize, patch: &[u8]) -> Vec<u8> {
    let mut v = bytes.to_vec();
    v[at..at + patch.len()].copy_from_slice(patch);
    v
}

/// A version 4 file with the same content as a version 3 one, laid out as splat-transform
/// writes it (a 32-byte header, the table of contents, one ZSTD frame per attribute).
fn to_v4(v3: &[u8]) -> Vec<u8> {
    use std::io::Read;
    let mut raw = Vec::new();
    flate2::read::GzDecoder::new(v3)
        .read_to_end(&mut raw)
        .unwrap();
    let n = u32::from_le_bytes(raw[8..12].try_into().unwrap()) as usize;
    let degree = raw[12] as usize;
    let rest = [0, 3, 8, 15][degree];
    let sizes = [9 * n, n, 3 * n, 3 * n, 4 * n, 3 * rest * n];
    let streams = if degree == 0 { 5 } else { 6 };
    let mut out = raw[..16].to_vec();
    out[4] = 4;
    out[15] = streams as u8;
    out.extend(32u32.to_le_bytes());
    out.resize(32, 0);
    let mut body = &raw[16..];
    let mut frames = Vec::new();
    for &size in &sizes[..streams] {
        let (part, tail) = body.split_at(size);
        body = tail;
        let frame =
            ruzstd::encoding::compress_to_vec(part, ruzstd::encoding::CompressionLevel::Fastest);
        out.extend((frame.len() as u64).to_le_bytes());
        out.extend((size as u64).to_le_bytes());
        frames.push(frame);
    }
    for f in frames {
        out.extend(f);
    }
    out
}

#[test]
fn version_4_reads_as_its_version_3_twin() {
    for deg in [0, 3] {
        let g = random_scene(80 + deg as u64, 300, deg, (0.02, 0.3), 1.2);
        let v3 = to_spz(&g).unwrap();
        let p = std::path::Path::new("twin.spz");
        let a = parse_spz(p, &v3).unwrap();
        let b = parse_spz(p, &to_v4(&v3)).unwrap();
        assert_eq!(a, b, "SH degree {deg}");
    }
}

#[global_allocator]
static ALLOCATOR: base::alloc_watch::Watching = base::alloc_watch::Watching;

/// A version 4 file of `n` splats of degree 0 whose five streams are each the ZSTD frame of
/// `content(declared size of the stream)`.
fn v4_file(n: usize, content: impl Fn(usize) -> Vec<u8>) -> Vec<u8> {
    let sizes = [9 * n, n, 3 * n, 3 * n, 4 * n];
    let mut out = Vec::new();
    out.extend(0x5053_474eu32.to_le_bytes());
    out.extend(4u32.to_le_bytes());
    out.extend((n as u32).to_le_bytes());
    out.extend([0u8, 12, 0, 5]);
    out.extend(32u32.to_le_bytes());
    out.resize(32, 0);
    let frames: Vec<Vec<u8>> = sizes
        .iter()
        .map(|&size| {
            ruzstd::encoding::compress_to_vec(
                &content(size)[..],
                ruzstd::encoding::CompressionLevel::Fastest,
            )
        })
        .collect();
    for (size, frame) in sizes.iter().zip(&frames) {
        out.extend((frame.len() as u64).to_le_bytes());
        out.extend((*size as u64).to_le_bytes());
    }
    for f in frames {
        out.extend(f);
    }
    out
}

/// Bytes that do not compress.
fn noise(len: usize, seed: u64) -> Vec<u8> {
    let mut x = seed;
    (0..len)
        .map(|_| {
            x = x
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (x >> 56) as u8
        })
        .collect()
}

/// A count within the memory budget over streams that hold a sliver of it: refused for the
/// data missing, having reserved about what the streams hold, not what the header claims.
#[test]
fn a_count_far_above_the_data_reserves_what_the_data_holds() {
    const N: usize = 40_000_000;
    const HELD: usize = 1 << 20;
    let out = v4_file(N, |_| noise(HELD, 7));
    assert!(out.len() < 6 * HELD, "the file holds about 5 MB");
    base::alloc_watch::largest();
    let err = parse_spz(std::path::Path::new("short.spz"), &out)
        .unwrap_err()
        .to_string();
    let largest = base::alloc_watch::largest();
    assert!(
        err.contains("short.spz") && err.contains(&format!("decompresses to {HELD} bytes")),
        "{err}"
    );
    // The header claims 360 MB for the first stream alone.
    assert!(
        largest <= 9 * N / 16 + HELD,
        "{largest} bytes reserved at once"
    );

    // Beyond the budget (50 M splats of degree 3 are 11 GiB), nothing is decompressed.
    let mut over = out.clone();
    over[8..12].copy_from_slice(&50_000_000u32.to_le_bytes());
    over[12] = 3;
    base::alloc_watch::largest();
    let err = parse_spz(std::path::Path::new("short.spz"), &over)
        .unwrap_err()
        .to_string();
    assert!(err.contains("GiB a splat file may take"), "{err}");
    assert!(base::alloc_watch::largest() < 1 << 20);
}

/// Streams that really decompress to what a huge header declares (ZSTD turns a few bytes into
/// 128 KB of zeros): a file of a few kilobytes holding millions of identical splats is refused
/// before anything is decompressed, while a real scene whose higher SH bands are all zero (the
/// most compressible legal file) still reads.
#[test]
fn a_decompression_bomb_is_refused_before_it_expands() {
    const N: usize = 5_000_000;
    let bomb = v4_file(N, |size| vec![0u8; size]);
    assert!(bomb.len() < 20_000, "{} bytes", bomb.len());
    base::alloc_watch::largest();
    let err = parse_spz(std::path::Path::new("bomb.spz"), &bomb)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("bomb.spz") && err.contains("decompression bomb"),
        "{err}"
    );
    assert!(base::alloc_watch::largest() < 1 << 20);

    let mut g = random_scene(5, 20_000, 3, (0.02, 0.3), 1.2);
    g.sh_rest.iter_mut().for_each(|c| *c = Vec3::ZERO);
    let v3 = to_spz(&g).unwrap();
    let p = std::path::Path::new("flat.spz");
    assert_eq!(
        parse_spz(p, &to_v4(&v3)).unwrap(),
        parse_spz(p, &v3).unwrap()
    );
}

/// A gzip file of several members (what `cat a.gz b.gz` or a streaming writer makes) is one
/// valid stream: read whole, as gunzip reads it.
#[test]
fn a_multi_member_gzip_file_reads_as_one_stream() {
    use std::io::{Read, Write};
    let g = random_scene(5, 200, 1, (0.02, 0.3), 1.0);
    let one = to_spz(&g).unwrap();
    let mut raw = Vec::new();
    flate2::read::GzDecoder::new(&one[..])
        .read_to_end(&mut raw)
        .unwrap();
    let mut two = Vec::new();
    for part in [&raw[..raw.len() / 3], &raw[raw.len() / 3..]] {
        let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
        e.write_all(part).unwrap();
        two.extend(e.finish().unwrap());
    }
    let p = std::path::Path::new("members.spz");
    assert_eq!(parse_spz(p, &two).unwrap(), parse_spz(p, &one).unwrap());
}
