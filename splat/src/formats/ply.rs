//! PLY import/export in the INRIA 3DGS layout, on top of the `ply-rs-bw` crate.
//!
//! Written files are binary little-endian float32 with the vertex properties
//! `x y z nx ny nz f_dc_0..2 f_rest_0..(3K−1) opacity scale_0..2 rot_0..3`, where
//! `K = (degree+1)² − 1` and `f_rest` is channel-major (`f_rest_{c·K + k}` is channel `c` of
//! basis `k + 1`); opacity is a logit, scales are logs, `rot` is `(w, x, y, z)`.
//!
//! Reading accepts ASCII (one element per line, as the PLY spec requires), binary little- and
//! big-endian; any scalar property types; files with or without normals; `f_rest` counts of
//! 0, 9, 24 or 45 (SH degree 0..3); other elements before or after `vertex` (skipped). Every
//! failure is a [`SplatError::Ply`] naming the file.
//!
//! `ply-rs-bw` parses the header, decodes every value of the body (ASCII tokens, both byte
//! orders) and encodes the header and the values when writing. What this module adds around
//! it, and why (each is small and marked `Guard:` below):
//!
//! - it checks that no element or property name appears twice in the header: `ply-rs-bw`
//!   keeps its header in a name-keyed map, so a repeated name silently drops a declaration
//!   and the body would then be decoded misaligned;
//! - it does not hand binary elements without properties to `ply-rs-bw`, which would spin
//!   through their (possibly absurd) count reading nothing;
//! - before decoding a binary body it checks that the file is long enough for the declared
//!   counts, so a lying vertex count fails at once (instead of after decoding up to EOF) and
//!   never sizes an allocation;
//! - it turns `ply-rs-bw`'s errors into messages that say *truncated* / *cannot parse* /
//!   which vertex, and rejects ASCII vertex lines with more values than declared (which
//!   `ply-rs-bw` ignores);
//! - it runs the parser under `catch_unwind`, so even an unforeseen panic in the dependency
//!   becomes an error (no malformed input is known to make `ply-rs-bw` panic; the fuzzing is
//!   described in splat/README.md).

use std::io::{self, BufRead, BufReader, Read};
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::Path;

use glam::Vec3;
use ply_rs_bw::parser::{Parser, Reader};
use ply_rs_bw::ply::{
    Addable, ElementDef, Encoding, Header, PropertyAccess, PropertyAccessResult, PropertyDef,
    PropertyType, ScalarType,
};
use ply_rs_bw::writer::Writer;

use crate::error::SplatError;
use crate::model::{Gaussians, MAX_SH_DEGREE, sh_rest_count};

/// Vertex properties every file must have, in slot order (slots `0..14` of [`Row`]).
const REQUIRED: [&str; 14] = [
    "x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2",
    "rot_0", "rot_1", "rot_2", "rot_3",
];
/// Slot of `f_rest_0`; `f_rest_k` is slot `REST0 + k`.
const REST0: usize = REQUIRED.len();
use crate::model::MAX_LOG_SCALE;
const MAX_REST: usize = 3 * sh_rest_count(MAX_SH_DEGREE);
const SLOTS: usize = REST0 + MAX_REST;

/// Slot of an INRIA vertex property name, `None` for anything else (normals, extras).
/// `f_rest_k` must be spelled exactly as written (`f_rest_7`, not `f_rest_07`).
#[inline(always)]
fn slot(name: &str) -> Option<usize> {
    let b = name.as_bytes();
    let digit = |c: u8| c.is_ascii_digit().then(|| usize::from(c - b'0'));
    match b.len() {
        1 => match b[0] {
            b'x' => Some(0),
            b'y' => Some(1),
            b'z' => Some(2),
            _ => None,
        },
        5 if b.starts_with(b"rot_") => digit(b[4]).filter(|&d| d < 4).map(|d| 10 + d),
        6 if b.starts_with(b"f_dc_") => digit(b[5]).filter(|&d| d < 3).map(|d| 3 + d),
        7 if b == b"opacity" => Some(6),
        7 if b.starts_with(b"scale_") => digit(b[6]).filter(|&d| d < 3).map(|d| 7 + d),
        8 | 9 if b.starts_with(b"f_rest_") => {
            let k = if b.len() == 8 {
                digit(b[7])?
            } else if b[7] == b'0' {
                return None;
            } else {
                digit(b[7])? * 10 + digit(b[8])?
            };
            (k < MAX_REST).then_some(REST0 + k)
        }
        _ => None,
    }
}

