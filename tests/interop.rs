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
    splat::formats::glb::write_glb(&path, &scene()).unwrap();
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
    splat::formats::glb::write_gltf(&text, &scene()).unwrap();
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
    splat::formats::ply::write_ply(&ours, &g).unwrap();
    // Its GLB of our PLY, read by us: the same scene, so the frame conventions agree.
    let its_glb = dir.path().join("its.glb");
    splat_transform(&tools, &ours, &its_glb);
    let from_glb = splat::formats::glb::read_glb(&its_glb).unwrap();
    assert_eq!(from_glb.len(), g.len());
    let p = psnr(&g, &from_glb);
    eprintln!("splat-transform's GLB of our PLY, rendered by us: {p:.1} dB");
    assert!(p >= 50.0, "{p} dB");
    // Its PLY of our PLY.
    let its_ply = dir.path().join("its.ply");
    splat_transform(&tools, &ours, &its_ply);
    let p = psnr(&g, &splat::formats::ply::read_ply(&its_ply).unwrap());
    assert!(p >= 50.0, "{p} dB");
    // Our GLB, read back by us after its round trip through our PLY writer: exact scene.
    let our_glb = dir.path().join("ours.glb");
    splat::formats::glb::write_glb(&our_glb, &g).unwrap();
    let p = psnr(&g, &splat::formats::glb::read_glb(&our_glb).unwrap());
    assert!(p >= 60.0, "{p} dB");
}

#[test]
fn splat_transform_and_we_agree_on_spz() {
    let Some(tools) = tools() else { return };
    let dir = tempfile::tempdir().unwrap();
    let g = scene();
    let ours_ply = dir.path().join("ours.ply");
    splat::formats::ply::write_ply(&ours_ply, &g).unwrap();
    // It reads our SPZ: its PLY of it matches our scene within SPZ's quantisation.
    let ours_spz = dir.path().join("ours.spz");
    splat::formats::spz::write_spz(&ours_spz, &g).unwrap();
    let its_ply = dir.path().join("its.ply");
    splat_transform(&tools, &ours_spz, &its_ply);
    let p = psnr(&g, &splat::formats::ply::read_ply(&its_ply).unwrap());
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
        let theirs = splat::formats::spz::read_spz(&its_spz).unwrap();
        assert_eq!(theirs.len(), g.len());
        // Its own decoding of its file is the reference for our reader; against the original
        // scene its SPZ loses more than ours (it quantises SH to 5 and 4 bits, we keep 8).
        let its_decoding = dir.path().join(format!("its_decoding_v{version}.ply"));
        splat_transform(&tools, &its_spz, &its_decoding);
        let same = psnr(
            &splat::formats::ply::read_ply(&its_decoding).unwrap(),
            &theirs,
        );
        let lossy = psnr(&g, &theirs);
        eprintln!(
            "splat-transform's SPZ v{version} read by us: {same:.1} dB against its own reading, {lossy:.1} dB against the scene"
        );
        assert!(same >= 50.0, "v{version}: {same} dB");
        assert!(lossy >= 30.0, "v{version}: {lossy} dB");
    }
}

/// The npm tools, Node and Chromium for the web-viewer check, or None (with the reason
/// printed; a failure under `METASPLAT_REQUIRE_TOOLS=1`).
fn web_tools() -> Option<(PathBuf, PathBuf)> {
    let dir = tools()?;
    let chromium = std::env::var_os("METASPLAT_CHROMIUM")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("/usr/bin/chromium"));
    let missing: Vec<&str> = ["playwright-core", "three", "@sparkjsdev/spark"]
        .into_iter()
        .filter(|m| !dir.join("node_modules").join(m).exists())
        .collect();
    if missing.is_empty() && chromium.exists() {
        return Some((dir, chromium));
    }
    let why = format!(
        "Chromium at {} and the npm packages {:?} under {}",
        chromium.display(),
        missing,
        dir.display()
    );
    if std::env::var("METASPLAT_REQUIRE_TOOLS").is_ok_and(|v| v == "1") {
        panic!("METASPLAT_REQUIRE_TOOLS=1 but there is no {why}");
    }
    eprintln!("SKIP: the web-viewer check needs {why}");
    None
}

