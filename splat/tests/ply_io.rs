//! PLY read/write: bit-exact round trips, alternative encodings, and typed errors.

mod common;

use std::path::Path;

use common::random_scene;
use glam::Vec3;
use splat::formats::ply::{parse_ply, read_ply, write_ply};
use splat::{Gaussians, SplatError};

fn bits(g: &Gaussians) -> Vec<u32> {
    let mut b = vec![g.sh_degree, g.len() as u32];
    b.extend(
        g.means
            .iter()
            .chain(&g.log_scales)
            .chain(&g.sh_dc)
            .chain(&g.sh_rest)
            .flat_map(|v| v.to_array())
            .chain(g.rotations.iter().flatten().copied())
            .chain(g.logit_opacities.iter().copied())
            .map(f32::to_bits),
    );
    b
}

fn tricky_scene(deg: u32) -> Gaussians {
    let mut g = random_scene(deg as u64 + 1, 17, deg, (1e-3, 10.0), 3.0);
    g.means[0] = Vec3::new(-0.0, f32::MIN_POSITIVE / 4.0, f32::MAX);
    g.logit_opacities[1] = -60.0;
    g.rotations[2] = [0.0; 4];
    g
}

/// The float32 body of an INRIA file written by `write_ply`, and its property names.
fn split_file(bytes: &[u8]) -> (Vec<String>, usize, &[u8]) {
    let end = bytes
        .windows(11)
        .position(|w| w == b"end_header\n")
        .unwrap()
        + 11;
    let header = std::str::from_utf8(&bytes[..end]).unwrap();
    let names: Vec<String> = header
        .lines()
        .filter_map(|l| l.strip_prefix("property float ").map(str::to_string))
        .collect();
    let n = header
        .lines()
        .find_map(|l| l.strip_prefix("element vertex "))
        .unwrap()
        .parse()
        .unwrap();
    (names, n, &bytes[end..])
}

fn header(format: &str, n: usize, names: &[String], extra: &str) -> String {
    let mut h = format!("ply\nformat {format} 1.0\ncomment test\n{extra}element vertex {n}\n");
    for p in names {
        h += &format!("property float {p}\n");
    }
    h + "end_header\n"
}

#[test]
fn binary_round_trip_is_bit_exact_for_every_degree() {
    let dir = tempfile::tempdir().unwrap();
    for deg in 0..=3 {
        let g = tricky_scene(deg);
        let path = dir.path().join(format!("scene{deg}.ply"));
        write_ply(&path, &g).unwrap();
        let back = read_ply(&path).unwrap();
        assert_eq!(bits(&back), bits(&g), "degree {deg}");
    }
    // Only the outputs are left behind: no temporary files.
    let names: Vec<_> = std::fs::read_dir(dir.path()).unwrap().collect();
    assert_eq!(names.len(), 4);
}

#[test]
fn inria_layout_is_written() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("s.ply");
    write_ply(&path, &tricky_scene(3)).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    let (names, n, body) = split_file(&bytes);
    assert_eq!(n, 17);
    assert_eq!(names.len(), 62);
    assert_eq!(
        &names[..9],
        &[
            "x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"
        ]
    );
    assert_eq!(names[9], "f_rest_0");
    assert_eq!(names[53], "f_rest_44");
    assert_eq!(
        &names[54..],
        &[
            "opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"
        ]
    );
    assert_eq!(body.len(), 17 * 62 * 4);
    // f_rest is channel-major: f_rest_15 is the green weight of basis 1 of vertex 0.
    let g = tricky_scene(3);
    let f = |k: usize| f32::from_le_bytes(body[k * 4..k * 4 + 4].try_into().unwrap());
    assert_eq!(f(9 + 15).to_bits(), g.sh_rest[0].y.to_bits());
    assert_eq!(f(54).to_bits(), g.logit_opacities[0].to_bits());
}

