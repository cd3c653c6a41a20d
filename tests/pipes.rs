//! Standard output that closes or fills: `| head` whose reader has gone, a full device. The
//! commands drop what they cannot print and still do their work: exit 0, no panic, every
//! output file written.

mod common;

use std::process::{Output, Stdio};

use common::cli::{metasplat, procedural, quick_train, s};

/// Makes what standard output goes to.
type Sink = fn() -> Stdio;

/// Runs the binary with standard output and error going to `stdout` (a closed pipe or a full
/// device).
fn run_into(args: &[&str], out: Sink) -> Output {
    metasplat()
        .args(args)
        .stdout(out())
        .stderr(Stdio::piped())
        .output()
        .expect("the binary runs")
}

/// A pipe whose reading end is already closed: every write to it fails (EPIPE).
fn closed_pipe() -> Stdio {
    let (reader, writer) = std::io::pipe().unwrap();
    drop(reader);
    writer.into()
}

fn full_device() -> Option<Stdio> {
    std::fs::OpenOptions::new()
        .write(true)
        .open("/dev/full")
        .ok()
        .map(Stdio::from)
}

fn check(what: &str, out: &Output) {
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!err.contains("panicked"), "{what} panicked:\n{err}");
    assert!(
        out.status.success(),
        "{what} failed ({:?}):\n{err}",
        out.status
    );
}

#[test]
fn commands_finish_their_work_when_their_output_cannot_be_written() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let scene = d.join("scene");
    procedural(&scene, 32, 24, 6);
    let full = full_device();
    if full.is_none() {
        eprintln!("SKIP part: /dev/full is not on this system; the closed pipe is tested alone");
    }
    let mut sinks: Vec<(&str, Sink)> = vec![("a closed pipe", closed_pipe)];
    if full.is_some() {
        sinks.push(("a full device", || full_device().unwrap()));
    }
    for (sink, out) in &sinks {
        let o = run_into(&["scene", "info", s(&scene)], *out);
        check(&format!("scene info into {sink}"), &o);
        let run = d.join(format!("run {sink}"));
        let o = run_into(&quick_train(&scene, &run, "20", &[]), *out);
        check(&format!("train into {sink}"), &o);
        for f in ["point_cloud.ply", "metrics.json", "config.json"] {
            assert!(run.join(f).is_file(), "train into {sink} left no {f}");
        }
        let frames = d.join(format!("frames {sink}"));
        let o = run_into(
            &[
                "render",
                "--in",
                s(&run.join("point_cloud.ply")),
                "--scene",
                s(&scene),
                "--downsample",
                "1",
                "--out",
                s(&frames),
            ],
            *out,
        );
        check(&format!("render into {sink}"), &o);
        assert!(
            std::fs::read_dir(&frames).is_ok_and(|mut r| r.next().is_some()),
            "render into {sink} wrote no frame"
        );
    }
}

/// A run killed before its first checkpoint leaves its `config.json` (and perhaps the log of
/// its first evaluations): the same command starts it again, and so does `--resume`, which
/// has nothing to continue; a folder with splats kept by `--save-at` is still refused.
#[test]
fn a_run_stopped_before_its_first_checkpoint_starts_again() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let scene = d.join("scene");
    procedural(&scene, 32, 24, 6);
    let run = d.join("run");
    let train = |extra: &[&str]| {
        metasplat()
            .args(quick_train(&scene, &run, "10", extra))
            .output()
            .unwrap()
    };
    let left_early = || {
        let config = std::fs::read(run.join("config.json")).unwrap();
        std::fs::remove_dir_all(&run).unwrap();
        std::fs::create_dir(&run).unwrap();
        std::fs::write(run.join("config.json"), config).unwrap();
        std::fs::write(run.join("train_log.csv"), "step\n").unwrap();
    };
    check("the first run", &train(&[]));
    for extra in [&[][..], &["--resume"][..]] {
        left_early();
        check(
            &format!("train {extra:?} on a run stopped early"),
            &train(extra),
        );
        assert!(run.join("point_cloud.ply").is_file());
    }
    left_early();
    std::fs::write(run.join("point_cloud_5.ply"), b"kept").unwrap();
    let o = train(&[]);
    assert!(
        !o.status.success(),
        "a folder with a --save-at snapshot was replaced"
    );
    assert_eq!(
        std::fs::read(run.join("point_cloud_5.ply")).unwrap(),
        b"kept"
    );
}
