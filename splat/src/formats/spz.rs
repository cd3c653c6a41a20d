//! SPZ (Niantic's compressed splat format), versions 2, 3 and 4 read, version 3 written.
//!
//! Versions 2 and 3: a gzip stream holding a 16-byte header (magic `NGSP`, version, count, SH degree,
//! fractional bits, flags) and then, attribute by attribute: positions as 24-bit fixed point
//! (12 fractional bits, so ±2048 units at 0.25 mm), opacity after the sigmoid in 8 bits, the
//! DC colour as `dc · 0.15 · 255 + 127.5`, log scales as `(s + 10) · 16`, orientation as
//! "smallest three" (version 3: the largest component's index in 2 bits and the others in
//! 10 bits each; version 2: x, y, z in 8 bits with w ≥ 0) and SH coefficients in 8 bits
//! (`x · 128 + 128`, per splat, coefficient by coefficient, RGB innermost).
//!
//! Frame: values are stored in the PLY's frame, as PlayCanvas' splat-transform reads and
//! writes them (Niantic's own converter turns PLY data into its right-up-back frame; its
//! files open here turned by half a turn about x).
//!
//! Version 4 (splat-transform's default) keeps the same attribute encodings but compresses
//! each attribute on its own: a plain 32-byte header (the 16 above, then the stream count and
//! the byte offset of a table of contents), optional extensions, the table (per stream: its
//! compressed and uncompressed sizes, u64 each) and one ZSTD frame per attribute, in the
//! order above (the SH stream only when the degree is above 0). Written as version 3: every
//! tool we check reads it, and gzip needs nothing beyond `flate2`.

use std::io::{Read, Write};
use std::path::Path;

use glam::Vec3;

use crate::error::SplatError;
use crate::model::{Gaussians, MAX_SH_DEGREE, check_splat_count, logit, sh_rest_count, sigmoid};

const MAGIC: u32 = 0x5053_474e;
const HEADER: usize = 16;
const FRACTIONAL_BITS: u8 = 12;
const COLOR_SCALE: f32 = 0.15;

fn to_u8(x: f32) -> u8 {
    x.round().clamp(0.0, 255.0) as u8
}

/// Encodes a unit quaternion (x, y, z, w) as "smallest three" in 32 bits.
fn pack_quat(q: [f32; 4]) -> u32 {
    let largest = (0..4)
        .max_by(|&a, &b| q[a].abs().total_cmp(&q[b].abs()))
        .expect("four components");
    let negate = q[largest] < 0.0;
    let mut comp = largest as u32;
    for (i, v) in q.iter().enumerate() {
        if i != largest {
            let neg = ((*v < 0.0) ^ negate) as u32;
            let mag = (511.0 * (v.abs() / std::f32::consts::FRAC_1_SQRT_2) + 0.5) as u32;
            comp = (comp << 10) | (neg << 9) | mag.min(511);
        }
    }
    comp
}

fn unpack_quat(mut comp: u32) -> [f32; 4] {
    let largest = (comp >> 30) as usize;
    let mut q = [0.0f32; 4];
    let mut sum = 0.0;
    for i in (0..4).rev() {
        if i != largest {
            let mag = comp & 511;
            let neg = (comp >> 9) & 1;
            comp >>= 10;
            let v = std::f32::consts::FRAC_1_SQRT_2 * mag as f32 / 511.0;
            q[i] = if neg == 1 { -v } else { v };
            sum += q[i] * q[i];
        }
    }
    q[largest] = (1.0 - sum).max(0.0).sqrt();
    q
}

