//! The viewer: its comparison images are the training pipeline's pixels, and a real window
//! (under Xvfb, on lavapipe in CI) shows what the headless renderer renders.
//!
//! The window tests need an X display and a GPU adapter. Without `DISPLAY` they start `Xvfb`
//! when it is installed; without either they skip with a printed reason, and
//! `METASPLAT_REQUIRE_DISPLAY=1` (set by CI) makes that a failure.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output};
use std::sync::OnceLock;

use metasplat::output::view::{
    CLEAN, CaptureComparison, PHOTO, REBLURRED, REFINED, RENDER, RESTORED,
};
use metasplat::settings::{self, DataOptions};
use metasplat::splats::procedural::{ProceduralOptions, ground_truth};
use metasplat::train::config::Mode;
use metasplat::train::data;
use metasplat::train::objective::Objective;

const W: u32 = 128;
const H: u32 = 96;

struct Fixture {
    _dir: tempfile::TempDir,
    aberrated: PathBuf,
    ply: PathBuf,
}

/// A 128×96 procedural capture, aberrated, and its ground-truth scene as a PLY.
fn fixture() -> &'static Fixture {
    static F: OnceLock<Fixture> = OnceLock::new();
    F.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap();
        let o = ProceduralOptions {
            width: W,
            height: H,
            views: 8,
            seed: 3,
        };
        let (_, aberrated, _) = common::aberrated_procedural(dir.path(), &o);
        let ply = dir.path().join("truth.ply");
        splat::formats::ply::write_ply(&ply, &ground_truth(o.seed)).unwrap();
        Fixture {
            _dir: dir,
            aberrated,
            ply,
        }
    })
}

fn options() -> DataOptions {
    DataOptions {
        downsample: 1,
        restorer: settings::RestorerChoice::Wiener,
        ..DataOptions::default()
    }
}

#[test]
fn comparison_images_are_the_training_pipelines_pixels() {
    let f = fixture();
    let model = ground_truth(3);
    let dataset = data::load(&f.aberrated, Mode::Aware, &options()).unwrap();
    let objective = Objective {
        mode: Mode::Aware,
        lambda: 0.5,
        dssim_weight: 0.2,
        imaging: dataset.imaging.as_ref(),
        width: dataset.width,
        height: dataset.height,
        outside: None,
    };
    let mut comparison = CaptureComparison::open(&f.aberrated, &options()).unwrap();
    let view = &dataset.train[1];
    let index = dataset
        .capture
        .cameras
        .iter()
        .position(|c| c.name == view.name)
        .unwrap();
    let settings = splat::RenderSettings {
        sh_degree: model.sh_degree,
        ..Default::default()
    };
    let render = splat::render(&model, &view.camera, &settings)
        .unwrap()
        .color;
    let panels = comparison.panels_for(index, &render).unwrap();
    let get = |name: &str| {
        panels
            .iter()
            .find(|p| p.name == name)
            .unwrap_or_else(|| panic!("no panel {name}"))
    };
    assert_eq!(get(PHOTO).pixels, view.observed);
    assert_eq!(get(RENDER).pixels, render);
    assert_eq!(
        get(REBLURRED).pixels,
        objective.as_observed(&render, None).unwrap()
    );
    assert_eq!(&get(RESTORED).pixels, view.restored.as_ref().unwrap());
    let clean = view.clean.as_ref().unwrap();
    assert_eq!(&get(CLEAN).pixels, clean);
    // Every PSNR printed is against the clean image, and the re-blurred ground truth is
    // much closer to the photo than to the clean image it came from.
    for p in &panels {
        match p.name.as_str() {
            CLEAN => assert!(p.psnr_vs_clean.is_none()),
            _ => {
                let want = base::psnr_rgb(&p.pixels, clean).unwrap();
                assert_eq!(p.psnr_vs_clean, Some(want), "{}", p.name);
            }
        }
    }
    let photo_vs_reblurred = base::psnr_rgb(&get(PHOTO).pixels, &get(REBLURRED).pixels).unwrap();
    assert!(photo_vs_reblurred > get(REBLURRED).psnr_vs_clean.unwrap() + 3.0);
    // A render of the wrong size is refused, not compared.
    assert!(comparison.panels_for(index, &render[1..]).is_err());

    // A run's refined grid adds the render through it, beside the one through the capture's.
    let tmp = tempfile::tempdir().unwrap();
    let supplied = dataset.imaging.as_ref().unwrap().psf();
    let mut p = [0.0; aberration::refine::warp::PARAMS];
    p[0] = 0.2;
    let refined = aberration::refine::warp::warp_grid(supplied, &p).unwrap();
    let path = tmp.path().join("psf_refined.npy");
    refined.save_npy(&path).unwrap();
    comparison.with_refined_psf(&path).unwrap();
    let panels = comparison.panels_for(index, &render).unwrap();
    let through = panels
        .iter()
        .find(|p| p.name == REFINED)
        .expect("a refined panel");
    let want = dataset
        .imaging
        .as_ref()
        .unwrap()
        .with_psf(refined)
        .unwrap()
        .blur_pixels(&render)
        .unwrap();
    assert_eq!(through.pixels, want);
    assert_ne!(through.pixels, get(REBLURRED).pixels);
    // A grid of another size (a run at another --downsample) is refused, naming the file.
    aberration::PsfGrid::delta(3, 5).save_npy(&path).unwrap();
    let err = comparison.with_refined_psf(&path).unwrap_err().to_string();
    assert!(
        err.contains("psf_refined.npy") && err.contains("--downsample"),
        "{err}"
    );
}

