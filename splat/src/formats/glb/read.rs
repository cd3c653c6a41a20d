//! Reading a `KHR_gaussian_splatting` primitive as the glTF 2.0 specification defines the
//! parts we read, checked as Khronos' validator checks them: every index resolves, every
//! accessor has the type and component type its attribute needs, every accessor and buffer
//! view in the file (read or not) lies inside what holds it (sums checked, never wrapped),
//! and every value is one a splat can have. Interpretations, stated: exactly one primitive may carry the extension;
//! the node that shows it must not move it (a transform is refused, not applied, since
//! splats would need their covariances turned with it); an extension the file requires and
//! we do not know is refused; sparse accessors are refused.

use std::path::Path;

use glam::Vec3;
use serde_json::Value;

use super::{EXT, FLOAT, half_turn};
use crate::error::SplatError;
use crate::model::{Gaussians, MAX_SH_DEGREE, logit};

/// The accessor `type` for each element width we read.
fn type_name(width: usize) -> &'static str {
    match width {
        1 => "SCALAR",
        3 => "VEC3",
        _ => "VEC4",
    }
}

/// The identity of each node transform property (the spec's defaults).
fn moves(node: &Value) -> Option<&'static str> {
    let is = |key: &str, identity: &[f64]| {
        node.get(key).is_none_or(|v| {
            v.as_array().is_some_and(|a| {
                a.len() == identity.len()
                    && a.iter().zip(identity).all(|(x, i)| x.as_f64() == Some(*i))
            })
        })
    };
    let identity = [
        1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0,
    ];
    if !is("matrix", &identity) {
        Some("matrix")
    } else if !is("translation", &[0.0; 3]) {
        Some("translation")
    } else if !is("rotation", &[0.0, 0.0, 0.0, 1.0]) {
        Some("rotation")
    } else if !is("scale", &[1.0; 3]) {
        Some("scale")
    } else {
        None
    }
}

/// Bytes of one accessor component, by the spec's `componentType` codes.
fn component_bytes(code: u64) -> Option<u64> {
    match code {
        5120 | 5121 => Some(1),
        5122 | 5123 => Some(2),
        5125 | 5126 => Some(4),
        _ => None,
    }
}

/// Components of one accessor element, by the spec's `type` names.
fn type_components(name: &str) -> Option<u64> {
    match name {
        "SCALAR" => Some(1),
        "VEC2" => Some(2),
        "VEC3" => Some(3),
        "VEC4" | "MAT2" => Some(4),
        "MAT3" => Some(9),
        "MAT4" => Some(16),
        _ => None,
    }
}

/// "accessor N", with the attributes that read it: a broken POSITION is named as such.
fn accessor_name(doc: &Value, a: usize) -> String {
    let mut users = Vec::new();
    for mesh in doc["meshes"].as_array().into_iter().flatten() {
        for prim in mesh["primitives"].as_array().into_iter().flatten() {
            for (name, index) in prim["attributes"].as_object().into_iter().flatten() {
                if index.as_u64() == Some(a as u64) && !users.contains(name) {
                    users.push(name.clone());
                }
            }
        }
    }
    if users.is_empty() {
        format!("accessor {a}")
    } else {
        format!("{} (accessor {a})", users.join(", "))
    }
}

