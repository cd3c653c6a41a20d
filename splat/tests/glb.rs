//! glTF (`KHR_gaussian_splatting`) both ways: values kept, the frame turn rendered, bad files
//! refused with the file and the problem.

mod common;

use common::{random_scene, test_camera};
use glam::{Mat3, Vec3};
use splat::formats::glb::{half_turn, parse_glb, read_glb, to_glb, write_glb};
use splat::{Camera, RenderSettings, render};

fn psnr(a: &[Vec3], b: &[Vec3]) -> f64 {
    base::psnr_rgb(a, b).unwrap()
}

fn settings(deg: u32) -> RenderSettings {
    RenderSettings {
        sh_degree: deg,
        background: Vec3::new(0.1, 0.2, 0.3),
        antialiased: false,
    }
}

#[test]
fn round_trip_keeps_every_value() {
    let dir = tempfile::tempdir().unwrap();
    for deg in 0..=3 {
        let g = random_scene(40 + deg as u64, 300, deg, (0.02, 0.3), 1.2);
        let path = dir.path().join(format!("s{deg}.glb"));
        write_glb(&path, &g).unwrap();
        let back = read_glb(&path).unwrap();
        assert_eq!(back.len(), g.len());
        assert_eq!(back.sh_degree, deg);
        // The half turn negates coordinates: exact.
        assert_eq!(back.means, g.means);
        assert_eq!(back.sh_dc, g.sh_dc);
        assert_eq!(back.sh_rest, g.sh_rest);
        for i in 0..g.len() {
            let rel = |a: f32, b: f32| (a - b).abs() / b.abs().max(1e-6);
            for k in 0..3 {
                let (a, b) = (back.log_scales[i][k].exp(), g.log_scales[i][k].exp());
                assert!(rel(a, b) < 1e-6, "scale {a} vs {b}");
            }
            let (a, b) = (
                splat::model::sigmoid(back.logit_opacities[i]),
                splat::model::sigmoid(g.logit_opacities[i]),
            );
            assert!(rel(a, b) < 1e-6, "opacity {a} vs {b}");
            // Unit quaternions in the file; ours are compared normalised.
            let q = g.rotations[i];
            let len = q.iter().map(|v| v * v).sum::<f32>().sqrt();
            for (got, want) in back.rotations[i].iter().zip(q) {
                assert!((got - want / len).abs() < 1e-6);
            }
        }
        let cam = test_camera(48, 36, 40.0);
        let (a, b) = (
            render(&g, &cam, &settings(deg)).unwrap().color,
            render(&back, &cam, &settings(deg)).unwrap().color,
        );
        let p = psnr(&b, &a);
        assert!(p >= 60.0, "degree {deg}: {p} dB");
    }
}

#[test]
fn the_half_turn_is_a_rigid_rotation_of_the_scene() {
    // Render the turned scene from the turned camera: the same image, which checks positions,
    // orientations and every SH band's signs together.
    let g = random_scene(7, 200, 3, (0.05, 0.4), 1.0);
    let cam = test_camera(50, 40, 45.0);
    let rz = Mat3::from_diagonal(Vec3::new(-1.0, -1.0, 1.0));
    let turned_cam = Camera {
        rotation: cam.rotation * rz,
        ..cam.clone()
    };
    let a = render(&g, &cam, &settings(3)).unwrap().color;
    let b = render(&half_turn(&g, false), &turned_cam, &settings(3))
        .unwrap()
        .color;
    let p = psnr(&b, &a);
    assert!(p >= 80.0, "{p} dB");
    // And the turn really moves things: the unturned camera sees another image.
    let c = render(&half_turn(&g, false), &cam, &settings(3))
        .unwrap()
        .color;
    assert!(psnr(&c, &a) < 40.0);
    // Back and forth is the identity (the quaternion keeps its sign).
    let back = half_turn(&half_turn(&g, false), true);
    assert_eq!(back.rotations, g.rotations);
    assert_eq!(back.sh_rest, g.sh_rest);
}

#[test]
fn the_file_is_a_gltf_with_the_extension() {
    let g = random_scene(3, 10, 1, (0.05, 0.2), 1.0);
    let bytes = to_glb(&g).unwrap();
    let glb = gltf::binary::Glb::from_slice(&bytes).unwrap();
    let doc: serde_json::Value = serde_json::from_slice(&glb.json).unwrap();
    let prim = &doc["meshes"][0]["primitives"][0];
    assert_eq!(prim["mode"], 0);
    assert_eq!(
        prim["extensions"]["KHR_gaussian_splatting"]["kernel"],
        "ellipse"
    );
    let attrs = prim["attributes"].as_object().unwrap();
    for name in [
        "POSITION",
        "COLOR_0",
        "KHR_gaussian_splatting:ROTATION",
        "KHR_gaussian_splatting:SCALE",
        "KHR_gaussian_splatting:OPACITY",
        "KHR_gaussian_splatting:SH_DEGREE_0_COEF_0",
        "KHR_gaussian_splatting:SH_DEGREE_1_COEF_0",
        "KHR_gaussian_splatting:SH_DEGREE_1_COEF_2",
    ] {
        assert!(attrs.contains_key(name), "{name} missing");
    }
    let pos = &doc["accessors"][attrs["POSITION"].as_u64().unwrap() as usize];
    assert!(pos["min"].is_array() && pos["max"].is_array());
}

