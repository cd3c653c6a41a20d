//! A training run killed with SIGKILL at several points leaves only complete files (and our
//! own temporary files, which the next run in that folder removes); `--resume` finishes it,
//! and the result equals an uninterrupted run bit for bit. `restorer train` stops between
//! the lenses of its bank.

mod common;

use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::time::{Duration, Instant};

use common::cli::{metasplat, ok as run_ok, procedural};

fn s(p: &Path) -> String {
    p.to_str().unwrap().to_string()
}

const ITERS: &str = "240";

fn train_args(scene: &Path, run: &Path, extra: &[&str]) -> Vec<String> {
    let mut a: Vec<String> = [
        "train",
        "--scene",
        &s(scene),
        "--out",
        &s(run),
        "--mode",
        "plain",
        "--downsample",
        "1",
        "--iters",
        ITERS,
        "--checkpoint-every",
        "10",
        "--eval-every",
        "60",
        "--spiral",
        "3",
        "--device",
        "cpu",
    ]
    .iter()
    .map(|x| x.to_string())
    .collect();
    a.extend(extra.iter().map(|x| x.to_string()));
    a
}

/// Every file and folder under `dir`, relative, sorted.
fn listing(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p.clone());
            }
            out.push(p.strip_prefix(dir).unwrap().to_path_buf());
        }
    }
    out.sort();
    out
}

fn is_ours_temporary(p: &Path) -> bool {
    p.components().any(|c| {
        c.as_os_str()
            .to_str()
            .is_some_and(|n| n.starts_with(base::atomic::TEMP_PREFIX))
    })
}

/// What a killed run may leave: complete files under the names a run writes, and our own
/// temporary files and staging folders. Each complete file is read back in full.
fn assert_only_complete_files(run: &Path, when: &str) {
    for rel in listing(run) {
        if is_ours_temporary(&rel) {
            continue;
        }
        let p = run.join(&rel);
        let name = rel.to_str().unwrap();
        match name {
            "checkpoint.bin" => {
                metasplat::train::checkpoint::load(&p)
                    .unwrap_or_else(|e| panic!("{when}: the checkpoint is damaged: {e}"));
            }
            "config.json" | "metrics.json" => {
                let text = std::fs::read_to_string(&p).unwrap();
                serde_json::from_str::<serde_json::Value>(&text)
                    .unwrap_or_else(|e| panic!("{when}: {name} is incomplete: {e}"));
            }
            "point_cloud.ply" => {
                splat::formats::ply::read_ply(&p)
                    .unwrap_or_else(|e| panic!("{when}: {name} is incomplete: {e}"));
            }
            "train_log.csv" | "psnr_vs_time.png" | "test" | "spiral" => {}
            // The killed holder's lock file: the kernel released the lock with the process.
            base::lock::LOCK_FILE => {
                drop(
                    base::FolderLock::folder(run, "test")
                        .unwrap_or_else(|e| panic!("{when}: the lock outlived its holder: {e}")),
                );
            }
            n if n.ends_with(".png") && (n.starts_with("test/") || n.starts_with("spiral/")) => {
                image::open(&p).unwrap_or_else(|e| panic!("{when}: {name} is incomplete: {e}"));
            }
            other => panic!("{when}: unexpected file {other} in the run folder"),
        }
    }
}

/// Spawns a run and kills it with SIGKILL once `ready` holds (or after `limit`); returns
/// whether it was killed before finishing.
fn run_and_kill(
    args: &[String],
    run: &Path,
    ready: &dyn Fn(&Path) -> bool,
    limit: Duration,
) -> bool {
    let mut child = metasplat()
        .args(args)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let start = Instant::now();
    loop {
        if let Some(status) = child.try_wait().unwrap() {
            assert!(status.success(), "the run failed on its own: {status:?}");
            return false;
        }
        if ready(run) || start.elapsed() > limit {
            child.kill().unwrap();
            child.wait().unwrap();
            return true;
        }
        std::thread::sleep(Duration::from_millis(2));
    }
}

/// The step of the checkpoint in `run`, if one is complete there.
fn checkpoint_step(run: &Path) -> Option<u64> {
    metasplat::train::checkpoint::load(&run.join("checkpoint.bin"))
        .ok()
        .map(|s| s.progress.step)
}

