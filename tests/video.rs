//! Videos through the real ffmpeg: a clip rendered to `.mp4`, restored frame by frame into
//! another `.mp4` at its rate. Without ffmpeg on the PATH these tests say so and pass, unless
//! `METASPLAT_REQUIRE_FFMPEG=1` (set by CI, which installs it) makes that a failure.

mod common;

use common::cli::{ok, s, small_psf};
use std::path::{Path, PathBuf};
use std::process::Command;

/// The ffmpeg on the PATH, or None with the reason printed (a failure under
/// `METASPLAT_REQUIRE_FFMPEG=1`).
fn ffmpeg() -> Option<PathBuf> {
    let found = std::env::split_paths(&std::env::var_os("PATH").unwrap_or_default())
        .map(|d| d.join("ffmpeg"))
        .find(|p| p.is_file());
    if found.is_none() {
        if std::env::var("METASPLAT_REQUIRE_FFMPEG").is_ok_and(|v| v == "1") {
            panic!("METASPLAT_REQUIRE_FFMPEG=1 but there is no ffmpeg on the PATH");
        }
        eprintln!("SKIP: the video tests need ffmpeg on the PATH");
    }
    found
}

/// The frames of `video` decoded by ffmpeg into `dir`: their count and the first one's size.
fn decoded(ffmpeg: &Path, video: &Path, dir: &Path) -> (usize, (u32, u32)) {
    std::fs::create_dir_all(dir).unwrap();
    let status = Command::new(ffmpeg)
        .args(["-hide_banner", "-loglevel", "error", "-i"])
        .arg(video)
        .arg(dir.join("f%03d.png"))
        .status()
        .unwrap();
    assert!(
        status.success(),
        "ffmpeg could not decode {}",
        video.display()
    );
    let count = std::fs::read_dir(dir).unwrap().count();
    let first = image::open(dir.join("f001.png")).unwrap();
    (count, (first.width(), first.height()))
}

/// An orbit of 6 frames rendered as `.mp4` at 12 frames per second, then restored through the
/// network into `.mp4`: both decode to 6 frames of the clip's size, the restored clip at the
/// same rate and not the input again, and the parts folder is gone.
#[test]
fn a_rendered_mp4_restores_into_an_mp4_at_its_rate() {
    let Some(ffmpeg) = ffmpeg() else { return };
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let ply = d.join("scene.ply");
    splat::formats::ply::write_ply(&ply, &splat::synthetic::random_box_scene(3, 800, 0)).unwrap();
    let clip = d.join("clip.mp4");
    let text = ok(&[
        "render",
        "--in",
        s(&ply),
        "--video",
        s(&clip),
        "--orbit",
        "6",
        "--width",
        "64",
        "--height",
        "48",
        "--fps",
        "12",
        "--device",
        "cpu",
    ]);
    assert!(text.contains("through ffmpeg"), "{text}");
    assert_eq!(decoded(&ffmpeg, &clip, &d.join("clip")), (6, (64, 48)));

    let psf = d.join("psf.npy");
    small_psf(&psf);
    let restored = d.join("restored.mp4");
    let text = ok(&[
        "restore",
        "--in",
        s(&clip),
        "--out",
        s(&restored),
        "--psf",
        s(&psf),
        "--any-grid",
    ]);
    assert!(text.contains("at 12 frames per second"), "{text}");
    assert_eq!(
        decoded(&ffmpeg, &restored, &d.join("restored")),
        (6, (64, 48))
    );
    assert!(!d.join("restored.mp4.parts").exists());
    let a = image::open(d.join("clip/f003.png")).unwrap().to_rgb8();
    let b = image::open(d.join("restored/f003.png")).unwrap().to_rgb8();
    assert_ne!(a, b, "the restored clip is the input again");
}