/// One vertex as `ply-rs-bw` hands it over (reading) or asks for it (writing): the INRIA
/// values by slot, plus the first non-finite value seen in any property, used or not.
struct Row {
    v: [f32; SLOTS],
    non_finite: Option<(String, f32)>,
}

impl Row {
    #[inline(always)]
    fn set(&mut self, name: &str, v: f32) -> PropertyAccessResult {
        if !v.is_finite() && self.non_finite.is_none() {
            self.non_finite = Some((name.to_string(), v));
        }
        match slot(name) {
            Some(s) => {
                self.v[s] = v;
                PropertyAccessResult::Set
            }
            None => PropertyAccessResult::Ignored,
        }
    }
}

/// Every scalar type is accepted and converted as `value as f64 as f32` (float32 is stored
/// unchanged, so binary and ASCII float32 round trips are bit-exact).
impl PropertyAccess for Row {
    fn new() -> Self {
        Row {
            v: [0.0; SLOTS],
            non_finite: None,
        }
    }
    fn set_char(&mut self, name: &str, v: i8) -> PropertyAccessResult {
        self.set(name, f32::from(v))
    }
    fn set_uchar(&mut self, name: &str, v: u8) -> PropertyAccessResult {
        self.set(name, f32::from(v))
    }
    fn set_short(&mut self, name: &str, v: i16) -> PropertyAccessResult {
        self.set(name, f32::from(v))
    }
    fn set_ushort(&mut self, name: &str, v: u16) -> PropertyAccessResult {
        self.set(name, f32::from(v))
    }
    fn set_int(&mut self, name: &str, v: i32) -> PropertyAccessResult {
        self.set(name, f64::from(v) as f32)
    }
    fn set_uint(&mut self, name: &str, v: u32) -> PropertyAccessResult {
        self.set(name, f64::from(v) as f32)
    }
    #[inline(always)]
    fn set_float(&mut self, name: &str, v: f32) -> PropertyAccessResult {
        self.set(name, v)
    }
    fn set_double(&mut self, name: &str, v: f64) -> PropertyAccessResult {
        self.set(name, v as f32)
    }
    #[inline(always)]
    fn get_float(&self, name: &str) -> Option<f32> {
        match slot(name) {
            Some(s) => Some(self.v[s]),
            None if matches!(name, "nx" | "ny" | "nz") => Some(0.0),
            None => None,
        }
    }
}

/// Element type for elements that are read past (every value ignored; zero-sized).
struct Skip;

impl PropertyAccess for Skip {
    fn new() -> Self {
        Skip
    }
}

fn ply_err(path: &Path, problem: impl Into<String>) -> SplatError {
    SplatError::Ply {
        path: path.to_path_buf(),
        problem: problem.into(),
    }
}

/// A `ply-rs-bw` error on one line (its messages embed `\n\t`).
/// The parser's message on one line, without the grammar's internal state it appends
/// (`Error: ParseError { location: …, expected: … }`), which names nothing a user wrote.
fn squash(e: &impl std::fmt::Display) -> String {
    let text = e.to_string();
    let text = text.split("Error: ParseError").next().unwrap_or(&text);
    text.split_whitespace().collect::<Vec<_>>().join(" ")
}

/// Buffered reader that counts consumed bytes and, while `log` is set, keeps a copy of them
/// (the header text, for the duplicate-name guard).
struct Tap<R> {
    inner: R,
    consumed: u64,
    log: Option<Vec<u8>>,
}

impl<R: BufRead> BufRead for Tap<R> {
    fn fill_buf(&mut self) -> io::Result<&[u8]> {
        self.inner.fill_buf()
    }