/// The files of a finished run that must not depend on interruptions (metrics and the log
/// hold wall-clock times).
fn results(run: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    listing(run)
        .into_iter()
        .filter(|p| {
            let n = p.to_str().unwrap();
            n == "point_cloud.ply" || n.ends_with(".png") && n != "psnr_vs_time.png"
        })
        .map(|p| {
            let bytes = std::fs::read(run.join(&p)).unwrap();
            (p, bytes)
        })
        .collect()
}

#[test]
fn a_killed_run_leaves_complete_files_and_resumes_to_the_same_result() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let scene = d.join("scene");
    procedural(&scene, 32, 24, 5);
    let reference = d.join("reference");
    run_ok(&train_args(&scene, &reference, &[]));
    let expected = results(&reference);
    assert!(expected.iter().any(|(p, _)| p.starts_with("spiral")));
    assert!(expected.iter().any(|(p, _)| p.starts_with("test")));

    let run = d.join("run");
    let mut kills = 0;
    // 1. Killed at once: at most config.json; nothing to resume, so --resume starts again.
    if run_and_kill(
        &train_args(&scene, &run, &[]),
        &run,
        &|_| true,
        Duration::ZERO,
    ) {
        kills += 1;
        if run.exists() {
            assert_only_complete_files(&run, "killed at start");
        }
    }
    // With a checkpoint --resume continues; with config.json alone it starts again.
    let fresh = if checkpoint_step(&run).is_some() || run.join("config.json").exists() {
        vec!["--resume"]
    } else {
        vec![]
    };
    // 2. Killed after its first checkpoint, 3. after a later one, 4. in the last steps, 5.
    // after the final checkpoint, while writing its outputs (PLY, test views, spiral).
    let points: [(&[&str], u64); 4] = [
        (&fresh, 10),
        (&["--resume"], 100),
        (&["--resume"], 230),
        (&["--resume"], 240),
    ];
    for (extra, at) in points {
        let args = train_args(&scene, &run, extra);
        let killed = run_and_kill(
            &args,
            &run,
            &|r| checkpoint_step(r).is_some_and(|s| s >= at),
            Duration::from_secs(20),
        );
        if killed {
            kills += 1;
            assert_only_complete_files(&run, &format!("killed after step {at}"));
        }
    }
    // Leftovers a killed run could leave in any folder it writes to: a temporary file and a
    // staging folder of a process that is gone. The resumed run removes them.
    std::fs::write(run.join(".metasplat-4294967290-abc.tmp"), b"partial").unwrap();
    std::fs::create_dir_all(run.join(".metasplat-4294967290-frames-xyz/spiral")).unwrap();
    let step = checkpoint_step(&run);
    let args = if step.is_some() {
        train_args(&scene, &run, &["--resume"])
    } else {
        train_args(&scene, &run, &["--overwrite"])
    };
    let text = run_ok(&args);
    assert!(
        kills >= 3,
        "only {kills} of 4 kills landed: the run is too fast to interrupt"
    );
    let left: Vec<_> = listing(&run)
        .into_iter()
        .filter(|p| is_ours_temporary(p))
        .collect();
    assert!(
        left.is_empty(),
        "temporary files left after the resumed run: {left:?}"
    );
    assert_only_complete_files(&run, "after resuming");
    let got = results(&run);
    assert_eq!(
        got.iter().map(|(p, _)| p).collect::<Vec<_>>(),
        expected.iter().map(|(p, _)| p).collect::<Vec<_>>()
    );
    for ((p, a), (_, b)) in got.iter().zip(&expected) {
        assert!(
            a == b,
            "{} differs from the uninterrupted run's ({text})",
            p.display()
        );
    }
    eprintln!("{kills} kills, resumed from step {step:?}: bit-identical to the uninterrupted run");
}

