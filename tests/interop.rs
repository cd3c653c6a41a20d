//! Our splat files checked by the tools people open them with (installed from npm by
//! `.ci/run` into `target/npm-tools`, or where `METASPLAT_NPM_TOOLS` points): Khronos'
//! glTF-Validator and PlayCanvas' splat-transform. Without Node or the tools these tests say
//! so and pass, unless `METASPLAT_REQUIRE_TOOLS=1` (set by CI) makes that a failure.

use std::path::{Path, PathBuf};
use std::process::Command;

use glam::Vec3;
use splat::{Camera, Gaussians, RenderSettings};

fn tools() -> Option<PathBuf> {
    let dir = std::env::var_os("METASPLAT_NPM_TOOLS")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("target/npm-tools"));
    let ok = dir.join("node_modules/.bin/splat-transform").exists()
        && dir.join("node_modules/gltf-validator").exists()
        && Command::new("node").arg("--version").output().is_ok();
    if ok {
        return Some(dir);
    }
    let why = format!(
        "Node.js with gltf-validator and @playcanvas/splat-transform under {}",
        dir.display()
    );
    if std::env::var("METASPLAT_REQUIRE_TOOLS").is_ok_and(|v| v == "1") {
        panic!("METASPLAT_REQUIRE_TOOLS=1 but there is no {why}");
    }
    eprintln!("SKIP: interop tests need {why}");
    None
}

fn scene() -> Gaussians {
    let mut g = splat::synthetic::random_box_scene(3, 3000, 3);
    // Larger splats than the benchmark's, so the image is well covered.
    for s in &mut g.log_scales {
        *s += Vec3::splat(1.0);
    }
    g
}

fn camera() -> Camera {
    splat::synthetic::benchmark_camera().resized(160, 120)
}

fn psnr(a: &Gaussians, b: &Gaussians) -> f64 {
    let s = RenderSettings {
        sh_degree: a.sh_degree.min(b.sh_degree),
        background: Vec3::new(0.2, 0.3, 0.4),
        antialiased: false,
    };
    let ra = splat::render(a, &camera(), &s).unwrap();
    let rb = splat::render(b, &camera(), &s).unwrap();
    assert!(
        ra.alpha.iter().any(|v| *v > 0.5),
        "the scene is not in view"
    );
    base::psnr_rgb(&rb.color, &ra.color).unwrap()
}

fn splat_transform(tools: &Path, input: &Path, output: &Path) {
    let out = Command::new(tools.join("node_modules/.bin/splat-transform"))
        .arg("-w")
        .arg(input)
        .arg(output)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "splat-transform {} -> {}: {}",
        input.display(),
        output.display(),
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn our_glb_passes_the_khronos_validator() {
    let Some(tools) = tools() else { return };
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("scene.glb");
    splat::glb::write_glb(&path, &scene()).unwrap();
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/tools/validate-glb.js");
    let out = Command::new("node")
        .arg(&script)
        .arg(&path)
        .env("NODE_PATH", tools.join("node_modules"))
        .output()
        .unwrap();
    let report = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "validator: {report} {}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(report.contains("\"errors\":0"), "{report}");
    // The same document as .gltf text with its buffer embedded.
    let text = dir.path().join("scene.gltf");
    splat::glb::write_gltf(&text, &scene()).unwrap();
    let out = Command::new("node")
        .arg(&script)
        .arg(&text)
        .env("NODE_PATH", tools.join("node_modules"))
        .output()
        .unwrap();
    let report = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success() && report.contains("\"errors\":0"),
        "{report}"
    );
}

#[test]
fn splat_transform_and_we_agree_on_ply_and_glb() {
    let Some(tools) = tools() else { return };
    let dir = tempfile::tempdir().unwrap();
    let g = scene();
    let ours = dir.path().join("ours.ply");
    splat::ply::write_ply(&ours, &g).unwrap();
    // Its GLB of our PLY, read by us: the same scene, so the frame conventions agree.
    let its_glb = dir.path().join("its.glb");
    splat_transform(&tools, &ours, &its_glb);
    let from_glb = splat::glb::read_glb(&its_glb).unwrap();
    assert_eq!(from_glb.len(), g.len());
    let p = psnr(&g, &from_glb);
    eprintln!("splat-transform's GLB of our PLY, rendered by us: {p:.1} dB");
    assert!(p >= 50.0, "{p} dB");
    // Its PLY of our PLY.
    let its_ply = dir.path().join("its.ply");
    splat_transform(&tools, &ours, &its_ply);
    let p = psnr(&g, &splat::ply::read_ply(&its_ply).unwrap());
    assert!(p >= 50.0, "{p} dB");
    // Our GLB, read back by us after its round trip through our PLY writer: exact scene.
    let our_glb = dir.path().join("ours.glb");
    splat::glb::write_glb(&our_glb, &g).unwrap();
    let p = psnr(&g, &splat::glb::read_glb(&our_glb).unwrap());
    assert!(p >= 60.0, "{p} dB");
}

#[test]
fn splat_transform_and_we_agree_on_spz() {
    let Some(tools) = tools() else { return };
    let dir = tempfile::tempdir().unwrap();
    let g = scene();
    let ours_ply = dir.path().join("ours.ply");
    splat::ply::write_ply(&ours_ply, &g).unwrap();
    // It reads our SPZ: its PLY of it matches our scene within SPZ's quantisation.
    let ours_spz = dir.path().join("ours.spz");
    splat::spz::write_spz(&ours_spz, &g).unwrap();
    let its_ply = dir.path().join("its.ply");
    splat_transform(&tools, &ours_spz, &its_ply);
    let p = psnr(&g, &splat::ply::read_ply(&its_ply).unwrap());
    eprintln!("our SPZ through splat-transform: {p:.1} dB");
    assert!(p >= 38.0, "{p} dB");
    // We read its SPZ of our PLY, in version 3 (gzip) and its default version 4 (ZSTD).
    for version in ["3", "4"] {
        let its_spz = dir.path().join(format!("its_v{version}.spz"));
        let out = Command::new(tools.join("node_modules/.bin/splat-transform"))
            .args(["-w", "--spz-version", version])
            .arg(&ours_ply)
            .arg(&its_spz)
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let head = std::fs::read(&its_spz).unwrap();
        assert_eq!(
            head[..2] == [0x1f, 0x8b],
            version == "3",
            "v{version}: gzip or not"
        );
        let theirs = splat::spz::read_spz(&its_spz).unwrap();
        assert_eq!(theirs.len(), g.len());
        // Its own decoding of its file is the reference for our reader; against the original
        // scene its SPZ loses more than ours (it quantises SH to 5 and 4 bits, we keep 8).
        let its_decoding = dir.path().join(format!("its_decoding_v{version}.ply"));
        splat_transform(&tools, &its_spz, &its_decoding);
        let same = psnr(&splat::ply::read_ply(&its_decoding).unwrap(), &theirs);
        let lossy = psnr(&g, &theirs);
        eprintln!(
            "splat-transform's SPZ v{version} read by us: {same:.1} dB against its own reading, {lossy:.1} dB against the scene"
        );
        assert!(same >= 50.0, "v{version}: {same} dB");
        assert!(lossy >= 30.0, "v{version}: {lossy} dB");
    }
}