    fn consume(&mut self, n: usize) {
        if let Some(log) = &mut self.log
            && let Ok(buf) = self.inner.fill_buf()
        {
            log.extend_from_slice(&buf[..n.min(buf.len())]);
        }
        self.consumed += n as u64;
        self.inner.consume(n);
    }
}

impl<R: BufRead> Read for Tap<R> {
    fn read(&mut self, out: &mut [u8]) -> io::Result<usize> {
        let buf = self.fill_buf()?;
        let n = buf.len().min(out.len());
        out[..n].copy_from_slice(&buf[..n]);
        self.consume(n);
        Ok(n)
    }

    /// Fast path for the 1–8 byte reads `ply-rs-bw` issues per binary value.
    #[inline]
    fn read_exact(&mut self, out: &mut [u8]) -> io::Result<()> {
        let buf = self.inner.fill_buf()?;
        let n = out.len();
        if buf.len() >= n && self.log.is_none() {
            // Constant-length copies for the common sizes (no `memcpy` call).
            match n {
                4 => out.copy_from_slice(&buf[..4]),
                8 => out.copy_from_slice(&buf[..8]),
                _ => out.copy_from_slice(&buf[..n]),
            }
            self.consumed += n as u64;
            self.inner.consume(n);
            return Ok(());
        }
        let mut rest = out;
        while !rest.is_empty() {
            match self.read(rest)? {
                0 => return Err(io::ErrorKind::UnexpectedEof.into()),
                n => rest = &mut rest[n..],
            }
        }
        Ok(())
    }
}

/// Bytes of one binary value (the header only names the type; `ply-rs-bw` does not expose
/// sizes).
fn scalar_size(t: &ScalarType) -> u64 {
    match t {
        ScalarType::Char | ScalarType::UChar => 1,
        ScalarType::Short | ScalarType::UShort => 2,
        ScalarType::Int | ScalarType::UInt | ScalarType::Float => 4,
        ScalarType::Double => 8,
    }
}

/// Least binary size of one element (lists counted as empty).
fn min_element_size(e: &ElementDef) -> u64 {
    e.properties
        .values()
        .map(|p| match &p.data_type {
            PropertyType::Scalar(t) | PropertyType::List(t, _) => scalar_size(t),
        })
        .sum()
}

/// Reads a Gaussian model from a PLY file (see the module docs for what is accepted). The
/// file is streamed, never held in memory whole.
pub fn read_ply(path: impl AsRef<Path>) -> Result<Gaussians, SplatError> {
    read_ply_reporting(path.as_ref(), &|_, _| {})
}

/// [`read_ply`], calling `progress(bytes_read, file_len)` as the file streams in (for a
/// progress bar on large scenes).
pub fn read_ply_reporting(
    path: &Path,
    progress: &dyn Fn(u64, u64),
) -> Result<Gaussians, SplatError> {
    let io = |source| SplatError::Io {
        path: path.to_path_buf(),
        source,
    };
    let file = base::input::open(path).map_err(io)?;
    let meta = file.metadata().map_err(io)?;
    if meta.is_dir() {
        return Err(io(io::ErrorKind::IsADirectory.into()));
    }
    let counted = Counted {
        inner: file,
        read: 0,
        total: meta.len(),
        reported: 0,
        progress,
    };
    parse_guarded(
        path,
        BufReader::with_capacity(1 << 20, counted),
        Some(meta.len()),
    )
}

/// A reader that reports how far it has got, every few megabytes.
struct Counted<'a, R> {
    inner: R,
    read: u64,
    total: u64,
    reported: u64,
    progress: &'a dyn Fn(u64, u64),
}

impl<R: Read> Read for Counted<'_, R> {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        let n = self.inner.read(buf)?;
        self.read += n as u64;
        if self.read - self.reported >= 4 << 20 || (n == 0 && self.read != self.reported) {
            self.reported = self.read;
            (self.progress)(self.read, self.total);
        }
        Ok(n)
    }
}

/// Parses PLY bytes; `path` is only used in error messages.
pub fn parse_ply(path: &Path, bytes: &[u8]) -> Result<Gaussians, SplatError> {
    parse_guarded(path, bytes, Some(bytes.len() as u64))
}