/// `render` leaves its staging folder beside `--out` when killed; the next render into that
/// folder removes it.
#[test]
fn a_killed_renders_staging_folder_is_removed_by_the_next_render() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let ply = d.join("model.ply");
    splat::formats::ply::write_ply(&ply, &splat::synthetic::random_box_scene(1, 60, 0)).unwrap();
    let orphan = d.join(".metasplat-4294967290-frames-abcdef");
    std::fs::create_dir_all(&orphan).unwrap();
    std::fs::write(orphan.join("orbit000.png"), b"half a frame").unwrap();
    let stale_tmp = d.join(".metasplat-4294967290-q1w2e3.tmp");
    std::fs::write(&stale_tmp, b"half a file").unwrap();
    // Another process's live temporary file (this test's own id) is left alone.
    let live = d.join(format!("{}live.tmp", base::temp_prefix()));
    std::fs::write(&live, b"being written").unwrap();
    run_ok(
        &[
            "render",
            "--ply",
            &s(&ply),
            "--out",
            &s(&d.join("frames")),
            "--orbit",
            "2",
            "--width",
            "16",
            "--height",
            "12",
            "--device",
            "cpu",
        ]
        .map(String::from),
    );
    assert!(!orphan.exists() && !stale_tmp.exists());
    assert!(live.exists());
    assert!(d.join("frames/orbit001.png").exists());
}

/// Sends SIGINT (Ctrl-C) to `pid`.
fn ctrl_c(pid: u32) {
    let status = std::process::Command::new("kill")
        .args(["-INT", &pid.to_string()])
        .status()
        .unwrap();
    assert!(status.success(), "kill -INT failed");
}

/// Starts `args`, waits until `ready` holds, presses Ctrl-C, and returns the exit status and
/// stderr; None when the command finished before it was ready (too fast to interrupt).
fn interrupt_when(args: &[String], ready: &dyn Fn() -> bool) -> Option<(Option<i32>, String)> {
    let mut child = metasplat()
        .args(args)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let start = Instant::now();
    while !ready() {
        if child.try_wait().unwrap().is_some() {
            return None;
        }
        assert!(start.elapsed() < Duration::from_secs(300), "never ready");
        std::thread::sleep(Duration::from_millis(2));
    }
    ctrl_c(child.id());
    let out = child.wait_with_output().unwrap();
    Some((
        out.status.code(),
        String::from_utf8_lossy(&out.stderr).into(),
    ))
}

/// Our staging entries directly inside `dir`.
fn staging_in(dir: &Path) -> Vec<String> {
    std::fs::read_dir(dir)
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with(base::atomic::TEMP_PREFIX) || n.ends_with(".lock"))
        .collect()
}

#[test]
fn ctrl_c_stops_training_with_a_checkpoint_of_that_step_and_resume_gives_the_same_result() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let scene = d.join("scene");
    procedural(&scene, 32, 24, 5);
    // No periodic checkpoint before the end: the one after Ctrl-C is the interruption's own.
    let args = |run: &Path, extra: &[&str]| {
        let mut a = train_args(&scene, run, extra);
        for (flag, value) in [("--iters", "1500"), ("--checkpoint-every", "100000")] {
            let at = a.iter().position(|x| x == flag).unwrap();
            a[at + 1] = value.into();
        }
        a
    };
    let reference = d.join("reference");
    run_ok(&args(&reference, &[]));
    let run = d.join("run");
    // Ready once it trains: the log of its steps is not written yet, the config is.
    let config = run.join("config.json");
    let Some((code, err)) = interrupt_when(&args(&run, &[]), &|| config.exists()) else {
        panic!("the run finished before it could be interrupted");
    };
    assert_eq!(code, Some(130), "{err}");
    assert!(
        err.contains("interrupted") && err.contains("--resume"),
        "{err}"
    );
    let step = checkpoint_step(&run).expect("no checkpoint after Ctrl-C");
    assert!(step < 1500, "stopped at {step}");
    assert!(err.contains(&format!("step {step}")), "{err}");
    assert_only_complete_files(&run, "after Ctrl-C");
    assert!(staging_in(&run).is_empty(), "{:?}", staging_in(&run));
    run_ok(&args(&run, &["--resume"]));
    assert_eq!(
        results(&run),
        results(&reference),
        "resumed from step {step}"
    );
}