#[test]
fn ascii_big_endian_and_extra_elements_read_identically() {
    let g = tricky_scene(2);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("s.ply");
    write_ply(&path, &g).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    let (names, n, body) = split_file(&bytes);
    let floats: Vec<f32> = body
        .chunks(4)
        .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
        .collect();

    let extra = "element camera 2\nproperty uchar id\nproperty list uchar int idx\n";
    let mut ascii = header("ascii", n, &names, extra);
    ascii += "7 2 1 2\n8 0\n";
    for row in floats.chunks(names.len()) {
        let line: Vec<String> = row.iter().map(|v| format!("{v}")).collect();
        ascii += &line.join(" ");
        ascii += "\n";
    }
    let back = parse_ply(Path::new("ascii.ply"), ascii.as_bytes()).unwrap();
    assert_eq!(bits(&back), bits(&g));

    let mut be = header(
        "binary_big_endian",
        n,
        &names,
        "element skip 3\nproperty double a\n",
    )
    .into_bytes();
    be.extend([0u8; 24]);
    for v in &floats {
        be.extend(v.to_be_bytes());
    }
    let back = parse_ply(Path::new("be.ply"), &be).unwrap();
    assert_eq!(bits(&back), bits(&g));
    // Bytes past the last declared vertex are a count that lies, not padding to ignore.
    be.extend(b"trailing bytes");
    assert!(parse_ply(Path::new("be.ply"), &be).is_err());
}

#[test]
fn files_without_normals_and_lower_degree_read() {
    let names: Vec<String> = [
        "x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2",
        "rot_0", "rot_1", "rot_2", "rot_3",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    let mut bytes = header("binary_little_endian", 2, &names, "").into_bytes();
    for v in 0..28 {
        bytes.extend((v as f32 * 0.5).to_le_bytes());
    }
    let g = parse_ply(Path::new("n.ply"), &bytes).unwrap();
    assert_eq!(g.sh_degree, 0);
    assert_eq!(g.means[1], Vec3::new(7.0, 7.5, 8.0));
    assert_eq!(g.logit_opacities[0], 3.0);
    assert_eq!(g.rotations[1], [12.0, 12.5, 13.0, 13.5]);
}

#[test]
fn real_donut_file_reads() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/ply/donut_sh0.ply");
    if !path.exists() {
        eprintln!("SKIP: {} not found", path.display());
        return;
    }
    let g = read_ply(&path).unwrap();
    assert_eq!(g.len(), 45624);
    assert_eq!(g.sh_degree, 0);
    assert!(g.means.iter().all(|m| m.is_finite()));
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("donut.ply");
    write_ply(&out, &g).unwrap();
    assert_eq!(bits(&read_ply(&out).unwrap()), bits(&g));
}

fn expect_err(bytes: &[u8], needle: &str) {
    match parse_ply(Path::new("/data/broken.ply"), bytes) {
        Err(e @ SplatError::Ply { .. }) => {
            let msg = e.to_string();
            assert!(msg.contains("/data/broken.ply"), "{msg}");
            assert!(msg.contains(needle), "expected '{needle}' in: {msg}");
        }
        other => panic!("expected a PLY error containing '{needle}', got {other:?}"),
    }
}

