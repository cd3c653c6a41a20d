//! The point cloud a nerfstudio capture names in `ply_file_path` (what `ns-process-data`
//! writes from COLMAP's points, and Polycam or Record3D their own): a PLY whose first element,
//! `vertex`, has `x y z` and, when present, `red green blue` (8 or 16 bits, or floats in
//! [0, 1]). Read whole within the model-file limit; the declared count is checked against the
//! bytes the body holds before anything is reserved, and every point against the coordinate
//! limit. Elements after the vertices (faces of a mesh) are not read.

use std::io::{BufRead, Cursor};
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::Path;

use glam::DVec3;
use ply_rs_bw::parser::{Parser, Reader};
use ply_rs_bw::ply::{DefaultElement, Encoding, Property, PropertyType, ScalarType};

use crate::error::{Result, SceneError};
use crate::limits;
use crate::points::PointCloud;

/// Most points a cloud may hold: 720 MB as the positions and colours initialisation keeps,
/// far above a sparse reconstruction's few hundred thousand.
pub const MAX_POINTS: usize = 20_000_000;

fn scalar_bytes(t: &ScalarType) -> u64 {
    match t {
        ScalarType::Char | ScalarType::UChar => 1,
        ScalarType::Short | ScalarType::UShort => 2,
        ScalarType::Int | ScalarType::UInt | ScalarType::Float => 4,
        ScalarType::Double => 8,
    }
}

fn number(p: &Property) -> Option<f64> {
    Some(match p {
        Property::Char(v) => *v as f64,
        Property::UChar(v) => *v as f64,
        Property::Short(v) => *v as f64,
        Property::UShort(v) => *v as f64,
        Property::Int(v) => *v as f64,
        Property::UInt(v) => *v as f64,
        Property::Float(v) => *v as f64,
        Property::Double(v) => *v,
        _ => return None,
    })
}

/// Reads the cloud at `path`; errors name the file and, for a bad point, its index.
pub fn read_points_ply(path: &Path) -> Result<PointCloud> {
    SceneError::check_file_size(path, base::limits::MAX_MODEL_FILE_BYTES)?;
    let bytes = base::input::read(path).map_err(|e| SceneError::io(path, e))?;
    let bad = |problem: String| SceneError::invalid(path, problem);
    // No panic of the parser is known; one on a hostile file must still be an error.
    catch_unwind(AssertUnwindSafe(|| parse(&bytes, &bad)))
        .unwrap_or_else(|_| Err(bad("the PLY parser failed on this file".into())))
}

fn parse(bytes: &[u8], bad: &dyn Fn(String) -> SceneError) -> Result<PointCloud> {
    let mut reader = Reader::new(Cursor::new(bytes));
    let parser = Parser::<DefaultElement>::new();
    let header = parser
        .read_header(&mut reader)
        .map_err(|e| bad(format!("not a PLY point cloud: {e}")))?;
    let header_len = reader.get_ref().position() as usize;
    // A name declared twice overwrites its entry in the parser's name-keyed map, and the
    // rows would then be misread.
    let declared = |kw: &[u8]| {
        bytes[..header_len]
            .split(|&c| c == b'\n')
            .filter(|l| l.starts_with(kw) && l.get(kw.len()) == Some(&b' '))
            .count()
    };
    let properties: usize = header.elements.values().map(|e| e.properties.len()).sum();
    if declared(b"element") != header.elements.len() || declared(b"property") != properties {
        return Err(bad(
            "the PLY header declares an element or property name twice".into(),
        ));
    }
    let Some((0, _, vertex)) = header.elements.get_full("vertex") else {
        return Err(bad(
            "a point cloud's first PLY element must be 'vertex'".into()
        ));
    };
    let mut row_bytes = 0u64;
    for p in vertex.properties.values() {
        match &p.data_type {
            PropertyType::Scalar(t) => row_bytes += scalar_bytes(t),
            PropertyType::List(..) => {
                return Err(bad(format!("vertex property '{}' is a list", p.name)));
            }
        }
    }
    let scalar = |name: &str| match vertex.properties.get(name).map(|p| &p.data_type) {
        Some(PropertyType::Scalar(t)) => Some(t.clone()),
        _ => None,
    };
    for name in ["x", "y", "z"] {
        if scalar(name).is_none() {
            return Err(bad(format!("no vertex property '{name}'")));
        }
    }
    let colour_types: Vec<Option<ScalarType>> =
        ["red", "green", "blue"].iter().map(|n| scalar(n)).collect();
    let colour_scale = match colour_types.as_slice() {
        [None, None, None] => None,
        [Some(a), Some(b), Some(c)] if a == b && b == c => Some(match a {
            ScalarType::UChar => 1.0 / 255.0,
            ScalarType::UShort => 1.0 / 65535.0,
            ScalarType::Float | ScalarType::Double => 1.0,
            t => {
                return Err(bad(format!(
                    "colours of type {t:?}; 8- or 16-bit unsigned or floats are read"
                )));
            }
        }),
        _ => {
            return Err(bad(
                "red, green and blue must be all present with one type, or all absent".into(),
            ));
        }
    };
    let n = vertex.count;
    if n == 0 {
        return Err(bad("the cloud has no points".into()));
    }
    if n > MAX_POINTS {
        return Err(bad(format!(
            "{n} points, more than the {MAX_POINTS} a cloud may have"
        )));
    }
    let body = (bytes.len() - header_len) as u64;
    let need = match header.encoding {
        // Every ASCII value takes a character and a separator at least.
        Encoding::Ascii => 2 * vertex.properties.len() as u64 * n as u64,
        _ => row_bytes * n as u64,
    };
    if need > body {
        return Err(bad(format!(
            "truncated: {n} points need at least {need} bytes, the body holds {body}"
        )));
    }
    let mut cloud = PointCloud {
        positions: Vec::with_capacity(n),
        colors: Vec::with_capacity(n),
    };
    let mut line = String::new();
    for i in 0..n {
        let row = match header.encoding {
            Encoding::Ascii => {
                line.clear();
                reader
                    .get_mut()
                    .read_line(&mut line)
                    .map_err(|e| bad(format!("point {i}: {e}")))?;
                parser.read_ascii_element(line.trim_end(), vertex)
            }
            Encoding::BinaryLittleEndian => {
                parser.read_little_endian_element(reader.get_mut(), vertex)
            }
            Encoding::BinaryBigEndian => parser.read_big_endian_element(reader.get_mut(), vertex),
        }
        .map_err(|e| {
            bad(format!(
                "point {i}: {}",
                e.to_string().lines().next().unwrap_or("")
            ))
        })?;
        let get = |name: &str| row.get(name).and_then(number).unwrap_or(f64::NAN);
        let xyz = [get("x"), get("y"), get("z")];
        limits::check_point(xyz).map_err(|p| bad(format!("point {i}: {p}")))?;
        cloud.positions.push(DVec3::from_array(xyz));
        let rgb = match colour_scale {
            None => [0.5; 3],
            Some(s) => {
                let rgb = [get("red"), get("green"), get("blue")].map(|v| (v * s) as f32);
                if let Some(c) = rgb.iter().find(|c| !(0.0..=1.0).contains(*c)) {
                    return Err(bad(format!(
                        "point {i}: the colour value {c} is outside [0, 1]"
                    )));
                }
                rgb
            }
        };
        cloud.colors.push(rgb);
    }
    Ok(cloud)
}