/// Guard: a panic inside the parser (none is known, see the module docs) becomes an error.
fn parse_guarded<R: BufRead>(
    path: &Path,
    source: R,
    len: Option<u64>,
) -> Result<Gaussians, SplatError> {
    catch_unwind(AssertUnwindSafe(|| parse_reader(path, source, len))).unwrap_or_else(|panic| {
        let msg = panic
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| panic.downcast_ref::<String>().cloned())
            .unwrap_or_default();
        Err(ply_err(path, format!("PLY parser panicked: {msg}")))
    })
}

fn parse_reader<R: BufRead>(
    path: &Path,
    source: R,
    len: Option<u64>,
) -> Result<Gaussians, SplatError> {
    let err = |m: String| ply_err(path, m);
    let mut reader = Reader::new(Tap {
        inner: source,
        consumed: 0,
        log: Some(Vec::new()),
    });

    // Header, parsed by ply-rs-bw.
    let header = match Parser::<Skip>::new().read_header(&mut reader) {
        Ok(h) => h,
        Err(e) => {
            let at_eof = reader.get_mut().fill_buf().is_ok_and(|b| b.is_empty());
            let seen = reader.get_ref().log.as_deref().unwrap_or_default();
            let magic = seen.len() < 3 || seen.starts_with(b"ply");
            return Err(err(if e.line() == Some(1) || !magic {
                format!("not a PLY file (missing 'ply' magic line): {}", squash(&e))
            } else if at_eof {
                format!("truncated: file ends before 'end_header': {}", squash(&e))
            } else {
                format!("malformed header: {}", squash(&e))
            }));
        }
    };
    let header_text = reader.get_mut().log.take().unwrap_or_default();
    let header_bytes = reader.get_ref().consumed;

    // Guard: a repeated element or property name overwrites an entry of ply-rs-bw's
    // name-keyed header map (the declaration count then disagrees with the map).
    let declared = |kw: &[u8]| {
        header_text
            .split(|&c| c == b'\n')
            .filter(|l| {
                l.starts_with(kw) && l.get(kw.len()).is_some_and(|c| matches!(c, b' ' | b'\t'))
            })
            .count()
    };
    let properties: usize = header.elements.values().map(|e| e.properties.len()).sum();
    if declared(b"element") != header.elements.len() || declared(b"property") != properties {
        return Err(err(
            "malformed header: an element or property name is declared twice".into(),
        ));
    }

    let vidx = header
        .elements
        .get_index_of("vertex")
        .ok_or_else(|| err("no 'vertex' element".into()))?;
    let vertex = &header.elements[vidx];
    if let Some(p) = vertex
        .properties
        .values()
        .find(|p| matches!(p.data_type, PropertyType::List(..)))
    {
        return Err(err(format!("vertex property '{}' is a list", p.name)));
    }
    for name in REQUIRED {
        if !vertex.properties.contains_key(name) {
            return Err(err(format!("missing required vertex property '{name}'")));
        }
    }
    let rest_total = vertex
        .properties
        .keys()
        .filter(|k| k.starts_with("f_rest_"))
        .count();
    let degree = (0..=MAX_SH_DEGREE)
        .find(|&d| 3 * sh_rest_count(d) == rest_total)
        .ok_or_else(|| {
            err(format!(
                "{rest_total} f_rest properties do not match any SH degree 0..3 \
                 (need 0, 9, 24 or 45)"
            ))
        })?;
    for k in 0..rest_total {
        let name = format!("f_rest_{k}");
        if !vertex.properties.contains_key(&name) {
            return Err(err(format!("missing required vertex property '{name}'")));
        }
    }
    // Guard: integer splat properties would be read as raw numbers (a quantised file's 0–255
    // taken as SH coefficients).
    let splat_property = |n: &str| REQUIRED.contains(&n) || n.starts_with("f_rest_");
    if let Some(p) = vertex.properties.values().find(|p| {
        splat_property(&p.name)
            && !matches!(
                p.data_type,
                PropertyType::Scalar(ScalarType::Float | ScalarType::Double)
            )
    }) {
        return Err(err(format!(
            "vertex property '{}' is {:?}: splat properties must be float or double \
             (decompress quantised layouts first)",
            p.name, p.data_type
        )));
    }

    let n = vertex.count;
    let binary = header.encoding != Encoding::Ascii;
    let have = len.map(|l| l.saturating_sub(header_bytes));
    // Guard: the body must be long enough for the declared counts before anything is
    // decoded or allocated.
    if binary && let Some(have) = have {
        let need = header
            .elements
            .values()
            .take(vidx + 1)
            .fold(0u64, |acc, e| {
                acc.saturating_add(min_element_size(e).saturating_mul(e.count as u64))
            });
        if need > have {
            return Err(err(format!(
                "truncated: {n} vertices (and the elements before them) need {need} bytes of \
                 data, file has {have}"
            )));
        }
        // Guard: data past the last declared vertex means the count is smaller than the data
        // (every vertex property is a scalar here, so the size is exact).
        if vidx + 1 == header.elements.len() && have > need {
            return Err(err(format!(
                "{} bytes follow the {n} declared vertices: the vertex count is smaller than \
                 the data",
                have - need
            )));
        }
    }

    // Elements before `vertex`: decoded by ply-rs-bw into nothing.
    let skip = Parser::<Skip>::new();
    for el in header.elements.values().take(vidx) {
        // Guard: ply-rs-bw would loop `count` times reading zero bytes.
        if binary && el.properties.is_empty() {
            continue;
        }
        skip.read_payload_for_element(&mut reader, el, &header)
            .map_err(|e| {
                err(if e.kind() == io::ErrorKind::UnexpectedEof {
                    format!("truncated inside element '{}': {}", el.name, squash(&e))
                } else {
                    format!("element '{}': {}", el.name, squash(&e))
                })
            })?;
    }

    // Vertices: decoded by ply-rs-bw one at a time into a `Row`, then stored.
    let k = sh_rest_count(degree);
    let mut g = Gaussians::new(degree);
    let nprops = vertex.properties.len();
    // The body holds at least `cap` vertices (binary: checked above; ASCII: ≥ 2 bytes per
    // value), so a lying count never sizes this allocation.
    let min_row = if binary {
        min_element_size(vertex).max(1)
    } else {
        2 * nprops as u64
    };
    let cap = have.map_or(0, |h| (h / min_row).min(n as u64) as usize);
    g.reserve_exact(cap);
    let parser = Parser::<Row>::new();
    let first_line = reader.line();
    let mut line = String::new();
    let mut rest = vec![Vec3::ZERO; k];
    for i in 0..n {
        let row = match header.encoding {
            Encoding::Ascii => {
                let ln = first_line + i;
                line.clear();
                let got = reader
                    .get_mut()
                    .read_line(&mut line)
                    .map_err(|e| err(format!("vertex {i} (line {ln}): {e}")))?;
                if got == 0 {
                    return Err(err(format!(
                        "truncated: file ends before vertex {i} of {n} (line {ln})"
                    )));
                }
                let values = line.split_ascii_whitespace().count();
                let at_eof = !line.ends_with('\n');
                match parser.read_ascii_element(&line, vertex) {
                    Ok(row) if values <= nprops => row,
                    Ok(_) => {
                        return Err(err(format!(
                            "vertex {i} (line {ln}) has {values} values, the header declares \
                             {nprops}"
                        )));
                    }
                    Err(e) => {
                        let numeric = |t: &str| {
                            t.parse::<f64>().is_ok()
                                && t.bytes()
                                    .all(|c| c.is_ascii_digit() || b"+-.eE".contains(&c))
                        };
                        let bad = line.split_ascii_whitespace().find(|t| !numeric(t));
                        return Err(err(match bad {
                            Some(t) => format!(
                                "cannot parse '{t}' as a number in vertex {i} (line {ln}): {}",
                                squash(&e)
                            ),
                            None if values < nprops && at_eof => format!(
                                "truncated: file ends inside vertex {i} (line {ln} has \
                                 {values} of {nprops} values)"
                            ),
                            None if values < nprops => format!(
                                "vertex {i} (line {ln}) has {values} values, the header \
                                 declares {nprops}"
                            ),
                            None => format!("vertex {i} (line {ln}): {}", squash(&e)),
                        }));
                    }
                }
            }
            Encoding::BinaryLittleEndian | Encoding::BinaryBigEndian => {
                let res = if header.encoding == Encoding::BinaryLittleEndian {
                    parser.read_little_endian_element(reader.get_mut(), vertex)
                } else {
                    parser.read_big_endian_element(reader.get_mut(), vertex)
                };
                res.map_err(|e| {
                    err(if e.kind() == io::ErrorKind::UnexpectedEof {
                        format!("truncated: file ends inside vertex {i} of {n}")
                    } else {
                        format!("vertex {i}: {}", squash(&e))
                    })
                })?
            }
        };
        if let Some((name, v)) = &row.non_finite {
            return Err(err(format!(
                "vertex {i} property '{name}' is {v} (not finite)"
            )));
        }
        let c = &row.v;
        if let Some(s) = c[7..10].iter().find(|s| **s > MAX_LOG_SCALE) {
            return Err(err(format!(
                "vertex {i} has log scale {s}: its scale overflows (at most {MAX_LOG_SCALE})"
            )));
        }
        for (kk, r) in rest.iter_mut().enumerate() {
            *r = Vec3::new(c[REST0 + kk], c[REST0 + k + kk], c[REST0 + 2 * k + kk]);
        }
        g.push(
            Vec3::new(c[0], c[1], c[2]),
            Vec3::new(c[7], c[8], c[9]),
            [c[10], c[11], c[12], c[13]],
            c[6],
            Vec3::new(c[3], c[4], c[5]),
            &rest,
        );
    }
    Ok(g)
}