#[test]
fn corrupt_files_give_errors_naming_file_and_problem() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("s.ply");
    write_ply(&path, &tricky_scene(1)).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    let (names, n, body) = split_file(&bytes);

    expect_err(&bytes[..bytes.len() - 3], "truncated");
    expect_err(&bytes[..40], "end_header");
    expect_err(b"plx\nformat ascii 1.0\nend_header\n", "magic");
    expect_err(
        b"ply\nformat ascii 1.0\nelement vertex x\nend_header\n",
        "malformed header",
    );
    expect_err(b"ply\nformat ascii 1.0\nend_header\n", "vertex");
    let mut huge = header("ascii", usize::MAX, &names, "");
    huge += "1 2";
    expect_err(huge.as_bytes(), "truncated");
    let mut huge = header("binary_little_endian", usize::MAX / 2, &names, "").into_bytes();
    huge.extend(body);
    expect_err(&huge, "truncated");

    let missing: Vec<String> = names.iter().filter(|p| *p != "rot_3").cloned().collect();
    let mut b = header("binary_little_endian", n, &missing, "").into_bytes();
    b.extend(body);
    expect_err(&b, "'rot_3'");

    let odd: Vec<String> = names.iter().filter(|p| *p != "f_rest_8").cloned().collect();
    let mut b = header("binary_little_endian", n, &odd, "").into_bytes();
    b.extend(body);
    expect_err(&b, "f_rest");

    let mut b = bytes.clone();
    let at = bytes.len() - body.len() + 4 * 5;
    b[at..at + 4].copy_from_slice(&f32::NAN.to_le_bytes());
    expect_err(&b, "not finite");

    let mut ascii = header("ascii", 1, &names, "");
    ascii += "1 2 3";
    expect_err(ascii.as_bytes(), "truncated");
    let mut ascii = header("ascii", 1, &names, "");
    ascii += "abc\n";
    expect_err(ascii.as_bytes(), "cannot parse 'abc'");

    match read_ply(dir.path().join("nope.ply")) {
        Err(SplatError::Io { path, .. }) => assert!(path.ends_with("nope.ply")),
        other => panic!("{other:?}"),
    }
}

#[test]
fn refusing_to_write_nan_leaves_the_old_file_intact() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("s.ply");
    let g = tricky_scene(0);
    write_ply(&path, &g).unwrap();
    let mut bad = g.clone();
    bad.means[3].x = f32::NAN;
    assert!(write_ply(&path, &bad).is_err());
    assert_eq!(bits(&read_ply(&path).unwrap()), bits(&g));
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
}

#[test]
fn real_donut_file_renders() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/ply/donut_sh0.ply");
    if !path.exists() {
        eprintln!("SKIP: {} not found", path.display());
        return;
    }
    let g = read_ply(&path).unwrap();
    let (lo, hi) = g
        .means
        .iter()
        .fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), m| {
            (lo.min(*m), hi.max(*m))
        });
    let centre = (lo + hi) * 0.5;
    let size = (hi - lo).length();
    let cam = splat::Camera::look_at(
        centre + Vec3::new(0.3, -0.4, -1.0).normalize() * size * 1.2,
        centre,
        Vec3::Y,
        48.0,
        48.0,
        64,
        48,
    );
    let out = splat::render(&g, &cam, &splat::RenderSettings::default()).unwrap();
    let covered = out.alpha.iter().filter(|&&a| a > 0.5).count();
    assert!(covered > 64 * 48 / 20, "donut covers {covered} pixels");
    assert!(out.color.iter().all(|c| c.is_finite()));
}

/// `(names, floats)` of the INRIA file `write_ply` makes for `g`.
fn written_floats(g: &Gaussians) -> (Vec<String>, usize, Vec<f32>) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("s.ply");
    write_ply(&path, g).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    let (names, n, body) = split_file(&bytes);
    let floats = body
        .chunks(4)
        .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
        .collect();
    (names, n, floats)
}

#[test]
fn repeated_element_or_property_names_are_errors_not_misreads() {
    // ply-rs-bw keys its header by name: without the guard a repeated name drops a
    // declaration and the body is decoded shifted.
    let g = tricky_scene(0);
    let (names, n, floats) = written_floats(&g);
    let mut dup = names.clone();
    dup.push("x".into());
    let mut b = header("binary_little_endian", n, &dup, "").into_bytes();
    for row in floats.chunks(names.len()) {
        row.iter().for_each(|v| b.extend(v.to_le_bytes()));
        b.extend(9.0f32.to_le_bytes());
    }
    expect_err(&b, "declared twice");

    let h = header(
        "binary_little_endian",
        n,
        &names,
        "element camera 1\nproperty uchar id\n",
    )
    .replace(
        "end_header\n",
        "element camera 1\nproperty uchar id\nend_header\n",
    );
    let mut b = h.into_bytes();
    b.push(7);
    floats.iter().for_each(|v| b.extend(v.to_le_bytes()));
    b.push(8);
    expect_err(&b, "declared twice");
}