/// Every buffer view inside its buffer and every accessor inside its view, including those
/// the splat primitive does not use: the validator reports a broken file as broken whichever
/// part of it is broken, and a file another tool reads in full must not pass here.
fn check_layout(
    doc: &Value,
    bin_len: u64,
    bad: &dyn Fn(String) -> SplatError,
) -> Result<(), SplatError> {
    let buffers = doc["buffers"].as_array().map_or(&[][..], |v| v.as_slice());
    let views = doc["bufferViews"]
        .as_array()
        .map_or(&[][..], |v| v.as_slice());
    for (v, view) in views.iter().enumerate() {
        let b = view["buffer"].as_u64().unwrap_or(u64::MAX);
        let Some(buffer) = buffers.get(b as usize) else {
            return Err(bad(format!(
                "buffer view {v} reads buffer {}, which does not exist",
                view["buffer"]
            )));
        };
        // Buffer 0 is the file's own bytes; another buffer is held to what it declares.
        let len = if b == 0 {
            bin_len
        } else {
            buffer["byteLength"]
                .as_u64()
                .ok_or_else(|| bad(format!("buffer {b} has no byteLength")))?
        };
        let view_len = view["byteLength"]
            .as_u64()
            .ok_or_else(|| bad(format!("buffer view {v} has no byteLength")))?;
        let start = view["byteOffset"].as_u64().unwrap_or(0);
        if start.checked_add(view_len).is_none_or(|e| e > len) {
            return Err(bad(format!(
                "buffer view {v} ({view_len} bytes from byte {start}) does not fit buffer {b} ({len} bytes)"
            )));
        }
    }
    for (a, acc) in doc["accessors"]
        .as_array()
        .into_iter()
        .flatten()
        .enumerate()
    {
        let at = |problem: String| bad(format!("{}: {problem}", accessor_name(doc, a)));
        let component = acc["componentType"]
            .as_u64()
            .and_then(component_bytes)
            .ok_or_else(|| {
                at(format!(
                    "component type {} is not glTF's",
                    acc["componentType"]
                ))
            })?;
        let width = acc["type"]
            .as_str()
            .and_then(type_components)
            .ok_or_else(|| at(format!("type {} is not glTF's", acc["type"])))?;
        let count = acc["count"].as_u64().ok_or_else(|| at("no count".into()))?;
        if count == 0 {
            return Err(at(
                "count 0; glTF accessors hold at least one element".into()
            ));
        }
        // An accessor without a view is all zeros (or sparse): nothing to lie outside.
        let Some(v) = acc.get("bufferView") else {
            continue;
        };
        let view = v
            .as_u64()
            .and_then(|v| views.get(v as usize))
            .ok_or_else(|| at(format!("buffer view {v} does not exist")))?;
        let element = component * width;
        let stride = view["byteStride"].as_u64().unwrap_or(element).max(element);
        let offset = acc["byteOffset"].as_u64().unwrap_or(0);
        let view_len = view["byteLength"].as_u64().unwrap_or(0);
        let used = (count - 1)
            .checked_mul(stride)
            .and_then(|u| u.checked_add(element))
            .and_then(|u| u.checked_add(offset));
        if used.is_none_or(|u| u > view_len) {
            return Err(at(format!(
                "{count} elements of {element} bytes (stride {stride}) from byte {offset} do not fit buffer view {v} ({view_len} bytes)"
            )));
        }
    }
    Ok(())
}

