//! PLY import/export in the INRIA 3DGS layout.
//!
//! Written files are binary little-endian float32 with the vertex properties
//! `x y z nx ny nz f_dc_0..2 f_rest_0..(3K−1) opacity scale_0..2 rot_0..3`, where
//! `K = (degree+1)² − 1` and `f_rest` is channel-major (`f_rest_{c·K + k}` is channel `c` of
//! basis `k + 1`); opacity is a logit, scales are logs, `rot` is `(w, x, y, z)`.
//!
//! Reading accepts ASCII, binary little- and big-endian; any scalar property types; files with
//! or without normals; `f_rest` counts of 0, 9, 24 or 45 (SH degree 0..3); other elements
//! before or after `vertex` (skipped). Every failure is a [`SplatError::Ply`] naming the file.

use std::io::Write;
use std::path::{Path, PathBuf};

use glam::Vec3;

use crate::error::SplatError;
use crate::model::{Gaussians, MAX_SH_DEGREE, sh_rest_count};

#[derive(Clone, Copy, Debug, PartialEq)]
enum Format {
    Ascii,
    LittleEndian,
    BigEndian,
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(s: &str) -> Option<Self> {
        Some(match s {
            "char" | "int8" => Self::I8,
            "uchar" | "uint8" => Self::U8,
            "short" | "int16" => Self::I16,
            "ushort" | "uint16" => Self::U16,
            "int" | "int32" => Self::I32,
            "uint" | "uint32" => Self::U32,
            "float" | "float32" => Self::F32,
            "double" | "float64" => Self::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Self::I8 | Self::U8 => 1,
            Self::I16 | Self::U16 => 2,
            Self::I32 | Self::U32 | Self::F32 => 4,
            Self::F64 => 8,
        }
    }

    /// Decodes one value; float32 stays bit-exact through the f64 (it is widened losslessly).
    fn decode(self, b: &[u8], f: Format) -> f64 {
        macro_rules! get {
            ($t:ty, $n:expr) => {{
                let a: [u8; $n] = b[..$n].try_into().unwrap();
                if f == Format::BigEndian {
                    <$t>::from_be_bytes(a) as f64
                } else {
                    <$t>::from_le_bytes(a) as f64
                }
            }};
        }
        match self {
            Self::I8 => b[0] as i8 as f64,
            Self::U8 => b[0] as f64,
            Self::I16 => get!(i16, 2),
            Self::U16 => get!(u16, 2),
            Self::I32 => get!(i32, 4),
            Self::U32 => get!(u32, 4),
            Self::F32 => get!(f32, 4),
            Self::F64 => get!(f64, 8),
        }
    }
}

#[derive(Clone, Debug)]
struct Property {
    name: String,
    /// `Some(count type)` for list properties.
    list: Option<Scalar>,
    ty: Scalar,
}

#[derive(Clone, Debug)]
struct Element {
    name: String,
    count: usize,
    props: Vec<Property>,
}

struct Header {
    format: Format,
    elements: Vec<Element>,
    body_start: usize,
}

fn ply_err(path: &Path, problem: impl Into<String>) -> SplatError {
    SplatError::Ply {
        path: path.to_path_buf(),
        problem: problem.into(),
    }
}

fn parse_header(path: &Path, bytes: &[u8]) -> Result<Header, SplatError> {
    let err = |m: String| ply_err(path, m);
    if !bytes.starts_with(b"ply\n") && !bytes.starts_with(b"ply\r\n") {
        return Err(err("not a PLY file (missing 'ply' magic line)".into()));
    }
    let end = bytes
        .windows(10)
        .position(|w| w == b"end_header")
        .ok_or_else(|| err("header has no 'end_header'".into()))?;
    let mut body_start = end + 10;
    if bytes.get(body_start) == Some(&b'\r') {
        body_start += 1;
    }
    if bytes.get(body_start) != Some(&b'\n') {
        return Err(err("'end_header' is not followed by a newline".into()));
    }
    body_start += 1;
    let text =
        std::str::from_utf8(&bytes[..end]).map_err(|_| err("header is not valid UTF-8".into()))?;
    let mut format = None;
    let mut elements: Vec<Element> = Vec::new();
    for (ln, line) in text.lines().enumerate().skip(1) {
        let tok: Vec<&str> = line.split_whitespace().collect();
        let bad = || {
            err(format!(
                "malformed header line {}: '{}'",
                ln + 1,
                line.trim()
            ))
        };
        match tok.first().copied() {
            None | Some("comment") | Some("obj_info") => {}
            Some("format") => {
                format = Some(match tok.get(1).copied() {
                    Some("ascii") => Format::Ascii,
                    Some("binary_little_endian") => Format::LittleEndian,
                    Some("binary_big_endian") => Format::BigEndian,
                    _ => return Err(bad()),
                });
            }
            Some("element") => {
                if tok.len() != 3 {
                    return Err(bad());
                }
                let count = tok[2].parse().map_err(|_| bad())?;
                elements.push(Element {
                    name: tok[1].to_string(),
                    count,
                    props: Vec::new(),
                });
            }
            Some("property") => {
                let el = elements.last_mut().ok_or_else(bad)?;
                let prop = if tok.get(1) == Some(&"list") {
                    if tok.len() != 5 {
                        return Err(bad());
                    }
                    Property {
                        name: tok[4].to_string(),
                        list: Some(Scalar::parse(tok[2]).ok_or_else(bad)?),
                        ty: Scalar::parse(tok[3]).ok_or_else(bad)?,
                    }
                } else {
                    if tok.len() != 3 {
                        return Err(bad());
                    }
                    Property {
                        name: tok[2].to_string(),
                        list: None,
                        ty: Scalar::parse(tok[1]).ok_or_else(bad)?,
                    }
                };
                el.props.push(prop);
            }
            Some(_) => return Err(bad()),
        }
    }
    Ok(Header {
        format: format.ok_or_else(|| err("header has no 'format' line".into()))?,
        elements,
        body_start,
    })
}

/// Sequential reader over the body for either encoding.
struct Body<'a> {
    path: &'a Path,
    format: Format,
    bytes: &'a [u8],
    pos: usize,
}