#[test]
fn binary_elements_without_properties_are_skipped_whatever_their_count() {
    // ply-rs-bw would loop `count` times reading nothing (here: forever).
    let g = tricky_scene(1);
    let (names, n, floats) = written_floats(&g);
    let extra = format!("element marker {}\n", usize::MAX);
    let mut b = header("binary_little_endian", n, &names, &extra).into_bytes();
    floats.iter().for_each(|v| b.extend(v.to_le_bytes()));
    let back = parse_ply(Path::new("m.ply"), &b).unwrap();
    assert_eq!(bits(&back), bits(&g));
}

#[test]
fn ascii_vertex_lines_must_hold_exactly_the_declared_values() {
    let g = tricky_scene(0);
    let (names, n, floats) = written_floats(&g);
    let lines: Vec<String> = floats
        .chunks(names.len())
        .map(|row| {
            let s: Vec<String> = row.iter().map(|v| format!("{v}")).collect();
            s.join(" ")
        })
        .collect();
    let mut ascii = header("ascii", n, &names, "");
    ascii += &format!("{} 1.5\n", lines[0]);
    ascii += &lines[1..].join("\n");
    expect_err(ascii.as_bytes(), "has 18 values, the header declares 17");
    let mut ascii = header("ascii", n, &names, "");
    ascii += &lines.join("\n");
    assert_eq!(
        bits(&parse_ply(Path::new("a.ply"), ascii.as_bytes()).unwrap()),
        bits(&g)
    );
}

#[test]
fn mutated_files_give_models_or_errors_never_panics() {
    // Byte flips, truncations, deletions, insertions and token swaps of small valid ASCII,
    // big- and little-endian files (with list elements). A panic inside ply-rs-bw would be
    // caught and reported as "panicked"; none may occur.
    let g = tricky_scene(1).gather(&[0, 1, 2]);
    let (names, n, floats) = written_floats(&g);
    let mut le = header(
        "binary_little_endian",
        n,
        &names,
        "element face 2\nproperty list uchar int idx\n",
    )
    .into_bytes();
    le.extend([2, 1, 0, 0, 0, 2, 0, 0, 0, 0]);
    floats.iter().for_each(|v| le.extend(v.to_le_bytes()));
    let mut be = header(
        "binary_big_endian",
        n,
        &names,
        "element e 1\nproperty double a\nproperty list int short l\n",
    )
    .into_bytes();
    be.extend([0u8; 8]);
    be.extend([0, 0, 0, 1, 0, 5]);
    floats.iter().for_each(|v| be.extend(v.to_be_bytes()));
    let mut ascii = header(
        "ascii",
        n,
        &names,
        "element face 1\nproperty list uchar int i\n",
    );
    ascii += "3 0 1 2\n";
    for row in floats.chunks(names.len()) {
        let s: Vec<String> = row.iter().map(|v| format!("{v}")).collect();
        ascii += &s.join(" ");
        ascii += "\n";
    }
    let seeds = [le, be, ascii.into_bytes()];
    const TOKENS: &[&str] = &[
        "ply",
        "format",
        "ascii",
        "binary_big_endian",
        "element",
        "property",
        "list",
        "uchar",
        "int",
        "float",
        "double",
        "vertex",
        "end_header",
        "comment",
        "\n",
        "\r\n",
        " ",
        "0",
        "1",
        "-1",
        "4294967295",
        "18446744073709551615",
        "99999999999999999999",
        "1e40",
        "nan",
        "x",
        "f_rest_0",
        "\u{ff}",
    ];
    let mut rng = base::SplitMix64::new(7);
    let mut below = |n: usize| (rng.next_u64() % n.max(1) as u64) as usize;
    let (mut ok, mut errors) = (0, 0);
    for it in 0..20_000 {
        let mut d = seeds[it % seeds.len()].clone();
        for _ in 0..1 + below(3) {
            let i = below(d.len() + 1);
            match below(5) {
                0 if i < d.len() => d[i] = below(256) as u8,
                1 => d.truncate(i),
                2 => {
                    let j = (i + below(8)).min(d.len());
                    d.drain(i..j);
                }
                3 => {
                    let t = TOKENS[below(TOKENS.len())];
                    d.splice(i..i, t.bytes());
                }
                _ => {
                    // Replace the space-delimited token starting at or after `i`.
                    let Some(a) = d[i..].iter().position(|&c| c == b' ').map(|p| i + p + 1) else {
                        continue;
                    };
                    let b = d[a..]
                        .iter()
                        .position(|&c| c == b' ' || c == b'\n')
                        .map_or(d.len(), |p| a + p);
                    let t = TOKENS[below(TOKENS.len())];
                    d.splice(a..b, t.bytes());
                }
            }
        }
        match parse_ply(Path::new("/fuzz.ply"), &d) {
            Ok(m) => {
                ok += 1;
                assert!(m.validate().is_ok());
            }
            Err(e @ SplatError::Ply { .. }) => {
                errors += 1;
                let msg = e.to_string();
                assert!(
                    msg.starts_with("/fuzz.ply: ") && !msg.contains("panicked"),
                    "{msg}"
                );
            }
            Err(e) => panic!("unexpected error kind: {e}"),
        }
    }
    assert!(ok > 100 && errors > 100, "ok {ok}, errors {errors}");
}

