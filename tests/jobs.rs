//! The other commands as library jobs: `restorer train`, `restorer eval`, `restore`, `render`,
//! `export` and `bench restorer` driven through `metasplat::jobs` without the binary, their
//! events and reports read (`bench step` in its own test binary).

mod common;

use clap::Parser;
use metasplat::TrainError;
use metasplat::jobs::restore::{RestoreEvent, Restored};
use metasplat::jobs::restorer_eval::evaluate;
use metasplat::jobs::restorer_train::{RestorerEvent, RestorerTrainRequest, prepare};
use restore::train::Event;
use std::path::Path;

#[derive(Parser)]
struct Args {
    #[command(flatten)]
    a: RestorerTrainRequest,
}

fn request(flags: &[&str]) -> RestorerTrainRequest {
    Args::parse_from(std::iter::once("train").chain(flags.iter().copied())).a
}

/// Two steps of `tiny`, stopped after the first by a zero-minute budget and resumed: the
/// events say how it starts and every validation, the report what it reached; a request
/// that validates on its training photos is refused by `prepare` before anything is
/// written.
#[test]
fn restorer_training_runs_through_the_library_and_reports() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (psf, psf_path, train, val) = common::restorer_inputs(d, 80, 72);
    let out = d.join("w.bin");
    let s = common::cli::s;
    let flags = common::restorer_flags(&train, &val, &psf_path, &out);
    let flags: Vec<&str> = flags.iter().map(String::as_str).collect();
    let run = |extra: &[&str]| {
        let all: Vec<&str> = flags.iter().chain(extra).copied().collect();
        let prepared = prepare(&request(&all), "test").unwrap();
        let mut said = prepared.notes.clone();
        let mut vals = Vec::new();
        let report = prepared
            .run(&mut |e| match e {
                RestorerEvent::Said(line) => said.push(line),
                RestorerEvent::Step(Event::Val { step, psnr, .. }) => vals.push((*step, *psnr)),
                _ => {}
            })
            .unwrap();
        (report, said, vals)
    };
    let (first, said, vals) = run(&["--minutes", "0"]);
    assert!(first.stopped_early() && first.reached == 1, "{first:?}");
    assert!(
        said.iter().any(|l| l.contains("2 training photos")),
        "{said:?}"
    );
    assert_eq!(vals.len(), 1);
    assert!(out.is_file() && first.state.is_file());
    let (second, said, vals) = run(&["--resume"]);
    assert!(!second.stopped_early() && (second.first, second.reached) == (1, 2));
    assert!(said.iter().any(|l| l.contains("resuming")), "{said:?}");
    assert_eq!(vals.iter().map(|v| v.0).collect::<Vec<_>>(), vec![2]);
    assert!(second.val.0.is_finite() && second.val.0 == vals[0].1);
    assert_eq!(second.log.len(), 1);

    let other = d.join("other.bin");
    let mut same = flags.to_vec();
    same[3] = s(&train);
    same[7] = s(&other);
    let err = match prepare(&request(&same), "test") {
        Err(e @ TrainError::Invalid(_)) => e.to_string(),
        Err(e) => panic!("another error: {e}"),
        Ok(_) => panic!("validating on the training photos was accepted"),
    };
    assert!(err.contains("hold the same photos"), "{err}");
    assert!(!other.exists());

    // The weights it wrote, evaluated at PSFs mapped to 15 px: every method scored, the
    // strips written, the photos blurred at the scale asked for.
    let restorer = restore::Restorer::load(&out, &psf).unwrap();
    let strips = d.join("strips");
    let photos = restore::data::load_folder(&val, 1).unwrap();
    let mut seen = 0;
    let report = evaluate(
        &psf,
        &restorer,
        &photos,
        Some(15),
        Some(&strips),
        &mut || seen += 1,
    )
    .unwrap();
    assert_eq!((report.photos, seen), (1, 1));
    assert_eq!(report.mapped_px, (15, 15));
    let rows = report.rows();
    assert_eq!(rows.len(), 5, "{rows:?}");
    assert!(
        rows.iter().all(|r| r.1.is_finite() && r.2 > 0.0),
        "{rows:?}"
    );
    // The best single K is at least the bank's K = 1e-2 filter scored on its own.
    let model = aberration::ImagingModel::new(
        &psf,
        80,
        72,
        aberration::BlurMode::Tiled,
        Some(psf.sensor_for_psf_px(80, 72, 15)),
        aberration::NoiseModel::default(),
    )
    .unwrap();
    let blurred = model.capture(&photos[0].1, 0x5EED_0000).unwrap();
    let (input, _) = aberration::compare(&blurred, &photos[0].1).unwrap();
    assert!((input - rows[0].1).abs() < 1e-9, "{input} {rows:?}");
    let k2 = aberration::deconvolve(&blurred, model.psf(), aberration::Regularizer::Fixed(1e-2))
        .unwrap();
    assert!(aberration::compare(&k2, &photos[0].1).unwrap().0 <= rows[1].1 + 1e-9);
    let strip = image::open(strips.join("p0_abr_base_net_clean.png")).unwrap();
    assert_eq!((strip.width(), strip.height()), (4 * 80, 72));

    // The training photos as a clip's frames, restored with these weights through the
    // library: a frame event each, and a resumed run that finds them all done.
    let restored = d.join("restored");
    let restore_request = |resume: bool| {
        let mut flags = vec![
            "restore",
            "--weights",
            s(&out),
            "--psf",
            s(&psf_path),
            "--in",
            s(&train),
            "--out",
            s(&restored),
        ];
        if resume {
            flags.push("--resume");
        }
        RestoreArgs::parse_from(flags).a
    };
    let mut frames = Vec::new();
    let report = metasplat::jobs::restore::run(&restore_request(false), &mut |e| {
        if let RestoreEvent::Frame { done, total, .. } = e {
            frames.push((done, total));
        }
    })
    .unwrap();
    assert_eq!(frames, vec![(1, 2), (2, 2)]);
    assert_eq!(
        (report.kind, report.frames, report.size),
        (Restored::Frames, 2, (80, 72))
    );
    for name in ["p0.png", "p1.png"] {
        assert!(restored.join(name).is_file(), "{name}");
    }
    let again = metasplat::jobs::restore::run(&restore_request(false), &mut |_| {});
    assert!(matches!(&again, Err(e) if e.to_string().contains("--resume")));
    let resumed = metasplat::jobs::restore::run(&restore_request(true), &mut |_| {}).unwrap();
    assert_eq!(resumed.frames, 0);
}