fn run(args: &[&str], display: Option<&str>) -> Output {
    let mut c = Command::new(env!("CARGO_BIN_EXE_metasplat"));
    c.args(args);
    match display {
        Some(d) => c.env("DISPLAY", d),
        None => c.env_remove("DISPLAY"),
    };
    c.env_remove("WAYLAND_DISPLAY");
    c.output().expect("the binary runs")
}

#[test]
fn without_a_display_the_viewer_says_so() {
    let f = fixture();
    let out = run(&["view", f.ply.to_str().unwrap()], None);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert_ne!(out.status.code(), Some(101), "{err}");
    assert!(!err.contains("panicked"), "{err}");
    assert!(err.contains("no display"), "{err}");
}

#[test]
fn bad_viewer_arguments_are_refused_before_a_window_opens() {
    let f = fixture();
    let ply = f.ply.to_str().unwrap();
    let scene = f.aberrated.to_str().unwrap();
    for (args, says) in [
        (vec!["view", "/nonexistent/x.ply"], "/nonexistent/x.ply"),
        (
            vec![
                "view",
                ply,
                "--scene",
                scene,
                "--downsample",
                "1",
                "--at",
                "nosuch",
            ],
            "--at nosuch",
        ),
        (vec!["view", ply, "--screenshot", ply], "--screenshot"),
        (vec!["view"], "give a splat scene file"),
    ] {
        let out = run(&args, Some(":12345"));
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{args:?}");
        assert!(!err.contains("panicked"), "{args:?}: {err}");
        assert!(err.contains(says), "{args:?} should mention {says}: {err}");
    }
    // The scene file was not touched by the refused screenshot.
    assert!(splat::formats::files::read_splats(&f.ply).is_ok());
}

/// An X display for the window tests: the environment's, or an Xvfb started for the test.
struct Display {
    name: String,
    server: Option<Child>,
}

impl Drop for Display {
    fn drop(&mut self) {
        if let Some(s) = &mut self.server {
            let _ = s.kill();
            let _ = s.wait();
        }
    }
}

fn required() -> bool {
    std::env::var("METASPLAT_REQUIRE_DISPLAY").is_ok_and(|v| v == "1")
}

fn skip(why: &str) -> Option<Display> {
    if required() {
        panic!("METASPLAT_REQUIRE_DISPLAY=1 but {why}");
    }
    eprintln!("SKIP: {why}");
    None
}

fn display() -> Option<Display> {
    if let Err(e) = splat::gpu::GpuContext::new() {
        return skip(&format!("there is no GPU adapter for the viewer: {e}"));
    }
    if let Some(d) = std::env::var("DISPLAY").ok().filter(|d| !d.is_empty()) {
        return Some(Display {
            name: d,
            server: None,
        });
    }
    // A display number unlikely to be taken: different per test process and per test.
    static NEXT: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);
    let k = NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let n = 100 + (std::process::id() % 300) * 8 + k;
    let name = format!(":{n}");
    let server = match Command::new("Xvfb")
        .args([
            name.as_str(),
            "-screen",
            "0",
            "1280x1024x24",
            "-nolisten",
            "tcp",
        ])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
    {
        Ok(s) => s,
        Err(e) => return skip(&format!("no DISPLAY and Xvfb cannot start ({e})")),
    };
    let socket = PathBuf::from(format!("/tmp/.X11-unix/X{n}"));
    for _ in 0..100 {
        if socket.exists() {
            return Some(Display {
                name,
                server: Some(server),
            });
        }
        std::thread::sleep(std::time::Duration::from_millis(100));
    }
    skip("Xvfb did not come up within 10 s")
}

fn read_png(p: &Path) -> image::RgbImage {
    image::open(p)
        .unwrap_or_else(|e| panic!("{}: {e}", p.display()))
        .to_rgb8()
}

