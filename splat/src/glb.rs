//! glTF binary (`.glb`) with Khronos' `KHR_gaussian_splatting` (the Release Candidate text
//! of April 2026), both ways.
//!
//! Mapping, per splat: `POSITION`; `KHR_gaussian_splatting:ROTATION` (unit quaternion in
//! **x, y, z, w** order; ours is w, x, y, z); `:SCALE` (**linear**, the exponent of our log
//! scale; an earlier draft stored log scale, so a file with a negative scale is refused
//! saying so); `:OPACITY` (after the sigmoid, in [0, 1]); `:SH_DEGREE_0_COEF_0` (our DC
//! coefficient) and `:SH_DEGREE_l_COEF_n` (one RGB triple per coefficient, n over m = −l..l,
//! the INRIA order we store in). The primitive is `POINTS`, the extension object names
//! `kernel: "ellipse"` and `colorSpace: "srgb_rec709_display"`, and `COLOR_0` carries the DC
//! colour (linear, with opacity as alpha) so viewers without the extension show a point cloud.
//!
//! Frames: our scenes are in the capture's frame (OpenCV-style, +y down). PlayCanvas'
//! splat-transform treats PLY data as rotated 180° about Z against glTF and bakes that
//! rotation into its GLB; so do we, on export and (inverted) on import. Rotating the scene
//! rotates each splat's orientation and its SH: under a half turn about Z a real SH
//! coefficient of order m changes sign when m is odd.
//!
//! The `gltf` crate reads and writes the GLB container; its JSON model cannot name the
//! extension's attributes (it accepts only glTF's own semantics and `_`-prefixed ones), so the
//! JSON document is written and read here with `serde_json`.

use std::path::Path;

use glam::Vec3;
use serde_json::{Value, json};

use crate::error::SplatError;
use crate::model::{Gaussians, MAX_SH_DEGREE, logit, sigmoid};
use crate::sh::{num_bases, sh_dc_to_rgb};

const EXT: &str = "KHR_gaussian_splatting";
const FLOAT: u64 = 5126;

/// The half turn about Z between our frame and glTF's: `(x, y, z) → (−x, −y, z)`.
fn turn_point(p: Vec3) -> Vec3 {
    Vec3::new(-p.x, -p.y, p.z)
}

/// The same half turn applied to an orientation (w, x, y, z): `q_z(π) · q`.
fn turn_quat([w, x, y, z]: [f32; 4]) -> [f32; 4] {
    [-z, -y, x, w]
}

/// Inverse of [`turn_quat`] (the half turn is its own inverse up to the quaternion's sign).
fn unturn_quat([w, x, y, z]: [f32; 4]) -> [f32; 4] {
    [z, y, -x, -w]
}

/// Sign of SH coefficient `k` (k ≥ 1, INRIA order: m = −l..l) under the half turn.
fn turn_sign(k: usize) -> f32 {
    let (_, m) = degree_order(k);
    if m.rem_euclid(2) == 1 { -1.0 } else { 1.0 }
}

/// Degree `l` and order `m` of SH basis function `k` (INRIA order: m = −l..l).
fn degree_order(k: usize) -> (i64, i64) {
    let mut l = 0i64;
    while ((l + 1) * (l + 1)) as usize <= k {
        l += 1;
    }
    (l, k as i64 - l * l - l)
}

/// `g` seen after the half turn about Z between our frame and glTF's (`inverse`: back):
/// positions, orientations and SH coefficients turned; scales and opacities unchanged.
pub fn half_turn(g: &Gaussians, inverse: bool) -> Gaussians {
    let mut t = g.clone();
    for m in &mut t.means {
        *m = turn_point(*m);
    }
    for q in &mut t.rotations {
        *q = if inverse {
            unturn_quat(*q)
        } else {
            turn_quat(*q)
        };
    }
    let rc = g.rest_count();
    for (j, c) in t.sh_rest.iter_mut().enumerate() {
        *c *= turn_sign(j % rc.max(1) + 1);
    }
    t
}

fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

/// The GLB bytes of `g`.
pub fn to_glb(g: &Gaussians) -> Result<Vec<u8>, SplatError> {
    let (doc, bin) = document(g)?;
    let json = serde_json::to_vec(&doc).map_err(|e| SplatError::InvalidModel(e.to_string()))?;
    let glb = gltf::binary::Glb {
        header: gltf::binary::Header {
            magic: *b"glTF",
            version: 2,
            length: 0,
        },
        json: json.into(),
        bin: Some(bin.into()),
    };
    glb.to_vec()
        .map_err(|e| SplatError::InvalidModel(format!("cannot encode GLB: {e}")))
}