impl Body<'_> {
    fn value(&mut self, ty: Scalar, what: &dyn Fn() -> String) -> Result<f64, SplatError> {
        if self.format == Format::Ascii {
            while self.pos < self.bytes.len() && self.bytes[self.pos].is_ascii_whitespace() {
                self.pos += 1;
            }
            let start = self.pos;
            while self.pos < self.bytes.len() && !self.bytes[self.pos].is_ascii_whitespace() {
                self.pos += 1;
            }
            if start == self.pos {
                return Err(ply_err(
                    self.path,
                    format!("truncated: file ends before {}", what()),
                ));
            }
            let tok = std::str::from_utf8(&self.bytes[start..self.pos]).unwrap_or("");
            // f32 properties parse as f32 so ASCII round trips are bit-exact.
            let parsed = match ty {
                Scalar::F32 => tok.parse::<f32>().map(f64::from).ok(),
                _ => tok.parse::<f64>().ok(),
            };
            parsed.ok_or_else(|| ply_err(self.path, format!("cannot parse '{tok}' as {}", what())))
        } else {
            let n = ty.size();
            if self.pos + n > self.bytes.len() {
                return Err(ply_err(
                    self.path,
                    format!(
                        "truncated: file ends before {} (offset {}, size {})",
                        what(),
                        self.pos,
                        self.bytes.len()
                    ),
                ));
            }
            let v = ty.decode(&self.bytes[self.pos..], self.format);
            self.pos += n;
            Ok(v)
        }
    }

    fn skip_element(&mut self, el: &Element) -> Result<(), SplatError> {
        let fixed = el.props.iter().all(|p| p.list.is_none());
        if fixed && self.format != Format::Ascii {
            let size: usize = el.props.iter().map(|p| p.ty.size()).sum();
            let total = size.saturating_mul(el.count);
            if self.bytes.len() - self.pos < total {
                return Err(ply_err(
                    self.path,
                    format!("truncated inside element '{}'", el.name),
                ));
            }
            self.pos += total;
            return Ok(());
        }
        for i in 0..el.count {
            for p in &el.props {
                let what = || format!("element '{}' #{i} property '{}'", el.name, p.name);
                let n = match p.list {
                    Some(ct) => self.value(ct, &what)? as usize,
                    None => 1,
                };
                for _ in 0..n {
                    self.value(p.ty, &what)?;
                }
            }
        }
        Ok(())
    }
}