fn psnr(a: &image::RgbImage, b: &image::RgbImage) -> f64 {
    assert_eq!(a.dimensions(), b.dimensions());
    let mse = a
        .as_raw()
        .iter()
        .zip(b.as_raw())
        .map(|(&x, &y)| (x as f64 - y as f64).powi(2))
        .sum::<f64>()
        / a.as_raw().len() as f64;
    10.0 * (255.0f64 * 255.0 / mse.max(1e-12)).log10()
}

fn succeed(args: &[&str], display: &Display) -> String {
    let out = run(args, Some(&display.name));
    let text =
        String::from_utf8_lossy(&out.stdout).to_string() + &String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "metasplat {args:?} failed:\n{text}");
    text
}

#[test]
fn a_window_at_a_capture_camera_shows_the_headless_render() {
    let Some(display) = display() else {
        return;
    };
    let f = fixture();
    let dir = tempfile::tempdir().unwrap();
    let (ply, scene) = (f.ply.to_str().unwrap(), f.aberrated.to_str().unwrap());
    let shot = dir.path().join("window.png");
    let capture = scenes::open(
        &f.aberrated,
        &scenes::OpenOptions {
            resolution: scenes::Resolution::Downsample(1),
            ..Default::default()
        },
    )
    .unwrap();
    let name = capture.cameras[2].name.clone();
    succeed(
        &[
            "view",
            ply,
            "--scene",
            scene,
            "--downsample",
            "1",
            "--at",
            &name,
            "--screenshot",
            shot.to_str().unwrap(),
            "--frames",
            "3",
        ],
        &display,
    );
    let frames = dir.path().join("frames");
    succeed(
        &[
            "render",
            "--ply",
            ply,
            "--scene",
            scene,
            "--downsample",
            "1",
            "--out",
            frames.to_str().unwrap(),
            "--device",
            "cpu",
        ],
        &display,
    );
    let window = read_png(&shot);
    let headless = read_png(&frames.join(format!(
        "{}.png",
        Path::new(&name).file_stem().unwrap().to_str().unwrap()
    )));
    assert_eq!(window.dimensions(), (W, H));
    let db = psnr(&window, &headless);
    assert!(
        db >= 40.0,
        "the window shows {db:.1} dB from the headless render"
    );
    // Not a blank frame that would match a blank render.
    let lit = window.as_raw().iter().filter(|&&v| v > 20).count();
    assert!(
        lit > window.as_raw().len() / 10,
        "the window is mostly black"
    );
}

#[test]
fn a_window_with_a_free_camera_shows_the_headless_render() {
    let Some(display) = display() else {
        return;
    };
    let f = fixture();
    let dir = tempfile::tempdir().unwrap();
    let ply = f.ply.to_str().unwrap();
    let model = ground_truth(3);
    let (c, _) = splat::camera::scene_bounds(&model.means).unwrap();
    let pose = format!(
        "{},{},{},{},{},{}",
        c.x + 0.5,
        c.y - 1.0,
        c.z - 4.0,
        c.x,
        c.y,
        c.z
    );
    let shot = dir.path().join("window.png");
    let size = ["--width", "200", "--height", "150", "--fov", "55"];
    let mut args = vec![
        "view",
        ply,
        "--camera",
        &pose,
        "--screenshot",
        shot.to_str().unwrap(),
    ];
    args.extend(size);
    succeed(&args, &display);
    let frames = dir.path().join("frames");
    let mut args = vec![
        "render",
        "--ply",
        ply,
        "--camera",
        &pose,
        "--out",
        frames.to_str().unwrap(),
        "--device",
        "cpu",
    ];
    args.extend(size);
    succeed(&args, &display);
    let db = psnr(&read_png(&shot), &read_png(&frames.join("camera.png")));
    assert!(
        db >= 40.0,
        "the window shows {db:.1} dB from the headless render"
    );
    // The comparison mode opens at a capture camera and draws its panels.
    let cmp = dir.path().join("compare.png");
    let capture_name = {
        let cap = scenes::open(
            &f.aberrated,
            &scenes::OpenOptions {
                resolution: scenes::Resolution::Downsample(1),
                ..Default::default()
            },
        )
        .unwrap();
        cap.cameras[0].name.clone()
    };
    let text = succeed(
        &[
            "view",
            ply,
            "--scene",
            f.aberrated.to_str().unwrap(),
            "--downsample",
            "1",
            "--at",
            &capture_name,
            "--compare",
            "--restorer",
            "wiener",
            "--screenshot",
            cmp.to_str().unwrap(),
            "--with-panel",
            "--width",
            "900",
            "--height",
            "500",
        ],
        &display,
    );
    assert!(text.contains("Comparison: I_ac"), "{text}");
    let picture = read_png(&cmp);
    assert_eq!(picture.dimensions(), (900, 500));
}