const DATA_URI: &str = "data:application/octet-stream;base64,";

/// The `.gltf` text of `g`: the same document with its buffer embedded as a base64 data URI.
pub fn to_gltf(g: &Gaussians) -> Result<String, SplatError> {
    use base64::Engine;
    let (mut doc, bin) = document(g)?;
    let uri = format!(
        "{DATA_URI}{}",
        base64::engine::general_purpose::STANDARD.encode(&bin)
    );
    doc["buffers"][0]["uri"] = Value::String(uri);
    serde_json::to_string(&doc).map_err(|e| SplatError::InvalidModel(e.to_string()))
}

/// The glTF document of `g` and its binary buffer.
fn document(g: &Gaussians) -> Result<(Value, Vec<u8>), SplatError> {
    if !g.finite_except_opacity() || g.logit_opacities.iter().any(|o| o.is_nan()) {
        return Err(SplatError::InvalidModel(
            "refusing to write non-finite parameters".into(),
        ));
    }
    let g = &half_turn(g, false);
    let n = g.len();
    let rc = g.rest_count();
    let mut bin: Vec<u8> = Vec::new();
    let mut views = Vec::new();
    let mut accessors = Vec::new();
    let mut attributes = serde_json::Map::new();
    let mut add = |name: String, kind: &str, width: usize, values: Vec<f32>, bounds: bool| {
        let offset = bin.len();
        bin.extend(values.iter().flat_map(|v| v.to_le_bytes()));
        views.push(json!({"buffer": 0, "byteOffset": offset, "byteLength": values.len() * 4}));
        let mut acc = json!({
            "bufferView": views.len() - 1,
            "componentType": FLOAT,
            "count": n,
            "type": kind,
        });
        if bounds && n > 0 {
            let (mut lo, mut hi) = (vec![f32::INFINITY; width], vec![f32::NEG_INFINITY; width]);
            for c in values.chunks_exact(width) {
                for k in 0..width {
                    lo[k] = lo[k].min(c[k]);
                    hi[k] = hi[k].max(c[k]);
                }
            }
            acc["min"] = json!(lo);
            acc["max"] = json!(hi);
        }
        accessors.push(acc);
        attributes.insert(name, json!(accessors.len() - 1));
    };
    add(
        "POSITION".into(),
        "VEC3",
        3,
        g.means.iter().flat_map(|m| m.to_array()).collect(),
        true,
    );
    add(
        format!("{EXT}:ROTATION"),
        "VEC4",
        4,
        g.rotations
            .iter()
            .flat_map(|q| {
                // Unit length, as the extension requires (the zero quaternion is the identity).
                let [w, x, y, z] = *q;
                let len = (w * w + x * x + y * y + z * z).sqrt();
                if len > 0.0 {
                    [x / len, y / len, z / len, w / len]
                } else {
                    [0.0, 0.0, 1.0, 0.0]
                }
            })
            .collect(),
        false,
    );
    add(
        format!("{EXT}:SCALE"),
        "VEC3",
        3,
        g.log_scales
            .iter()
            .flat_map(|s| s.exp().to_array())
            .collect(),
        false,
    );
    add(
        format!("{EXT}:OPACITY"),
        "SCALAR",
        1,
        g.logit_opacities.iter().map(|o| sigmoid(*o)).collect(),
        false,
    );
    add(
        format!("{EXT}:SH_DEGREE_0_COEF_0"),
        "VEC3",
        3,
        g.sh_dc.iter().flat_map(|c| c.to_array()).collect(),
        false,
    );
    for k in 1..num_bases(g.sh_degree) {
        let (l, m) = degree_order(k);
        let coef = m + l;
        add(
            format!("{EXT}:SH_DEGREE_{l}_COEF_{coef}"),
            "VEC3",
            3,
            (0..n)
                .flat_map(|i| g.sh_rest[i * rc + k - 1].to_array())
                .collect(),
            false,
        );
    }
    add(
        "COLOR_0".into(),
        "VEC4",
        4,
        (0..n)
            .flat_map(|i| {
                let c = sh_dc_to_rgb(g.sh_dc[i]).clamp(Vec3::ZERO, Vec3::ONE);
                [
                    srgb_to_linear(c.x),
                    srgb_to_linear(c.y),
                    srgb_to_linear(c.z),
                    sigmoid(g.logit_opacities[i]),
                ]
            })
            .collect(),
        false,
    );
    let doc = json!({
        "asset": {"version": "2.0", "generator": "metasplat"},
        "extensionsUsed": [EXT],
        "buffers": [{"byteLength": bin.len()}],
        "bufferViews": views,
        "accessors": accessors,
        "meshes": [{"primitives": [{
            "mode": 0,
            "attributes": attributes,
            "extensions": {EXT: {"kernel": "ellipse", "colorSpace": "srgb_rec709_display"}},
        }]}],
        "nodes": [{"mesh": 0}],
        "scenes": [{"nodes": [0]}],
        "scene": 0,
    });
    Ok((doc, bin))
}