/// The SPZ (version 3) bytes of `g`.
pub fn to_spz(g: &Gaussians) -> Result<Vec<u8>, SplatError> {
    let bad = |m: String| SplatError::InvalidModel(m);
    let n = g.len();
    let limit = (1 << 23) as f32 / (1 << FRACTIONAL_BITS) as f32;
    if let Some((i, m)) = g
        .means
        .iter()
        .enumerate()
        .find(|(_, m)| !m.is_finite() || m.abs().max_element() >= limit)
    {
        return Err(bad(format!(
            "splat {i} at {m} cannot be stored in SPZ (24-bit fixed point: |x| < {limit}); PLY or GLB keep any position"
        )));
    }
    let rc = g.rest_count();
    let mut raw = Vec::with_capacity(HEADER + n * (9 + 1 + 3 + 3 + 4 + 3 * rc));
    raw.extend(MAGIC.to_le_bytes());
    raw.extend(3u32.to_le_bytes());
    raw.extend((n as u32).to_le_bytes());
    raw.extend([g.sh_degree as u8, FRACTIONAL_BITS, 0, 0]);
    let scale = (1 << FRACTIONAL_BITS) as f32;
    for m in &g.means {
        for v in m.to_array() {
            let fixed = (v * scale).round() as i32;
            raw.extend(&fixed.to_le_bytes()[..3]);
        }
    }
    raw.extend(g.logit_opacities.iter().map(|o| to_u8(sigmoid(*o) * 255.0)));
    for c in &g.sh_dc {
        raw.extend(
            c.to_array()
                .map(|v| to_u8(v * (COLOR_SCALE * 255.0) + 0.5 * 255.0)),
        );
    }
    for s in &g.log_scales {
        raw.extend(s.to_array().map(|v| to_u8((v + 10.0) * 16.0)));
    }
    for [w, x, y, z] in &g.rotations {
        let len = (w * w + x * x + y * y + z * z).sqrt();
        let q = if len > 0.0 && len.is_finite() {
            [x / len, y / len, z / len, w / len]
        } else {
            [0.0, 0.0, 0.0, 1.0]
        };
        raw.extend(pack_quat(q).to_le_bytes());
    }
    for c in &g.sh_rest {
        raw.extend(c.to_array().map(|v| to_u8(v * 128.0 + 128.0)));
    }
    let mut enc = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
    enc.write_all(&raw)
        .and_then(|_| enc.finish())
        .map_err(|e| bad(format!("cannot compress: {e}")))
}

/// Writes `g` as an SPZ file (atomically, ordinary permissions).
pub fn write_spz(path: impl AsRef<Path>, g: &Gaussians) -> Result<(), SplatError> {
    let path = path.as_ref();
    let bytes = to_spz(g)?;
    base::write_bytes_atomically(path, &bytes).map_err(|source| SplatError::Io {
        path: path.to_path_buf(),
        source,
    })
}