#[test]
fn bad_files_are_refused_with_the_problem() {
    let p = std::path::Path::new("scene.glb");
    let g = random_scene(5, 20, 0, (0.05, 0.2), 1.0);
    let bytes = to_glb(&g).unwrap();
    // Truncations and garbage: errors, never panics.
    for cut in [0, 3, 12, 19, 20, 40, bytes.len() / 2, bytes.len() - 1] {
        let err = parse_glb(p, &bytes[..cut]).unwrap_err().to_string();
        assert!(err.contains("scene.glb"), "{err}");
    }
    let mut rng = base::SplitMix64::new(1);
    for _ in 0..300 {
        let mut b = bytes.clone();
        for _ in 0..4 {
            let i = (rng.next_u64() % b.len() as u64) as usize;
            b[i] = rng.next_u64() as u8;
        }
        let _ = parse_glb(p, &b);
    }
    // An older draft's log scales.
    let mut old = g.clone();
    old.log_scales[0] = Vec3::splat(-3.0);
    let glb = to_glb(&old).unwrap();
    let doc: serde_json::Value =
        serde_json::from_slice(&gltf::binary::Glb::from_slice(&glb).unwrap().json).unwrap();
    let scale_acc = doc["meshes"][0]["primitives"][0]["attributes"]["KHR_gaussian_splatting:SCALE"]
        .as_u64()
        .unwrap() as usize;
    let view = doc["accessors"][scale_acc]["bufferView"].as_u64().unwrap() as usize;
    let offset = doc["bufferViews"][view]["byteOffset"].as_u64().unwrap() as usize;
    let parsed = gltf::binary::Glb::from_slice(&glb).unwrap();
    let mut bin = parsed.bin.unwrap().to_vec();
    bin[offset..offset + 4].copy_from_slice(&(-3.0f32).to_le_bytes());
    let out = gltf::binary::Glb {
        header: parsed.header,
        json: parsed.json,
        bin: Some(bin.into()),
    }
    .to_vec()
    .unwrap();
    let err = parse_glb(p, &out).unwrap_err().to_string();
    assert!(
        err.contains("log scale") && err.contains("scene.glb"),
        "{err}"
    );
    // A glTF without the extension.
    let err = parse_glb(
        p,
        b"glTF\x02\x00\x00\x00\x14\x00\x00\x00\x00\x00\x00\x00JSON",
    )
    .unwrap_err()
    .to_string();
    assert!(err.contains("scene.glb"), "{err}");
}

#[test]
fn gltf_with_an_embedded_buffer_reads_as_the_glb_does() {
    let dir = tempfile::tempdir().unwrap();
    let g = random_scene(9, 120, 2, (0.02, 0.3), 1.0);
    let (a, b) = (dir.path().join("s.glb"), dir.path().join("s.gltf"));
    write_glb(&a, &g).unwrap();
    splat::formats::glb::write_gltf(&b, &g).unwrap();
    let (x, y) = (
        read_glb(&a).unwrap(),
        splat::formats::glb::read_gltf(&b).unwrap(),
    );
    assert_eq!(x.means, y.means);
    assert_eq!(x.log_scales, y.log_scales);
    assert_eq!(x.rotations, y.rotations);
    assert_eq!(x.logit_opacities, y.logit_opacities);
    assert_eq!(x.sh_rest, y.sh_rest);
    // The text is plain glTF JSON; an external buffer is refused with the way out.
    let text = std::fs::read_to_string(&b).unwrap();
    assert!(text.contains("KHR_gaussian_splatting") && text.contains("base64,"));
    let ext = dir.path().join("ext.gltf");
    std::fs::write(
        &ext,
        text.replacen("data:application/octet-stream;base64,", "x.bin#", 1),
    )
    .unwrap();
    let err = splat::formats::glb::read_gltf(&ext)
        .unwrap_err()
        .to_string();
    assert!(err.contains("ext.gltf") && err.contains(".glb"), "{err}");
    // The other media type the specification names for embedded buffers reads the same.
    let other = dir.path().join("other.gltf");
    std::fs::write(
        &other,
        text.replacen(
            "data:application/octet-stream;base64,",
            "data:application/gltf-buffer;base64,",
            1,
        ),
    )
    .unwrap();
    assert_eq!(splat::formats::glb::read_gltf(&other).unwrap(), y);
}
