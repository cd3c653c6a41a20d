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

mod read;

use std::path::Path;

use glam::Vec3;
use serde_json::{Value, json};

use crate::error::SplatError;
use crate::model::{Gaussians, sigmoid};
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
    let bytes = base::input::read(path).map_err(|source| SplatError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let doc: Value =
        serde_json::from_slice(&bytes).map_err(|e| bad(format!("bad glTF JSON: {e}")))?;
    let uri = doc["buffers"][0]["uri"]
        .as_str()
        .ok_or_else(|| bad("no buffer URI".into()))?;
    // Both media types the glTF specification names for embedded buffers.
    let data = [DATA_URI, "data:application/gltf-buffer;base64,"]
        .iter()
        .find_map(|prefix| uri.strip_prefix(prefix))
        .ok_or_else(|| {
            bad("only buffers embedded as base64 data URIs are read (export a .glb instead)".into())
        })?;
    let bin = base64::engine::general_purpose::STANDARD
        .decode(data)
        .map_err(|e| bad(format!("bad base64 buffer: {e}")))?;
    read::parse_document(path, &doc, &bin)
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
    let bytes = base::input::read(path).map_err(|source| SplatError::Io {
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
    read::parse_document(path, &doc, bin)
}