#[derive(Parser)]
struct RestoreArgs {
    #[command(flatten)]
    a: metasplat::jobs::restore::RestoreRequest,
}

/// A family run records how it draws its PSF scales, and a resume that asks for another draw
/// is refused naming the flag and the run's draw, before anything is trained; the same draw
/// resumes; so is a resume over another `--psf-px-range`. A second run on the same `--out` is
/// refused while the first holds it. Without `--family` the flag is refused by the parser.
#[test]
fn a_family_run_resumes_only_with_its_own_scale_draw() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (_, psf_path, train, val) = common::restorer_inputs(d, 96, 96);
    let out = d.join("f.bin");
    let mut flags = common::restorer_flags(&train, &val, &psf_path, &out);
    flags.extend(["--family", "--lenses", "1"].map(String::from));
    let flags: Vec<&str> = flags.iter().map(String::as_str).collect();
    let req = |extra: &[&str]| request(&[&flags[..], extra].concat());
    let range = ["--psf-px-draw", "linear", "--psf-px-range", "60-90"];
    let held = prepare(&req(&[&range[..], &["--minutes", "0"]].concat()), "test").unwrap();
    // While one run holds `--out`, a second one writing it is refused before any work.
    let busy = match prepare(&req(&["--psf-px-draw", "linear"]), "test") {
        Err(e @ TrainError::Lock(_)) => e.to_string(),
        Err(e) => panic!("another error: {e}"),
        Ok(_) => panic!("two runs were let write {}", out.display()),
    };
    assert!(
        busy.contains("f.bin") && busy.contains("restorer train"),
        "{busy}"
    );
    assert!(!out.exists());
    let first = held.run(&mut |_| {}).unwrap();
    assert!(first.stopped_early() && first.reached == 1, "{first:?}");
    let (header, _) = restore::weights::read(&out).unwrap();
    let drawn = &header.family.as_ref().unwrap().drawn;
    assert_eq!(drawn["psf_px_draw"], "linear", "{drawn}");
    assert_eq!(drawn["psf_px"], serde_json::json!([60, 90]), "{drawn}");
    assert_eq!(header.trained_psf_px, Some([60, 90]));
    let before = std::fs::read(&out).unwrap();
    let err = match prepare(&req(&["--resume"]), "test") {
        Err(e) => e.to_string(),
        Ok(_) => panic!("a resume with another scale draw was accepted"),
    };
    assert!(
        err.contains("--psf-px-draw log") && err.contains("linear") && err.contains("f.bin"),
        "{err}"
    );
    let err = match prepare(&req(&["--resume", "--psf-px-draw", "linear"]), "test") {
        Err(e) => e.to_string(),
        Ok(_) => panic!("a resume over another scale range was accepted"),
    };
    assert!(
        err.contains("--psf-px-range 15-140") && err.contains("60-90 px"),
        "{err}"
    );
    assert_eq!(
        std::fs::read(&out).unwrap(),
        before,
        "a refused resume touched the weights"
    );
    let second = prepare(&req(&[&["--resume"][..], &range[..]].concat()), "test")
        .unwrap()
        .run(&mut |_| {})
        .unwrap();
    assert_eq!((second.first, second.reached), (1, 2));
    // Without --family there is no family to draw over.
    let plain = [
        "--images",
        "x",
        "--val",
        "x",
        "--psf",
        "x",
        "--out",
        "x",
        "--psf-px-draw",
        "linear",
    ];
    assert!(Args::try_parse_from(std::iter::once("train").chain(plain)).is_err());
}