#[test]
fn ctrl_c_during_a_render_or_an_aberration_leaves_nothing_behind() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let scene = d.join("scene");
    procedural(&scene, 160, 120, 40);
    let run = d.join("run");
    let mut train = train_args(&scene, &run, &[]);
    let at = train.iter().position(|x| x == "--iters").unwrap();
    train[at + 1] = "20".into();
    run_ok(&train);
    let out = d.join("out");
    std::fs::create_dir_all(&out).unwrap();
    let frames = out.join("frames");
    let render = [
        "render",
        "--ply",
        &s(&run.join("point_cloud.ply")),
        "--out",
        &s(&frames),
        "--orbit",
        "5000",
        "--width",
        "320",
        "--height",
        "240",
        "--device",
        "cpu",
    ]
    .map(String::from);
    let staged = || !staging_in(&out).is_empty();
    let (code, err) = interrupt_when(&render, &staged).expect("the render was too fast");
    assert_eq!(code, Some(130), "{err}");
    assert!(err.contains("interrupted"), "{err}");
    assert!(!frames.exists(), "frames were kept");
    assert!(staging_in(&out).is_empty(), "{:?}", staging_in(&out));

    let psf = d.join("psf.npy");
    run_ok(&[
        "psf",
        "simulate",
        "--out",
        &s(&psf),
        "--size",
        "41",
        "--grid",
        "3",
    ]);
    let abr = out.join("abr");
    let aberrate = [
        "scene",
        "aberrate",
        "--scene",
        &s(&scene),
        "--psf",
        &s(&psf),
        "--out",
        &s(&abr),
        "--downsample",
        "1",
    ]
    .map(String::from);
    let (code, err) = interrupt_when(&aberrate, &staged).expect("the aberration was too fast");
    assert_eq!(code, Some(130), "{err}");
    assert!(err.contains("interrupted"), "{err}");
    assert!(!abr.exists(), "a partial capture was kept");
    assert!(staging_in(&out).is_empty(), "{:?}", staging_in(&out));
}