#[test]
fn a_run_being_followed_shows_its_newest_model() {
    use metasplat::output::view::RunWatch;
    let dir = tempfile::tempdir().unwrap();
    let mut watch = RunWatch::new(dir.path());
    // Nothing yet: nothing to show.
    assert!(watch.check().is_none());
    let ply = dir.path().join(metasplat::output::PLY_FILE);
    let g = ground_truth(3);
    splat::formats::ply::write_ply(&ply, &g).unwrap();
    let (first, what) = watch.check().unwrap().unwrap();
    assert_eq!(first.len(), g.len());
    assert!(what.contains("finished run"), "{what}");
    // Unchanged: no reload.
    assert!(watch.check().is_none());
    // A newer file replaces it (a later mtime; file systems may round to a second).
    std::thread::sleep(std::time::Duration::from_millis(1100));
    let other = metasplat::splats::procedural::ground_truth_around(0);
    splat::formats::ply::write_ply(&ply, &other).unwrap();
    let (second, _) = watch.check().unwrap().unwrap();
    assert_eq!(second.len(), other.len());
    assert_ne!(other.len(), g.len());
    // A damaged file is reported, not shown, and not retried until it changes.
    std::thread::sleep(std::time::Duration::from_millis(1100));
    std::fs::write(&ply, b"ply\nnot really").unwrap();
    assert!(watch.check().unwrap().is_err());
    assert!(watch.check().is_none());
}

/// One spelling for a splat file everywhere (`--in`, as `render` and `export` take it), and a
/// run folder given as the file is followed as `--run` follows it: the same picture each way.
#[test]
fn a_run_folder_or_in_opens_as_the_file_does() {
    let Some(display) = display() else {
        return;
    };
    let f = fixture();
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("run");
    std::fs::create_dir_all(&run).unwrap();
    std::fs::copy(&f.ply, run.join(metasplat::output::PLY_FILE)).unwrap();
    let model = ground_truth(3);
    let (c, _) = splat::camera::scene_bounds(&model.means).unwrap();
    let pose = format!(
        "{},{},{},{},{},{}",
        c.x,
        c.y - 1.0,
        c.z - 4.0,
        c.x,
        c.y,
        c.z
    );
    let shot = |name: &str, how: &[&str]| {
        let path = dir.path().join(name);
        let mut args = vec!["view"];
        args.extend(how);
        args.extend(["--camera", &pose, "--width", "160", "--height", "120"]);
        args.extend(["--screenshot", path.to_str().unwrap()]);
        succeed(&args, &display);
        read_png(&path)
    };
    let ply = f.ply.to_str().unwrap();
    let r = run.to_str().unwrap();
    let by_file = shot("file.png", &[ply]);
    assert_eq!(shot("in.png", &["--in", ply]), by_file);
    assert_eq!(shot("folder.png", &[r]), shot("run.png", &["--run", r]));
    assert!(psnr(&shot("folder2.png", &[r]), &by_file) >= 40.0);
}

/// With a capture and no camera asked for, the window opens at the first held-out capture
/// camera (at its size), and `--compare` needs no `--at`.
#[test]
fn with_a_capture_the_window_opens_at_its_first_held_out_camera() {
    let Some(display) = display() else {
        return;
    };
    let f = fixture();
    let dir = tempfile::tempdir().unwrap();
    let cap = scenes::open(
        &f.aberrated,
        &scenes::OpenOptions {
            resolution: scenes::Resolution::Downsample(1),
            ..Default::default()
        },
    )
    .unwrap();
    let first = &cap.cameras[cap.split.test[0]];
    let ply = f.ply.to_str().unwrap();
    let scene = f.aberrated.to_str().unwrap();
    let common = [
        "--scene",
        scene,
        "--downsample",
        "1",
        "--restorer",
        "wiener",
    ];
    let shot = |name: &str, extra: &[&str]| {
        let path = dir.path().join(name);
        let mut args = vec!["view", ply];
        args.extend(common);
        args.extend(extra);
        args.extend(["--screenshot", path.to_str().unwrap()]);
        succeed(&args, &display);
        read_png(&path)
    };
    let default = shot("default.png", &[]);
    assert_eq!(default.dimensions(), (first.width, first.height));
    assert_eq!(shot("at.png", &["--at", &first.name]), default);
    let compared = shot("compare.png", &["--compare"]);
    assert_eq!(compared.dimensions(), (first.width, first.height));
}