#[derive(Parser)]
struct RenderArgs {
    #[command(flatten)]
    a: metasplat::jobs::render::RenderRequest,
}

/// `render --split test` through the library: the report counts the capture's held-out
/// views, whose renders and ground truth lie side by side under one name each; a request the
/// job must refuse (a frame rate for a folder of frames) writes nothing.
#[test]
fn rendering_runs_through_the_library_and_reports() {
    let c = common::small_capture(4);
    let d = c.dir.path();
    let ply = d.join("scene.ply");
    splat::formats::ply::write_ply(&ply, &splat::synthetic::random_box_scene(3, 500, 1)).unwrap();
    let out = d.join("split");
    let s = common::cli::s;
    let request = |extra: &[&str]| {
        let flags = ["--in", s(&ply), "--scene", s(&c.clean), "--downsample", "1"];
        RenderArgs::parse_from(
            std::iter::once("render")
                .chain(flags)
                .chain(extra.iter().copied()),
        )
        .a
    };
    let prepared =
        metasplat::jobs::render::prepare(&request(&["--out", s(&out), "--split", "test"])).unwrap();
    assert!(!out.exists(), "prepare wrote {}", out.display());
    let report = prepared.run().unwrap();
    let capture = metasplat::settings::open_scene(&c.clean, 1, false).unwrap();
    let test: Vec<&str> = capture
        .split
        .test
        .iter()
        .map(|&i| capture.cameras[i].name.as_str())
        .collect();
    assert_eq!(report.frames, test.len());
    assert_eq!(report.size, (64, 48));
    assert!(
        report.said.iter().any(|l| l.contains("gt/")),
        "{:?}",
        report.said
    );
    for name in test {
        for dir in ["renders", "gt"] {
            assert!(
                out.join(dir).join(format!("{name}.png")).is_file(),
                "{dir}/{name}"
            );
        }
    }
    let again = d.join("again");
    let err = metasplat::jobs::render::prepare(&request(&["--out", s(&again), "--fps", "24"]));
    assert!(matches!(&err, Err(e) if e.to_string().contains("--fps 24")));
    assert!(!again.exists());
}