/// Reads a Gaussian model from a PLY file (see the module docs for what is accepted).
pub fn read_ply(path: impl AsRef<Path>) -> Result<Gaussians, SplatError> {
    let path = path.as_ref();
    let bytes = std::fs::read(path).map_err(|source| SplatError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    parse_ply(path, &bytes)
}

/// Parses PLY bytes; `path` is only used in error messages.
pub fn parse_ply(path: &Path, bytes: &[u8]) -> Result<Gaussians, SplatError> {
    let header = parse_header(path, bytes)?;
    let vidx = header
        .elements
        .iter()
        .position(|e| e.name == "vertex")
        .ok_or_else(|| ply_err(path, "no 'vertex' element"))?;
    let vertex = &header.elements[vidx];
    if let Some(p) = vertex.props.iter().find(|p| p.list.is_some()) {
        return Err(ply_err(
            path,
            format!("vertex property '{}' is a list", p.name),
        ));
    }
    let find = |name: &str| -> Result<usize, SplatError> {
        vertex
            .props
            .iter()
            .position(|p| p.name == name)
            .ok_or_else(|| ply_err(path, format!("missing required vertex property '{name}'")))
    };
    let mut cols = Vec::new();
    for name in [
        "x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2",
        "rot_0", "rot_1", "rot_2", "rot_3",
    ] {
        cols.push(find(name)?);
    }
    let rest_total = vertex
        .props
        .iter()
        .filter(|p| p.name.starts_with("f_rest_"))
        .count();
    let degree = (0..=MAX_SH_DEGREE)
        .find(|&d| 3 * sh_rest_count(d) == rest_total)
        .ok_or_else(|| {
            ply_err(path, format!("{rest_total} f_rest properties do not match any SH degree 0..3 (need 0, 9, 24 or 45)"))
        })?;
    let mut rest_cols = Vec::with_capacity(rest_total);
    for k in 0..rest_total {
        rest_cols.push(find(&format!("f_rest_{k}"))?);
    }

    let mut body = Body {
        path,
        format: header.format,
        bytes,
        pos: header.body_start,
    };
    for el in &header.elements[..vidx] {
        body.skip_element(el)?;
    }
    let n = vertex.count;
    let k = sh_rest_count(degree);
    if header.format != Format::Ascii {
        let size: usize = vertex.props.iter().map(|p| p.ty.size()).sum();
        let need = size.saturating_mul(n);
        let have = bytes.len() - body.pos;
        if have < need {
            return Err(ply_err(
                path,
                format!("truncated: {n} vertices need {need} bytes of data, file has {have}"),
            ));
        }
    }
    let mut g = Gaussians::new(degree);
    // A lying vertex count must not trigger a huge allocation before the data runs out.
    g.means.reserve(n.min(bytes.len()));
    let mut row = vec![0.0f32; vertex.props.len()];
    let mut rest = vec![Vec3::ZERO; k];
    for i in 0..n {
        for (j, p) in vertex.props.iter().enumerate() {
            let v = body.value(p.ty, &|| format!("vertex {i} property '{}'", p.name))?;
            let v = v as f32;
            if !v.is_finite() {
                return Err(ply_err(
                    path,
                    format!("vertex {i} property '{}' is {v} (not finite)", p.name),
                ));
            }
            row[j] = v;
        }
        let c = |m: usize| row[cols[m]];
        for (kk, r) in rest.iter_mut().enumerate() {
            *r = Vec3::new(
                row[rest_cols[kk]],
                row[rest_cols[k + kk]],
                row[rest_cols[2 * k + kk]],
            );
        }
        g.push(
            Vec3::new(c(0), c(1), c(2)),
            Vec3::new(c(7), c(8), c(9)),
            [c(10), c(11), c(12), c(13)],
            c(6),
            Vec3::new(c(3), c(4), c(5)),
            &rest,
        );
    }
    Ok(g)
}

/// The INRIA header for `g` (binary little-endian float32).
fn header_for(g: &Gaussians) -> String {
    let mut h = String::from("ply\nformat binary_little_endian 1.0\n");
    h += &format!("element vertex {}\n", g.len());
    let mut names: Vec<String> = [
        "x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    names.extend((0..3 * g.rest_count()).map(|k| format!("f_rest_{k}")));
    names.extend(
        [
            "opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3",
        ]
        .iter()
        .map(|s| s.to_string()),
    );
    for n in names {
        h += &format!("property float {n}\n");
    }
    h + "end_header\n"
}

/// Writes `g` in the INRIA layout, atomically: the data goes to a temporary file in the
/// destination directory which is then renamed over `path`.
pub fn write_ply(path: impl AsRef<Path>, g: &Gaussians) -> Result<(), SplatError> {
    let path = path.as_ref();
    g.validate()?;
    let finite = g
        .means
        .iter()
        .chain(&g.log_scales)
        .chain(&g.sh_dc)
        .chain(&g.sh_rest)
        .all(|v| v.is_finite())
        && g.rotations.iter().flatten().all(|v| v.is_finite())
        && g.logit_opacities.iter().all(|v| v.is_finite());
    if !finite {
        return Err(ply_err(path, "refusing to write non-finite parameters"));
    }
    let k = g.rest_count();
    let mut data = header_for(g).into_bytes();
    data.reserve(g.len() * 4 * (17 + 3 * k));
    for i in 0..g.len() {
        let mut put = |v: f32| data.extend_from_slice(&v.to_le_bytes());
        g.means[i].to_array().into_iter().for_each(&mut put);
        [0.0; 3].into_iter().for_each(&mut put);
        g.sh_dc[i].to_array().into_iter().for_each(&mut put);
        let rest = g.sh_rest_of(i);
        for c in 0..3 {
            rest.iter().for_each(|r| put(r[c]));
        }
        put(g.logit_opacities[i]);
        g.log_scales[i].to_array().into_iter().for_each(&mut put);
        g.rotations[i].into_iter().for_each(&mut put);
    }
    write_atomically(path, &data)
}

fn write_atomically(path: &Path, data: &[u8]) -> Result<(), SplatError> {
    let io = |source| SplatError::Io {
        path: path.to_path_buf(),
        source,
    };
    let dir: PathBuf = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let mut tmp = tempfile::NamedTempFile::new_in(&dir).map_err(io)?;
    tmp.write_all(data).map_err(io)?;
    tmp.as_file().sync_all().map_err(io)?;
    tmp.persist(path).map_err(|e| io(e.error))?;
    Ok(())
}
