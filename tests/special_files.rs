//! Special files where a file is read: a link to an endless device and a FIFO with no writer,
//! given as each kind of input (an initial splat file, a splat file to render, weights, a
//! camera path, a PSF grid, a photo, a checkpoint). Each is refused at once, naming the file,
//! where the commands used to read without a bound or block forever.

mod common;

use std::path::Path;
use std::process::Stdio;
use std::time::{Duration, Instant};

use common::cli::{metasplat, ok, plain_train, procedural, quick_train, s, small_psf};

/// Runs the binary, which must fail within a time limit, without a panic, naming `named`.
fn refused_quickly(args: &[&str], named: &Path) {
    let mut child = metasplat()
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let start = Instant::now();
    loop {
        if child.try_wait().unwrap().is_some() {
            break;
        }
        if start.elapsed() > Duration::from_secs(60) {
            let _ = child.kill();
            panic!("metasplat {args:?} still ran after 60 s");
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    let out = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "metasplat {args:?} succeeded");
    assert!(
        !err.contains("panicked"),
        "metasplat {args:?} panicked:\n{err}"
    );
    let name = named.file_name().unwrap().to_str().unwrap();
    assert!(
        err.contains(name) && err.contains("not a regular file"),
        "metasplat {args:?} did not name {name}:\n{err}"
    );
}

#[cfg(unix)]
#[test]
fn special_files_given_as_inputs_are_refused_at_once() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let scene = d.join("scene");
    procedural(&scene, 32, 24, 6);
    let run = d.join("run");
    ok(&quick_train(&scene, &run, "10", &[]));
    let psf = d.join("psf.npy");
    small_psf(&psf);
    let photo = d.join("photo.png");
    std::fs::copy(
        std::fs::read_dir(scene.join("images"))
            .unwrap()
            .next()
            .unwrap()
            .unwrap()
            .path(),
        &photo,
    )
    .unwrap();
    // Each special file under each name.
    let specials = |name: &str| {
        let link = d.join(format!("zero_{name}"));
        std::os::unix::fs::symlink("/dev/zero", &link).unwrap();
        let fifo = d.join(format!("fifo_{name}"));
        let made = std::process::Command::new("mkfifo").arg(&fifo).status();
        assert!(made.is_ok_and(|s| s.success()), "mkfifo made no FIFO");
        [link, fifo]
    };
    for f in specials("init.ply") {
        let r2 = d.join("r2");
        refused_quickly(&plain_train(&scene, &r2, "10", &["--init", s(&f)]), &f);
    }
    for f in specials("render.ply") {
        refused_quickly(
            &["render", "--in", s(&f), "--out", s(&d.join("frames"))],
            &f,
        );
    }
    for f in specials("path.json") {
        refused_quickly(
            &[
                "render",
                "--in",
                s(&run.join("point_cloud.ply")),
                "--path",
                s(&f),
                "--out",
                s(&d.join("frames")),
            ],
            &f,
        );
    }
    for f in specials("weights.bin") {
        refused_quickly(
            &[
                "restore",
                "--weights",
                s(&f),
                "--psf",
                s(&psf),
                "--in",
                s(&photo),
                "--out",
                s(&d.join("restored.png")),
            ],
            &f,
        );
    }
    for f in specials("psf.npy") {
        refused_quickly(
            &[
                "deconvolve",
                "--psf",
                s(&f),
                "--in",
                s(&photo),
                "--out",
                s(&d.join("deconvolved.png")),
            ],
            &f,
        );
    }
    for f in specials("photo.png") {
        refused_quickly(
            &[
                "deconvolve",
                "--psf",
                s(&psf),
                "--in",
                s(&f),
                "--out",
                s(&d.join("deconvolved.png")),
            ],
            &f,
        );
    }
    // A checkpoint replaced by a special file: --resume refuses it.
    let ckpt = run.join("checkpoint.bin");
    for f in specials("checkpoint.bin") {
        std::fs::remove_file(&ckpt).ok();
        std::fs::rename(&f, &ckpt).unwrap();
        refused_quickly(&plain_train(&scene, &run, "20", &["--resume"]), &ckpt);
    }
}