#[derive(Parser)]
struct ExportArgs {
    #[command(flatten)]
    a: metasplat::jobs::export::ExportRequest,
}

/// `export` through the library: the bands cut as asked and the file read back with them;
/// a degree the scene does not have is refused by `prepare`, with nothing written.
#[test]
fn exporting_runs_through_the_library_and_reports() {
    let dir = tempfile::tempdir().unwrap();
    let ply = dir.path().join("scene.ply");
    let scene = splat::synthetic::random_box_scene(5, 300, 2);
    splat::formats::ply::write_ply(&ply, &scene).unwrap();
    let s = common::cli::s;
    let request = |out: &Path, degree: &str| {
        ExportArgs::parse_from([
            "export",
            "--in",
            s(&ply),
            "--out",
            s(out),
            "--sh-degree",
            degree,
        ])
        .a
    };
    let spz = dir.path().join("out/scene.spz");
    let report = metasplat::jobs::export::prepare(&request(&spz, "1"))
        .unwrap()
        .run()
        .unwrap();
    assert_eq!((report.splats, report.sh_degree), (300, 1));
    assert_eq!(report.bytes, std::fs::metadata(&spz).unwrap().len());
    let back = splat::formats::files::read_splats(&spz).unwrap();
    assert_eq!((back.len(), back.sh_degree), (300, 1));
    let glb = dir.path().join("scene.glb");
    let err = metasplat::jobs::export::prepare(&request(&glb, "3"));
    assert!(matches!(&err, Err(e) if e.to_string().contains("--sh-degree 3")));
    assert!(!glb.exists());
}

#[derive(Parser)]
struct BenchArgs {
    #[command(flatten)]
    a: metasplat::jobs::bench_restorer::RestorerBenchRequest,
}

/// `bench restorer` through the library: bad sizes refused by `prepare`, then a row per case
/// handed over as it is timed and returned, every figure positive and the speed-up the ratio
/// of the two kernels' times.
#[test]
fn the_restorer_benchmark_runs_through_the_library_and_reports() {
    use metasplat::jobs::bench_restorer::prepare;
    let req = |flags: &[&str]| {
        BenchArgs::parse_from(std::iter::once("bench").chain(flags.iter().copied())).a
    };
    let e = prepare(&req(&["--configs", "tiny", "--sides", "100"]))
        .err()
        .expect("refused")
        .to_string();
    assert!(e.contains("--sides") && e.contains("100 px"), "{e}");
    let e = prepare(&req(&["--configs", "tiny", "--crop", "30"]))
        .err()
        .expect("refused")
        .to_string();
    assert!(e.contains("--crop") && e.contains("30 px"), "{e}");
    let prepared = prepare(&req(&[
        "--configs",
        "tiny",
        "--sides",
        "32",
        "--batch",
        "1",
        "--threads",
        "1",
        "--rounds",
        "1",
    ]))
    .unwrap();
    let mut seen = 0;
    let rows = prepared.run(&mut |_| seen += 1).unwrap();
    assert_eq!((rows.len(), seen), (2, 2));
    for r in &rows {
        let reference = r.reference_s.expect("both kernels timed");
        for v in [reference, r.fast_s, r.fast_cpu_s, r.gflops, r.s_per_mp()] {
            assert!(v.is_finite() && v > 0.0, "{r:?}");
        }
    }
    assert!(matches!(
        rows[0].workload,
        restore::speed::Workload::Forward { side: 32 }
    ));
}