/// A video tool that hangs: the first Ctrl-C ends it and the render, and nothing is left (no
/// video, no temporary file, no staging folder, no lock).
#[test]
fn ctrl_c_ends_a_hung_video_tool_and_leaves_nothing_behind() {
    use std::os::unix::fs::PermissionsExt;
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let scene = d.join("scene");
    procedural(&scene, 32, 24, 5);
    let run = d.join("run");
    let mut train = train_args(&scene, &run, &[]);
    let at = train.iter().position(|x| x == "--iters").unwrap();
    train[at + 1] = "20".into();
    run_ok(&train);
    let bin = d.join("bin");
    std::fs::create_dir_all(&bin).unwrap();
    let started = d.join("started");
    let fake = bin.join("ffmpeg");
    std::fs::write(
        &fake,
        format!(
            "#!/bin/sh\n: > '{}'\nexec /bin/sleep 600\n",
            started.display()
        ),
    )
    .unwrap();
    std::fs::set_permissions(&fake, std::fs::Permissions::from_mode(0o755)).unwrap();
    let out = d.join("out");
    std::fs::create_dir_all(&out).unwrap();
    let video = out.join("v.mp4");
    let mut child = metasplat()
        .env("PATH", &bin)
        .args([
            "render",
            "--in",
            &s(&run.join("point_cloud.ply")),
            "--video",
            &s(&video),
            "--orbit",
            "3",
            "--width",
            "32",
            "--height",
            "24",
            "--device",
            "cpu",
        ])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let start = Instant::now();
    while !started.exists() {
        assert!(
            child.try_wait().unwrap().is_none(),
            "the render ended early"
        );
        assert!(
            start.elapsed() < Duration::from_secs(120),
            "the tool never ran"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    ctrl_c(child.id());
    let stopped = Instant::now();
    while child.try_wait().unwrap().is_none() {
        if stopped.elapsed() > Duration::from_secs(30) {
            let _ = child.kill();
            panic!("the first Ctrl-C did not end the render while its video tool hung");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let out_ = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out_.stderr);
    assert_eq!(out_.status.code(), Some(130), "{err}");
    assert!(err.contains("encoded the video"), "{err}");
    assert!(!video.exists(), "a video was left");
    assert!(staging_in(&out).is_empty(), "{:?}", staging_in(&out));
}

/// Ctrl-C while a finished run writes its frames: it says that `--resume` writes them, and
/// the resume does, from the final checkpoint, without training again.
#[test]
fn ctrl_c_during_the_final_frames_says_resume_writes_them() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let scene = d.join("scene");
    procedural(&scene, 32, 24, 5);
    let run = d.join("run");
    let mut args = train_args(&scene, &run, &[]);
    for (flag, value) in [("--iters", "20"), ("--spiral", "3000")] {
        let at = args.iter().position(|x| x == flag).unwrap();
        args[at + 1] = value.into();
    }
    let writing = || run.join("point_cloud.ply").exists() && !staging_in(&run).is_empty();
    let Some((code, err)) = interrupt_when(&args, &writing) else {
        panic!("the run wrote its frames before it could be interrupted");
    };
    assert_eq!(code, Some(130), "{err}");
    assert!(err.contains("--resume writes the run's files"), "{err}");
    let mut resume = args.clone();
    resume.push("--resume".into());
    run_ok(&resume);
    assert!(run.join("spiral").join("spiral2999.png").exists());
}

#[test]
fn ctrl_c_while_i_ac_is_made_keeps_the_views_restored_so_far() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let scene = d.join("scene");
    procedural(&scene, 160, 120, 24);
    // The default lens: the shipped network serves only its grid.
    let psf = d.join("psf.npy");
    run_ok(&["psf", "simulate", "--out", &s(&psf)]);
    let abr = d.join("abr");
    run_ok(&[
        "scene",
        "aberrate",
        "--scene",
        &s(&scene),
        "--psf",
        &s(&psf),
        "--out",
        &s(&abr),
        "--downsample",
        "1",
    ]);
    let weights = Path::new(env!("CARGO_MANIFEST_DIR")).join("restore/weights/tiny.bin");
    let run = d.join("run");
    let mut args = train_args(&abr, &run, &["--restorer", &s(&weights)]);
    let at = args.iter().position(|x| x == "--mode").unwrap();
    args[at + 1] = "restored".into();
    let at = args.iter().position(|x| x == "--iters").unwrap();
    args[at + 1] = "2".into();
    let cache = abr.join(metasplat::train::iac_cache::CACHE_DIR);
    let entries = || {
        std::fs::read_dir(&cache).map_or(0, |d| {
            d.flatten()
                .filter(|e| e.file_name().to_string_lossy().ends_with(".safetensors"))
                .count()
        })
    };
    let (code, err) =
        interrupt_when(&args, &|| entries() >= 2).expect("I_ac was made too fast to interrupt");
    assert_eq!(code, Some(130), "{err}");
    assert!(
        err.contains("I_ac stopped after") && err.contains("--overwrite"),
        "{err}"
    );
    let kept = entries();
    // The training views of 24 (every eighth held out).
    let total = 21;
    assert!((2..total).contains(&kept), "{kept} of {total} cached");
    // The next run makes only the others.
    args.push("--overwrite".into());
    let out = run_ok(&args);
    assert!(
        out.contains(&format!(
            "restored {} of {total} training views; the others came from the cache",
            total - kept
        )),
        "{out}"
    );
    assert_eq!(entries(), total);
}

/// A stop asked for while `restorer train --family` simulates its lens bank (most of a minute
/// per lens) ends the run at the next lens, saying so, with no weights written and `--out`
/// let go. The request is made in this process, which trains nothing else (the other tests
/// here run the binary).
#[test]
fn a_restorer_run_stops_between_the_lenses_of_its_bank() {
    use clap::Parser;
    use metasplat::jobs::restorer_train::{RestorerTrainRequest, prepare};
    #[derive(Parser)]
    struct Args {
        #[command(flatten)]
        a: RestorerTrainRequest,
    }
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (_, psf_path, train, val) = common::restorer_inputs(d, 96, 96);
    let out = d.join("f.bin");
    let mut flags = vec!["train".to_string()];
    flags.extend(common::restorer_flags(&train, &val, &psf_path, &out));
    flags.extend(["--family", "--lenses", "3"].map(String::from));
    let prepared = prepare(&Args::parse_from(&flags).a, "test").unwrap();
    base::interrupt::request();
    let result = prepared.run(&mut |_| {});
    base::interrupt::clear();
    let err = match result {
        Err(e @ metasplat::TrainError::Interrupted(_)) => e.to_string(),
        Err(e) => panic!("another error: {e}"),
        Ok(r) => panic!("the run trained: {r:?}"),
    };
    assert!(
        err.contains("lens family") && err.contains("1 of 3"),
        "{err}"
    );
    assert!(!out.exists() && !restore::train_state::state_path(&out).exists());
    // `--out` is free again.
    drop(prepare(&Args::parse_from(&flags).a, "test").unwrap());
}