/// The scene of a glTF document with its buffer 0 in `bin`.
pub(super) fn parse_document(
    path: &Path,
    doc: &Value,
    bin: &[u8],
) -> Result<Gaussians, SplatError> {
    let bad = |problem: String| SplatError::Ply {
        path: path.to_path_buf(),
        problem,
    };
    if let Some(required) = doc["extensionsRequired"].as_array() {
        for e in required {
            if e.as_str() != Some(EXT) {
                return Err(bad(format!(
                    "the file requires the extension {e}, which is not read"
                )));
            }
        }
    }
    let buffer_len = match doc["buffers"][0]["byteLength"].as_u64() {
        Some(n) if n as usize <= bin.len() => n as usize,
        Some(n) => {
            return Err(bad(format!(
                "buffer 0 declares {n} bytes, the file holds {}",
                bin.len()
            )));
        }
        None => return Err(bad("buffer 0 has no byteLength".into())),
    };
    let bin = &bin[..buffer_len];
    check_layout(doc, bin.len() as u64, &bad)?;
    // (mesh, primitive) of every primitive with the extension.
    let mut found = Vec::new();
    for (m, mesh) in doc["meshes"].as_array().into_iter().flatten().enumerate() {
        for (p, prim) in mesh["primitives"]
            .as_array()
            .into_iter()
            .flatten()
            .enumerate()
        {
            if prim["extensions"].get(EXT).is_some() {
                found.push((m, p, prim));
            }
        }
    }
    let (mesh, prim) = match found.as_slice() {
        [] => return Err(bad(format!("no primitive with {EXT}"))),
        [(m, _, prim)] => (*m, *prim),
        more => {
            return Err(bad(format!(
                "{} primitives carry {EXT} (meshes {}); one splat scene per file is read",
                more.len(),
                more.iter()
                    .map(|(m, p, _)| format!("{m} primitive {p}"))
                    .collect::<Vec<_>>()
                    .join(", ")
            )));
        }
    };
    // Splats are points with an ellipse kernel in display sRGB: anything else would be read
    // as if it were (linear colours as sRGB, a box as an ellipse). Left out, the extension's
    // values and POINTS are taken as written by every splat tool we check.
    if let Some(mode) = prim.get("mode")
        && mode.as_u64() != Some(0)
    {
        return Err(bad(format!(
            "mesh {mesh}: the splat primitive's mode is {mode}, not 0 (POINTS)"
        )));
    }
    let ext = &prim["extensions"][EXT];
    for (key, known) in [
        ("kernel", &["ellipse"][..]),
        ("colorSpace", &["srgb_rec709_display"][..]),
        ("projection", &["perspective"][..]),
    ] {
        if let Some(v) = ext.get(key)
            && !known.iter().any(|k| v.as_str() == Some(*k))
        {
            return Err(bad(format!(
                "mesh {mesh}: {EXT} {key} {v} is not read (only {})",
                known.join(", ")
            )));
        }
    }
    // Every node showing the mesh, and every node above one, must leave it where it is.
    let nodes = doc["nodes"].as_array().map_or(&[][..], |v| v.as_slice());
    let parent = |child: usize| {
        nodes.iter().position(|n| {
            n["children"]
                .as_array()
                .is_some_and(|c| c.iter().any(|x| x.as_u64() == Some(child as u64)))
        })
    };
    for (i, node) in nodes.iter().enumerate() {
        if node["mesh"].as_u64() != Some(mesh as u64) {
            continue;
        }
        let mut at = Some(i);
        // A cycle is invalid glTF; the walk stops after as many steps as there are nodes.
        for _ in 0..=nodes.len() {
            let Some(k) = at else { break };
            if let Some(what) = moves(&nodes[k]) {
                return Err(bad(format!(
                    "node {k} places the splats with a {what}; transformed splat scenes are not read (bake the transform into the splats)"
                )));
            }
            at = parent(k);
        }
    }
    let attrs = &prim["attributes"];
    let read = |name: &str, width: usize| -> Result<Option<Vec<f32>>, SplatError> {
        let Some(index) = attrs.get(name) else {
            return Ok(None);
        };
        let a = index.as_u64().unwrap_or(u64::MAX);
        let acc = doc["accessors"]
            .get(a as usize)
            .ok_or_else(|| bad(format!("{name}: accessor {index} does not exist")))?;
        let at = |problem: String| bad(format!("{name} (accessor {a}): {problem}"));
        if acc["componentType"].as_u64() != Some(FLOAT) {
            return Err(at(format!(
                "component type {}; only 32-bit floats ({FLOAT}) are read",
                acc["componentType"]
            )));
        }
        if acc["type"].as_str() != Some(type_name(width)) {
            return Err(at(format!(
                "type {}, but the attribute is a {}",
                acc["type"],
                type_name(width)
            )));
        }
        if acc["normalized"].as_bool() == Some(true) {
            return Err(at("a normalized float accessor is invalid glTF".into()));
        }
        if acc.get("sparse").is_some() {
            return Err(at("sparse accessors are not read".into()));
        }
        let count = acc["count"].as_u64().ok_or_else(|| at("no count".into()))?;
        let v = acc["bufferView"]
            .as_u64()
            .ok_or_else(|| at("no buffer view".into()))?;
        // check_layout put every view inside its buffer and every accessor inside its view
        // (the stride below only narrows what it allowed), so the reads below stay in bounds.
        let view = &doc["bufferViews"][v as usize];
        if view["buffer"].as_u64() != Some(0) {
            return Err(at(format!(
                "buffer view {v} reads buffer {}; only the file's own buffer 0 is read",
                view["buffer"]
            )));
        }
        let view_start = view["byteOffset"].as_u64().unwrap_or(0);
        let element = 4 * width as u64;
        let stride = view["byteStride"].as_u64().unwrap_or(element);
        if stride < element || stride > 252 || !stride.is_multiple_of(4) {
            return Err(at(format!(
                "byte stride {stride}; it must be a multiple of 4 from {element} to 252"
            )));
        }
        let offset = acc["byteOffset"].as_u64().unwrap_or(0);
        if !offset.is_multiple_of(4) || !view_start.is_multiple_of(4) {
            return Err(at("offsets must be multiples of 4 for floats".into()));
        }
        let start = (view_start + offset) as usize;
        let (count, stride) = (count as usize, stride as usize);
        let mut out = Vec::with_capacity(count * width);
        for i in 0..count {
            let at = start + i * stride;
            for k in 0..width {
                let b = &bin[at + 4 * k..at + 4 * k + 4];
                out.push(f32::from_le_bytes(b.try_into().expect("4 bytes")));
            }
        }
        if let Some(i) = out.iter().position(|x| !x.is_finite()) {
            return Err(at(format!(
                "value {} of splat {} is {}",
                i % width,
                i / width,
                out[i]
            )));
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
    if let Some(i) = scale.iter().position(|s| *s < 0.0) {
        return Err(bad(format!(
            "{EXT}:SCALE: splat {} has the negative scale {}: this file stores log scales (an earlier draft of {EXT}); the current text stores linear scales",
            i / 3,
            scale[i]
        )));
    }
    if let Some(i) = scale.iter().position(|s| *s == 0.0 || s.ln().is_infinite()) {
        return Err(bad(format!(
            "{EXT}:SCALE: splat {} has the scale {}; a splat needs a positive extent",
            i / 3,
            scale[i]
        )));
    }
    if let Some(i) = (0..n).find(|i| rot[4 * i..4 * i + 4].iter().all(|q| *q == 0.0)) {
        return Err(bad(format!(
            "{EXT}:ROTATION: splat {i} has the zero quaternion, which is no rotation"
        )));
    }
    if let Some(i) = opacity.iter().position(|o| !(0.0..=1.0).contains(o)) {
        return Err(bad(format!(
            "{EXT}:OPACITY: splat {i} has the opacity {}, outside [0, 1]",
            opacity[i]
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
            logit(opacity[i]),
            v3(&dc),
            &rest,
        );
    }
    g.validate()?;
    Ok(half_turn(&g, true))
}