pub fn read_spz(path: impl AsRef<Path>) -> Result<Gaussians, SplatError> {
    let path = path.as_ref();
    let bytes = base::input::read(path).map_err(|source| SplatError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    parse_spz(path, &bytes)
}

/// Parses SPZ bytes (`path` only names the file in errors).
pub fn parse_spz(path: &Path, bytes: &[u8]) -> Result<Gaussians, SplatError> {
    let bad = |problem: String| SplatError::Ply {
        path: path.to_path_buf(),
        problem,
    };
    let (header, body) = if bytes.len() >= 8 && bytes[..4] == MAGIC.to_le_bytes() {
        read_v4(bytes).map_err(bad)?
    } else {
        read_gzipped(bytes).map_err(bad)?
    };
    let (version, n, degree, frac) = header;
    let rot_bytes = if version >= 3 { 4 } else { 3 };
    let rc = sh_rest_count(degree);
    let (pos, rest) = body.split_at(9 * n);
    let (alpha, rest) = rest.split_at(n);
    let (color, rest) = rest.split_at(3 * n);
    let (scale, rest) = rest.split_at(3 * n);
    let (rot, sh) = rest.split_at(rot_bytes * n);
    let step = 1.0 / (1u32 << frac) as f32;
    let mut g = Gaussians::new(degree);
    // The count is proven by the data now.
    g.reserve_exact(n);
    let mut coeffs = vec![Vec3::ZERO; rc];
    for i in 0..n {
        let p: [f32; 3] = std::array::from_fn(|k| {
            let b = &pos[9 * i + 3 * k..9 * i + 3 * k + 3];
            // Sign-extend 24 bits.
            (i32::from_le_bytes([b[0], b[1], b[2], 0]) << 8 >> 8) as f32 * step
        });
        let v3 = |a: &[u8], f: &dyn Fn(u8) -> f32| {
            Vec3::new(f(a[3 * i]), f(a[3 * i + 1]), f(a[3 * i + 2]))
        };
        let q = if version >= 3 {
            unpack_quat(u32::from_le_bytes(
                rot[4 * i..4 * i + 4].try_into().expect("4 bytes"),
            ))
        } else {
            let c = |b: u8| b as f32 / 127.5 - 1.0;
            let (x, y, z) = (c(rot[3 * i]), c(rot[3 * i + 1]), c(rot[3 * i + 2]));
            [x, y, z, (1.0 - x * x - y * y - z * z).max(0.0).sqrt()]
        };
        for (k, c) in coeffs.iter_mut().enumerate() {
            let b = &sh[(i * rc + k) * 3..(i * rc + k) * 3 + 3];
            *c = Vec3::new(b[0] as f32, b[1] as f32, b[2] as f32) / 128.0 - Vec3::ONE;
        }
        g.push(
            Vec3::from_array(p),
            v3(scale, &|b| b as f32 / 16.0 - 10.0),
            [q[3], q[0], q[1], q[2]],
            logit(alpha[i] as f32 / 255.0),
            v3(color, &|b| (b as f32 / 255.0 - 0.5) / COLOR_SCALE),
            &coeffs,
        );
    }
    Ok(g)
}

/// Version, splat count, SH degree and fractional bits of a header, checked.
type Header = (u32, usize, u32, u8);

/// The per-splat bytes of each attribute: positions, alpha, colour, scales, rotation, SH.
fn stream_sizes(version: u32, n: usize, degree: u32) -> [usize; 6] {
    let rot_bytes = if version >= 3 { 4 } else { 3 };
    [
        9 * n,
        n,
        3 * n,
        3 * n,
        rot_bytes * n,
        3 * sh_rest_count(degree) * n,
    ]
}

fn check_header(h: &[u8], versions: std::ops::RangeInclusive<u32>) -> Result<Header, String> {
    let u32_at = |i: usize| u32::from_le_bytes(h[i..i + 4].try_into().expect("4 bytes"));
    if u32_at(0) != MAGIC {
        return Err("not an SPZ file (no NGSP magic)".into());
    }
    let version = u32_at(4);
    if !versions.contains(&version) {
        return Err(format!(
            "SPZ version {version} is not read (2, 3 and 4 are)"
        ));
    }
    let n = u32_at(8) as u64;
    let (degree, frac, flags) = (h[12] as u32, h[13], h[14]);
    if degree > MAX_SH_DEGREE {
        return Err(format!(
            "SH degree {degree} (at most {MAX_SH_DEGREE} is read)"
        ));
    }
    check_splat_count(n, degree)?;
    if frac > 23 {
        return Err(format!("{frac} fractional bits for 24-bit positions"));
    }
    if version < 4 && flags & 2 != 0 {
        return Err("SPZ extensions are not read".into());
    }
    Ok((version, n as usize, degree, frac))
}

/// The most a splat file may expand: deflate's own limit (1032:1), which versions 2 and 3 meet
/// by construction. ZSTD (version 4) expands zeros about 32 000:1, so a 30 KB file could
/// "hold" 50 M identical splats; real splat data compresses a few times at most (even with every
/// higher SH coefficient zero), so a file beyond deflate's limit is refused as a decompression
/// bomb rather than read into gigabytes.
const MAX_RATIO: u64 = 1032;

/// Versions 2 and 3: one gzip stream, header then the attributes back to back.
fn read_gzipped(bytes: &[u8]) -> Result<(Header, Vec<u8>), String> {
    // Several gzip members concatenated are one valid stream (RFC 1952), as gunzip reads it.
    let mut dec = flate2::read::MultiGzDecoder::new(bytes);
    let mut header = [0u8; HEADER];
    dec.read_exact(&mut header)
        .map_err(|e| format!("not an SPZ file (no gzip stream with a header): {e}"))?;
    let h = check_header(&header, 2..=3)?;
    let expected: usize = stream_sizes(h.0, h.1, h.2).iter().sum();
    // Deflate expands at most 1032:1, so a count the compressed bytes could never hold fails
    // before anything is reserved.
    if expected as u64 > (bytes.len() as u64).saturating_mul(MAX_RATIO) {
        return Err(format!(
            "{} splats need {expected} bytes after the header, more than the {} compressed bytes can hold",
            h.1,
            bytes.len()
        ));
    }
    let mut body = Vec::new();
    let got =
        fill(&mut dec, &mut body, expected).map_err(|e| format!("corrupt compressed data: {e}"))?;
    if got != expected {
        return Err(format!(
            "{} splats need {expected} bytes after the header, the file has {}{}",
            h.1,
            got.min(expected),
            if got > expected { " and more" } else { "" }
        ));
    }
    Ok((h, body))
}

/// Appends up to `expected` bytes of `src` to `body` and returns how many came (one more than
/// `expected` when the stream holds more). Memory grows only as data really arrives, in
/// pieces of at most a sixteenth of what is expected (and never by doubling), so a count that
/// lies about a short stream reserves about what the stream holds.
fn fill(src: &mut impl Read, body: &mut Vec<u8>, expected: usize) -> std::io::Result<usize> {
    let start = body.len();
    let piece = (expected / 16).clamp(1 << 16, 1 << 26);
    let mut got = 0;
    while got < expected {
        let want = piece.min(expected - got);
        body.reserve_exact(want);
        let at = body.len();
        body.resize(at + want, 0);
        let n = read_full(src, &mut body[at..])?;
        body.truncate(at + n);
        got += n;
        if n < want {
            return Ok(got);
        }
    }
    let mut probe = [0u8; 1];
    let extra = read_full(src, &mut probe)?;
    debug_assert_eq!(body.len() - start, got);
    Ok(got + extra)
}

/// Reads until `buf` is full or the stream ends; how many bytes came.
fn read_full(src: &mut impl Read, buf: &mut [u8]) -> std::io::Result<usize> {
    let mut n = 0;
    while n < buf.len() {
        match src.read(&mut buf[n..]) {
            Ok(0) => break,
            Ok(k) => n += k,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    Ok(n)
}

/// Version 4: a plain header, a table of contents and one ZSTD frame per attribute,
/// decompressed into version 3's layout.
fn read_v4(bytes: &[u8]) -> Result<(Header, Vec<u8>), String> {
    const HEADER_V4: usize = 32;
    if bytes.len() < HEADER_V4 {
        return Err(format!(
            "truncated: {} bytes, less than an SPZ header",
            bytes.len()
        ));
    }
    let version = u32::from_le_bytes(bytes[4..8].try_into().expect("4 bytes"));
    if (2..=3).contains(&version) {
        return Err(format!(
            "an uncompressed SPZ version {version} header: versions 2 and 3 are one gzip stream, and this file is not compressed"
        ));
    }
    let h = check_header(&bytes[..HEADER_V4], 4..=4)?;
    let streams = bytes[15] as usize;
    let toc = u32::from_le_bytes(bytes[16..20].try_into().expect("4 bytes")) as usize;
    let sizes = stream_sizes(h.0, h.1, h.2);
    let want = if h.2 == 0 { 5 } else { 6 };
    if streams != want {
        return Err(format!(
            "{streams} compressed streams; SH degree {} needs {want}",
            h.2
        ));
    }
    let total: u64 = sizes.iter().take(streams).map(|&s| s as u64).sum();
    if total > (bytes.len() as u64).saturating_mul(MAX_RATIO) {
        return Err(format!(
            "{} splats need {total} bytes, more than {MAX_RATIO} times the file's {} bytes: refused as a decompression bomb (no splat file compresses that far)",
            h.1,
            bytes.len()
        ));
    }
    let data_start = toc
        .checked_add(16 * streams)
        .filter(|&e| toc >= HEADER_V4 && e <= bytes.len())
        .ok_or_else(|| format!("table of contents at byte {toc} lies outside the file"))?;
    let mut body = Vec::new();
    let mut at = data_start;
    for (k, &expected) in sizes.iter().enumerate().take(streams) {
        let entry = &bytes[toc + 16 * k..toc + 16 * k + 16];
        let compressed = u64::from_le_bytes(entry[..8].try_into().expect("8 bytes"));
        let stated = u64::from_le_bytes(entry[8..].try_into().expect("8 bytes"));
        if stated != expected as u64 {
            return Err(format!(
                "stream {k} says it holds {stated} bytes; {} splats need {expected}",
                h.1
            ));
        }
        let end = usize::try_from(compressed)
            .ok()
            .and_then(|c| at.checked_add(c))
            .filter(|&e| e <= bytes.len())
            .ok_or_else(|| {
                format!("stream {k} ({compressed} bytes) runs past the end of the file")
            })?;
        let mut dec = ruzstd::decoding::StreamingDecoder::new(&bytes[at..end])
            .map_err(|e| format!("stream {k} is not ZSTD data: {e}"))?;
        let got = fill(&mut dec, &mut body, expected)
            .map_err(|e| format!("stream {k} is corrupt: {e}"))?;
        if got != expected {
            return Err(format!(
                "stream {k} decompresses to {}{} bytes, not {expected}",
                got.min(expected),
                if got > expected { " or more" } else { "" }
            ));
        }
        at = end;
    }
    Ok((h, body))
}