/// A binary little-endian PLY with `n` declared vertices, the given vertex property types
/// (INRIA names, SH degree 0) and the raw body.
fn raw_ply(n: usize, dc_type: &str, body: &[u8]) -> Vec<u8> {
    let mut h = format!("ply\nformat binary_little_endian 1.0\nelement vertex {n}\n");
    for p in ["x", "y", "z"] {
        h += &format!("property float {p}\n");
    }
    for p in ["f_dc_0", "f_dc_1", "f_dc_2"] {
        h += &format!("property {dc_type} {p}\n");
    }
    for p in [
        "opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3",
    ] {
        h += &format!("property float {p}\n");
    }
    h += "end_header\n";
    let mut out = h.into_bytes();
    out.extend_from_slice(body);
    out
}

fn floats(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

#[test]
fn lying_counts_integer_properties_and_overflowing_scales_are_refused() {
    let p = std::path::Path::new("scene.ply");
    let row = |log_scale: f32| {
        floats(&[
            0.0, 0.0, 1.0, 0.1, 0.2, 0.3, 1.0, log_scale, -3.0, -3.0, 1.0, 0.0, 0.0, 0.0,
        ])
    };
    let two = [row(-3.0), row(-3.0)].concat();
    // Sound: both vertices read.
    assert_eq!(parse_ply(p, &raw_ply(2, "float", &two)).unwrap().len(), 2);
    // A count smaller than the data.
    let err = parse_ply(p, &raw_ply(1, "float", &two))
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("scene.ply") && err.contains("vertex count is smaller"),
        "{err}"
    );
    // Colour stored as bytes (a quantised layout) is not read as SH coefficients.
    let mut q = floats(&[0.0, 0.0, 1.0]);
    q.extend([200u8, 10, 10]);
    q.extend(floats(&[1.0, -3.0, -3.0, -3.0, 1.0, 0.0, 0.0, 0.0]));
    let err = parse_ply(p, &raw_ply(1, "uchar", &q))
        .unwrap_err()
        .to_string();
    assert!(err.contains("f_dc_0") && err.contains("float"), "{err}");
    // A log scale whose exponential overflows.
    let err = parse_ply(p, &raw_ply(1, "float", &row(100.0)))
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("vertex 0") && err.contains("log scale"),
        "{err}"
    );
}