/// Pearson correlation of two images' luminance.
fn correlation(a: &[Vec3], b: &[Vec3]) -> f64 {
    let lum = |v: &Vec3| (0.299 * v.x + 0.587 * v.y + 0.114 * v.z) as f64;
    let (x, y): (Vec<f64>, Vec<f64>) = a.iter().zip(b).map(|(p, q)| (lum(p), lum(q))).unzip();
    let n = x.len() as f64;
    let (mx, my) = (x.iter().sum::<f64>() / n, y.iter().sum::<f64>() / n);
    let (mut sxy, mut sxx, mut syy) = (0.0, 0.0, 0.0);
    for (p, q) in x.iter().zip(&y) {
        sxy += (p - mx) * (q - my);
        sxx += (p - mx) * (p - mx);
        syy += (q - my) * (q - my);
    }
    sxy / (sxx * syy).sqrt().max(1e-30)
}

/// Lowest correlation accepted between Spark's picture of our file and our render of the same
/// camera: the two renderers differ in colour handling and antialiasing, not in geometry.
const WEB_VIEWER_MIN_CORRELATION: f64 = 0.97;

#[test]
fn a_web_viewer_shows_our_files() {
    let Some((tools, chromium)) = web_tools() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    // An object that is not symmetric, so a flipped or mirrored picture would not pass.
    let g = scene();
    let (center, radius) = splat::camera::scene_bounds(&g.means).unwrap();
    let eye = center + Vec3::new(0.4, -0.5, -2.5) * radius;
    let (w, h, fov) = (320u32, 240u32, 50.0f32);
    let cam = viewer::ViewCamera::looking(eye, center, fov.to_radians()).camera(w, h);
    let ours = splat::render(&g, &cam, &RenderSettings::default())
        .unwrap()
        .color;
    for ext in ["ply", "spz"] {
        let file = dir.path().join(format!("scene.{ext}"));
        splat::formats::files::write_splats(&file, &g).unwrap();
        let shot = dir.path().join(format!("spark_{ext}.png"));
        let pose: Vec<String> = [eye, center]
            .iter()
            .flat_map(|v| v.to_array())
            .map(|x| x.to_string())
            .collect();
        let out = Command::new("node")
            .arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/tools/spark-screenshot.mjs"))
            .arg(&tools)
            .arg(&file)
            .arg(&shot)
            .args([w.to_string(), h.to_string(), fov.to_string()])
            .args(&pose)
            .env("METASPLAT_CHROMIUM", &chromium)
            .output()
            .unwrap();
        let text = String::from_utf8_lossy(&out.stdout).to_string()
            + &String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "Spark on our {ext}: {text}");
        assert!(
            text.contains(&format!("splats {}", g.len())),
            "Spark on our {ext}: {text}"
        );
        let picture = image::open(&shot).unwrap().to_rgb8();
        assert_eq!(picture.dimensions(), (w, h));
        let theirs: Vec<Vec3> = picture
            .pixels()
            .map(|p| Vec3::new(p[0] as f32, p[1] as f32, p[2] as f32) / 255.0)
            .collect();
        let lit = theirs.iter().filter(|p| p.max_element() > 0.1).count();
        let r = correlation(&ours, &theirs);
        eprintln!(
            "Spark's picture of our {ext}: correlation {r:.3} with our render, {lit} lit pixels"
        );
        assert!(
            lit > (w * h / 20) as usize,
            "Spark's picture of our {ext} is nearly blank"
        );
        assert!(
            r >= WEB_VIEWER_MIN_CORRELATION,
            "Spark's picture of our {ext}: correlation {r:.3}"
        );
        // The threshold tells pictures apart: the same picture mirrored does not pass.
        let mirrored: Vec<Vec3> = (0..(w * h) as usize)
            .map(|i| theirs[i - i % w as usize + (w as usize - 1 - i % w as usize)])
            .collect();
        let rm = correlation(&ours, &mirrored);
        assert!(
            rm < WEB_VIEWER_MIN_CORRELATION,
            "a mirrored picture correlates {rm:.3}"
        );
    }
}