/// Writes `g` as a `.gltf` file with its buffer embedded (atomically, ordinary permissions).
pub fn write_gltf(path: impl AsRef<Path>, g: &Gaussians) -> Result<(), SplatError> {
    let path = path.as_ref();
    let text = to_gltf(g)?;
    base::write_bytes_atomically(path, text.as_bytes()).map_err(|source| SplatError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// Reads a `.gltf` file whose buffer is embedded as a data URI.
pub fn read_gltf(path: impl AsRef<Path>) -> Result<Gaussians, SplatError> {
    use base64::Engine;
    let path = path.as_ref();
    let bad = |problem: String| SplatError::Ply {
        path: path.to_path_buf(),
        problem,
    };
    let bytes = std::fs::read(path).map_err(|source| SplatError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let doc: Value =
        serde_json::from_slice(&bytes).map_err(|e| bad(format!("bad glTF JSON: {e}")))?;
    let uri = doc["buffers"][0]["uri"]
        .as_str()
        .ok_or_else(|| bad("no buffer URI".into()))?;
    let data = uri.strip_prefix(DATA_URI).ok_or_else(|| {
        bad("only buffers embedded as base64 data URIs are read (export a .glb instead)".into())
    })?;
    let bin = base64::engine::general_purpose::STANDARD
        .decode(data)
        .map_err(|e| bad(format!("bad base64 buffer: {e}")))?;
    parse_document(path, &doc, &bin)
}

/// Writes `g` as a GLB file (atomically, ordinary permissions).
pub fn write_glb(path: impl AsRef<Path>, g: &Gaussians) -> Result<(), SplatError> {
    let path = path.as_ref();
    let bytes = to_glb(g)?;
    base::write_bytes_atomically(path, &bytes).map_err(|source| SplatError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// Reads a GLB file with a `KHR_gaussian_splatting` primitive.
pub fn read_glb(path: impl AsRef<Path>) -> Result<Gaussians, SplatError> {
    let path = path.as_ref();
    let bytes = std::fs::read(path).map_err(|source| SplatError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    parse_glb(path, &bytes)
}

/// Parses GLB bytes (`path` only names the file in errors).
pub fn parse_glb(path: &Path, bytes: &[u8]) -> Result<Gaussians, SplatError> {
    let bad = |problem: String| SplatError::Ply {
        path: path.to_path_buf(),
        problem,
    };
    // The container reader subtracts the header size from the declared length unchecked.
    if bytes.len() < 20 || &bytes[..4] != b"glTF" {
        return Err(bad("not a GLB file (no glTF header)".into()));
    }
    let declared = u32::from_le_bytes(bytes[8..12].try_into().expect("4 bytes")) as usize;
    if declared < 20 || declared > bytes.len() {
        return Err(bad(format!(
            "the header declares {declared} bytes, the file has {}",
            bytes.len()
        )));
    }
    let glb = gltf::binary::Glb::from_slice(bytes).map_err(|e| bad(format!("bad GLB: {e}")))?;
    let doc: Value =
        serde_json::from_slice(&glb.json).map_err(|e| bad(format!("bad glTF JSON: {e}")))?;
    let bin = glb
        .bin
        .as_deref()
        .ok_or_else(|| bad("no binary chunk (external buffers are not read)".into()))?;
    parse_document(path, &doc, bin)
}

/// The scene of a glTF document with its buffer 0 in `bin`.
fn parse_document(path: &Path, doc: &Value, bin: &[u8]) -> Result<Gaussians, SplatError> {
    let bad = |problem: String| SplatError::Ply {
        path: path.to_path_buf(),
        problem,
    };
    let prim = doc["meshes"]
        .as_array()
        .into_iter()
        .flatten()
        .flat_map(|m| m["primitives"].as_array().into_iter().flatten())
        .find(|p| p["extensions"].get(EXT).is_some())
        .ok_or_else(|| bad(format!("no primitive with {EXT}")))?;
    let attrs = &prim["attributes"];
    let read = |name: &str, width: usize| -> Result<Option<Vec<f32>>, SplatError> {
        let Some(index) = attrs.get(name) else {
            return Ok(None);
        };
        let acc = index
            .as_u64()
            .and_then(|i| doc["accessors"].get(i as usize))
            .ok_or_else(|| bad(format!("{name}: no such accessor")))?;
        if acc["componentType"].as_u64() != Some(FLOAT) {
            return Err(bad(format!("{name}: only float attributes are read")));
        }
        let count = acc["count"]
            .as_u64()
            .ok_or_else(|| bad(format!("{name}: no count")))? as usize;
        let view = acc["bufferView"]
            .as_u64()
            .and_then(|i| doc["bufferViews"].get(i as usize))
            .ok_or_else(|| {
                bad(format!(
                    "{name}: no buffer view (sparse accessors are not read)"
                ))
            })?;
        if view["buffer"].as_u64().unwrap_or(0) != 0 {
            return Err(bad(format!("{name}: data outside the GLB's own buffer")));
        }
        let stride = view["byteStride"].as_u64().unwrap_or(4 * width as u64) as usize;
        let start = view["byteOffset"].as_u64().unwrap_or(0) as usize
            + acc["byteOffset"].as_u64().unwrap_or(0) as usize;
        let end = count
            .checked_sub(1)
            .map_or(Some(start), |c| {
                c.checked_mul(stride)?
                    .checked_add(start)?
                    .checked_add(4 * width)
            })
            .ok_or_else(|| bad(format!("{name}: {count} values overflow")))?;
        if stride < 4 * width || end > bin.len() {
            return Err(bad(format!(
                "{name}: {count} values of stride {stride} from byte {start} do not fit the {}-byte buffer",
                bin.len()
            )));
        }
        let mut out = Vec::with_capacity(count * width);
        for i in 0..count {
            let at = start + i * stride;
            for k in 0..width {
                let b = &bin[at + 4 * k..at + 4 * k + 4];
                out.push(f32::from_le_bytes(b.try_into().expect("4 bytes")));
            }
        }
        Ok(Some(out))
    };
    let need = |name: &str, width: usize| -> Result<Vec<f32>, SplatError> {
        read(name, width)?.ok_or_else(|| bad(format!("no {name} attribute")))
    };
    let pos = need("POSITION", 3)?;
    let n = pos.len() / 3;
    let rot = need(&format!("{EXT}:ROTATION"), 4)?;
    let scale = need(&format!("{EXT}:SCALE"), 3)?;
    let opacity = need(&format!("{EXT}:OPACITY"), 1)?;
    let dc = need(&format!("{EXT}:SH_DEGREE_0_COEF_0"), 3)?;
    for (name, len, width) in [
        ("ROTATION", rot.len(), 4),
        ("SCALE", scale.len(), 3),
        ("OPACITY", opacity.len(), 1),
        ("SH_DEGREE_0_COEF_0", dc.len(), 3),
    ] {
        if len != n * width {
            return Err(bad(format!(
                "{EXT}:{name} has {} values, POSITION {n}",
                len / width
            )));
        }
    }
    if let Some(s) = scale.iter().find(|s| **s < 0.0 || s.is_nan()) {
        return Err(bad(format!(
            "negative scale {s}: this file stores log scales (an earlier draft of {EXT}); \
             the current text stores linear scales"
        )));
    }
    // The degree: the highest whose every coefficient is present.
    let mut rest_cols: Vec<Vec<f32>> = Vec::new();
    let mut degree = 0;
    'deg: for l in 1..=MAX_SH_DEGREE as usize {
        let mut cols = Vec::new();
        for c in 0..2 * l + 1 {
            match read(&format!("{EXT}:SH_DEGREE_{l}_COEF_{c}"), 3)? {
                Some(v) if v.len() == 3 * n => cols.push(v),
                Some(_) => return Err(bad(format!("SH degree {l} has a wrong count"))),
                None if c == 0 => break 'deg,
                None => return Err(bad(format!("SH degree {l} is incomplete"))),
            }
        }
        rest_cols.extend(cols);
        degree = l as u32;
    }
    let mut g = Gaussians::new(degree);
    let mut rest = vec![Vec3::ZERO; rest_cols.len()];
    for i in 0..n {
        let v3 = |a: &[f32]| Vec3::new(a[3 * i], a[3 * i + 1], a[3 * i + 2]);
        for (k, col) in rest_cols.iter().enumerate() {
            rest[k] = v3(col);
        }
        g.push(
            v3(&pos),
            v3(&scale).map(f32::ln),
            [rot[4 * i + 3], rot[4 * i], rot[4 * i + 1], rot[4 * i + 2]],
            logit(opacity[i].clamp(0.0, 1.0)),
            v3(&dc),
            &rest,
        );
    }
    g.validate()?;
    Ok(half_turn(&g, true))
}