/// The INRIA header for `g` (binary little-endian float32).
fn header_for(g: &Gaussians) -> Header {
    let mut vertex = ElementDef::new("vertex".to_string());
    vertex.count = g.len();
    let names = [
        "x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2",
    ]
    .into_iter()
    .map(str::to_string)
    .chain((0..3 * g.rest_count()).map(|k| format!("f_rest_{k}")))
    .chain(
        [
            "opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3",
        ]
        .into_iter()
        .map(str::to_string),
    );
    for name in names {
        vertex.properties.add(PropertyDef::new(
            name,
            PropertyType::Scalar(ScalarType::Float),
        ));
    }
    let mut header = Header::new();
    header.encoding = Encoding::BinaryLittleEndian;
    header.elements.add(vertex);
    header
}

/// Writes `g` in the INRIA layout, atomically: the data goes to a temporary file in the
/// destination directory which is then renamed over `path`.
pub fn write_ply(path: impl AsRef<Path>, g: &Gaussians) -> Result<(), SplatError> {
    let path = path.as_ref();
    g.validate()?;
    if !g.is_finite() {
        return Err(ply_err(path, "refusing to write non-finite parameters"));
    }
    let header = header_for(g);
    let k = g.rest_count();
    base::write_atomically(path, |out| {
        let writer = Writer::<Row>::new();
        writer.write_header(out, &header)?;
        let vertex = &header.elements["vertex"];
        let mut row = Row::new();
        for i in 0..g.len() {
            let v = &mut row.v;
            v[0..3].copy_from_slice(&g.means[i].to_array());
            v[3..6].copy_from_slice(&g.sh_dc[i].to_array());
            v[6] = g.logit_opacities[i];
            v[7..10].copy_from_slice(&g.log_scales[i].to_array());
            v[10..14].copy_from_slice(&g.rotations[i]);
            for (kk, r) in g.sh_rest_of(i).iter().enumerate() {
                v[REST0 + kk] = r.x;
                v[REST0 + k + kk] = r.y;
                v[REST0 + 2 * k + kk] = r.z;
            }
            writer.write_little_endian_element(out, &row, vertex)?;
        }
        Ok(())
    })
    .map_err(|source| SplatError::Io {
        path: path.to_path_buf(),
        source,
    })
}
