//! End-to-end tests of the `metasplat` binary on small inputs.

mod common;

use std::path::Path;

use common::cli::{SMALL_LENS, fails, ok, procedural, quick_train, s, small_psf};
use common::photos;

/// `scene aberrate` of `clean` through `psf` into `out`, at full resolution.
fn aberrate(clean: &Path, psf: &Path, out: &Path) {
    ok(&[
        "scene",
        "aberrate",
        "--scene",
        s(clean),
        "--psf",
        s(psf),
        "--out",
        s(out),
        "--downsample",
        "1",
    ]);
}

#[test]
fn simulate_show_aberrate_and_deconvolve() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let psf = d.join("psf.npy");
    let mut args = vec!["psf", "simulate", "--out", s(&psf)];
    args.extend_from_slice(SMALL_LENS);
    let text = ok(&args);
    assert!(text.contains("field angles"), "{text}");
    let grid = aberration::PsfGrid::load_npy(&psf).unwrap();
    assert_eq!((grid.grid(), grid.size()), (3, 21));

    let pic = d.join("psf.png");
    ok(&["psf", "show", s(&psf), "--out", s(&pic)]);
    let img = image::open(&pic).unwrap();
    assert!(
        img.width() > 3 * 3 * 21,
        "picture too small: {}",
        img.width()
    );

    // An input photo with alpha, 16-bit, as users may bring.
    let input = d.join("in.png");
    let photo = image::ImageBuffer::from_fn(80, 50, |x, y| {
        image::Rgba([(x * 800) as u16, (y * 1300) as u16, 30000u16, 65535u16])
    });
    image::DynamicImage::ImageRgba16(photo)
        .save(&input)
        .unwrap();

    let clean = aberration::Image::load(&input).unwrap();
    for mode in ["tiled", "blend"] {
        let out = d.join(format!("ab_{mode}.png"));
        let text = ok(&[
            "aberrate",
            "--psf",
            s(&psf),
            "--in",
            s(&input),
            "--out",
            s(&out),
            "--mode",
            mode,
            "--seed",
            "3",
        ]);
        assert!(text.contains("PSNR"), "{text}");
        let blurred = aberration::Image::load(&out).unwrap();
        assert_eq!((blurred.width, blurred.height), (80, 50));
        assert!(
            aberration::psnr(&blurred, &clean).unwrap() < 60.0,
            "the blur changed nothing"
        );
        // Same seed, same bytes.
        let again = d.join(format!("ab_{mode}_again.png"));
        ok(&[
            "aberrate",
            "--psf",
            s(&psf),
            "--in",
            s(&input),
            "--out",
            s(&again),
            "--mode",
            mode,
            "--seed",
            "3",
        ]);
        assert_eq!(std::fs::read(&out).unwrap(), std::fs::read(&again).unwrap());
    }

    let blurred = d.join("ab_tiled.png");
    let single = d.join("wiener.png");
    ok(&[
        "deconvolve",
        "--psf",
        s(&psf),
        "--in",
        s(&blurred),
        "--out",
        s(&single),
        "--k",
        "1e-3",
    ]);
    assert!(single.exists());
    let bank = d.join("bank");
    let median = d.join("median.png");
    ok(&[
        "deconvolve",
        "--psf",
        s(&psf),
        "--in",
        s(&blurred),
        "--out",
        s(&median),
        "--bank",
        s(&bank),
    ]);
    assert_eq!(std::fs::read_dir(&bank).unwrap().count(), 13);
    assert!(median.exists());
}

#[test]
fn bad_inputs_name_the_file_and_leave_no_output() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = d.join("out.png");
    let input = d.join("in.png");
    image::RgbImage::from_pixel(8, 8, image::Rgb([10, 20, 30]))
        .save(&input)
        .unwrap();

    let missing = d.join("nope.npy");
    let err = fails(&[
        "aberrate",
        "--psf",
        s(&missing),
        "--in",
        s(&input),
        "--out",
        s(&out),
    ]);
    assert!(err.contains("nope.npy"), "{err}");

    let bogus = d.join("bogus.npy");
    std::fs::write(&bogus, b"\x93NUMPY garbage").unwrap();
    let err = fails(&[
        "aberrate",
        "--psf",
        s(&bogus),
        "--in",
        s(&input),
        "--out",
        s(&out),
    ]);
    assert!(err.contains("bogus.npy"), "{err}");

    let psf = d.join("psf.npy");
    aberration::PsfGrid::delta(3, 5).save_npy(&psf).unwrap();
    let noimg = d.join("missing.png");
    let err = fails(&[
        "aberrate",
        "--psf",
        s(&psf),
        "--in",
        s(&noimg),
        "--out",
        s(&out),
    ]);
    assert!(err.contains("missing.png"), "{err}");

    let unwritable = d.join("no_dir").join("out.png");
    let err = fails(&[
        "aberrate",
        "--psf",
        s(&psf),
        "--in",
        s(&input),
        "--out",
        s(&unwritable),
    ]);
    assert!(err.contains("out.png"), "{err}");

    assert!(!out.exists(), "a failed run left an output file");
    let names: Vec<_> = std::fs::read_dir(d)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(names.len(), 3, "unexpected files left behind: {names:?}");
}

/// Every file under `dir` has the mode `File::create` gives there (0666 less the umask): no
/// output is private to its owner, whichever writer made it (PLY, npy, PNG, JSON, CSV,
/// checkpoint).
fn assert_ordinary_modes(dir: &Path, kinds_expected: &[&str]) {
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        let mode = |p: &Path| std::fs::metadata(p).unwrap().permissions().mode() & 0o777;
        let probe = dir.join("mode-probe");
        std::fs::File::create(&probe).unwrap();
        let ordinary = mode(&probe);
        std::fs::remove_file(&probe).unwrap();
        let mut kinds = std::collections::BTreeSet::new();
        for p in files_under(dir) {
            assert_eq!(
                mode(&p),
                ordinary,
                "{} has mode {:o}",
                p.display(),
                mode(&p)
            );
            kinds.insert(p.extension().map(|x| x.to_string_lossy().into_owned()));
        }
        for ext in kinds_expected {
            assert!(
                kinds.contains(&Some(ext.to_string())),
                "no .{ext} output checked: {kinds:?}"
            );
        }
    }
}

#[test]
fn quick_demo_trains_plain_and_aware_and_reports_both() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("demo");
    let text = ok(&["demo", "--quick", "--out", s(&out)]);
    for f in [
        "psf.npy",
        "psf.png",
        "plain_vs_aware.png",
        "scene_aberrated/clean/view001.png",
        "run_plain/point_cloud.ply",
        "run_aware/point_cloud.ply",
        "run_aware/metrics.json",
        "run_aware/train_log.csv",
        "run_aware/psnr_vs_time.png",
        "run_aware/test/view000_compare.png",
        "run_aware/spiral/spiral000.png",
    ] {
        assert!(out.join(f).exists(), "demo did not write {f}");
    }
    assert_ordinary_modes(&out, &["ply", "npy", "png", "json", "csv"]);
    let psnr = |row: &str| -> f64 {
        let line = text
            .lines()
            .find(|l| l.starts_with(row))
            .unwrap_or_else(|| panic!("{row}:\n{text}"));
        line[row.len()..]
            .split_whitespace()
            .next()
            .unwrap()
            .parse()
            .unwrap()
    };
    let (input, plain, aware) = (
        psnr("aberrated input"),
        psnr("3DGS plain"),
        psnr("3DGS aware"),
    );
    assert!(
        input.is_finite() && plain.is_finite() && aware.is_finite(),
        "{text}"
    );
    // A second run replaces its own scene folders instead of failing.
    ok(&["demo", "--quick", "--out", s(&out), "--iters", "20"]);
}

#[test]
fn scene_info_reads_fern() {
    let fern = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/llff/fern");
    if !fern.exists() {
        eprintln!("SKIP: {} not found", fern.display());
        return;
    }
    let text = ok(&["scene", "info", s(&fern)]);
    assert!(text.contains("20") && text.contains("504x378"), "{text}");
}

#[test]
fn scene_aberrate_makes_fern_reproducibly() {
    let fern = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/llff/fern");
    if !fern.exists() {
        eprintln!("SKIP: {} not found", fern.display());
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let psf = d.join("psf.npy");
    small_psf(&psf);
    let (a, b) = (d.join("a"), d.join("b"));
    for out in [&a, &b] {
        let text = ok(&[
            "scene",
            "aberrate",
            "--scene",
            s(&fern),
            "--psf",
            s(&psf),
            "--out",
            s(out),
            "--seed",
            "3",
        ]);
        assert!(text.contains("20 images 504x378"), "{text}");
    }
    for rel in [
        "images_8/image007.png",
        "clean/image007.png",
        "poses_bounds.npy",
        "psf.npy",
    ] {
        let (x, y) = (
            std::fs::read(a.join(rel)).unwrap(),
            std::fs::read(b.join(rel)).unwrap(),
        );
        assert!(x == y, "{rel} differs between two runs with one seed");
    }
    let info = ok(&["scene", "info", s(&a)]);
    assert!(
        info.contains("10091 from"),
        "points3D must come along:\n{info}"
    );
    let err = fails(&[
        "scene",
        "aberrate",
        "--scene",
        s(&fern),
        "--psf",
        s(&psf),
        "--out",
        s(&a),
    ]);
    assert!(err.contains("already exists"), "{err}");
}

#[test]
fn train_then_render_and_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (clean, abr, psf) = (d.join("clean"), d.join("abr"), d.join("psf.npy"));
    small_psf(&psf);
    procedural(&clean, 48, 32, 9);
    aberrate(&clean, &psf, &abr);
    let run = d.join("run");
    let text = ok(&[
        "train",
        "--scene",
        s(&abr),
        "--out",
        s(&run),
        "--mode",
        "restored",
        "--iters",
        "40",
        "--downsample",
        "1",
        "--spiral",
        "3",
    ]);
    assert!(
        text.contains("Wiener image, K = 1e-2") && text.contains("mean"),
        "{text}"
    );
    let metrics = std::fs::read_to_string(run.join("metrics.json")).unwrap();
    assert!(
        metrics.contains("\"mean_psnr\"") && metrics.contains("stand-in"),
        "{metrics}"
    );
    let log = std::fs::read_to_string(run.join("train_log.csv")).unwrap();
    assert!(
        log.lines().count() >= 2 && log.starts_with("step,seconds"),
        "{log}"
    );
    assert_ordinary_modes(&run, &["ply", "png", "json", "csv", "bin"]);
    assert_ordinary_modes(&abr, &["npy", "png", "json", "safetensors"]);

    // I_ac was computed once and cached beside the capture; a run into another folder reads
    // it and trains identically, and so does a rerun over the first.
    let cache = abr.join(metasplat::train::iac_cache::CACHE_DIR);
    assert!(
        text.contains(&format!(
            "I_ac: restored all 7 training views and cached them in {}",
            cache.display()
        )),
        "{text}"
    );
    assert_eq!(std::fs::read_dir(&cache).unwrap().count(), 7);
    assert!(!run.join(metasplat::train::iac_cache::CACHE_DIR).exists());
    let first = std::fs::read(run.join("point_cloud.ply")).unwrap();
    for (out, extra) in [(d.join("second"), None), (run.clone(), Some("--overwrite"))] {
        let mut args = vec![
            "train",
            "--scene",
            s(&abr),
            "--out",
            s(&out),
            "--mode",
            "restored",
            "--iters",
            "40",
            "--downsample",
            "1",
            "--spiral",
            "3",
        ];
        args.extend(extra);
        let again = ok(&args);
        assert!(
            again.contains("I_ac: read all 7 training views from the cache"),
            "{again}"
        );
        assert_eq!(std::fs::read(out.join("point_cloud.ply")).unwrap(), first);
    }
    std::fs::remove_dir_all(d.join("second")).unwrap();

    let frames = d.join("frames");
    let text = ok(&[
        "render",
        "--ply",
        s(&run.join("point_cloud.ply")),
        "--scene",
        s(&abr),
        "--out",
        s(&frames),
        "--downsample",
        "1",
    ]);
    assert!(text.contains("to 9 images 48x32"), "{text}");
    assert!(frames.join("view004.png").exists());
    // The held-out views as INRIA's render.py lays them out, beside their clean images.
    let split = d.join("split");
    let text = ok(&[
        "render",
        "--ply",
        s(&run.join("point_cloud.ply")),
        "--scene",
        s(&abr),
        "--out",
        s(&split),
        "--downsample",
        "1",
        "--split",
        "test",
    ]);
    assert!(text.contains("the clean images"), "{text}");
    let names = |dir: &std::path::Path| {
        let mut n: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        n.sort();
        n
    };
    assert_eq!(
        names(&split.join("renders")),
        ["view000.png", "view008.png"]
    );
    assert_eq!(names(&split.join("gt")), names(&split.join("renders")));
    for n in names(&split.join("gt")) {
        let gt = image::open(split.join("gt").join(&n)).unwrap().to_rgb8();
        let clean = image::open(abr.join("clean").join(&n)).unwrap().to_rgb8();
        assert_eq!(gt, clean, "{n}");
    }

    // Aware on a clean capture without a PSF; an unwritable run folder; a foreign PSF grid.
    let err = fails(&[
        "train",
        "--scene",
        s(&clean),
        "--out",
        s(&d.join("r2")),
        "--downsample",
        "1",
    ]);
    assert!(err.contains("needs the PSF grid"), "{err}");
    let blocker = d.join("file");
    std::fs::write(&blocker, b"x").unwrap();
    let err = fails(&[
        "train",
        "--scene",
        s(&abr),
        "--out",
        s(&blocker.join("run")),
        "--downsample",
        "1",
    ]);
    assert!(err.contains("cannot use") && err.contains("file"), "{err}");
    let other = d.join("other.npy");
    let mut args = vec![
        "psf",
        "simulate",
        "--out",
        s(&other),
        "--grid",
        "3",
        "--size",
        "15",
    ];
    args.extend_from_slice(&SMALL_LENS[4..]);
    ok(&args);
    let err = fails(&[
        "train",
        "--scene",
        s(&abr),
        "--out",
        s(&d.join("r3")),
        "--downsample",
        "1",
        "--psf",
        s(&other),
    ]);
    assert!(err.contains("not the one"), "{err}");
}

#[test]
fn restorer_trains_restores_evaluates_and_feeds_splat_training() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let psf = d.join("psf.npy");
    small_psf(&psf);
    let imgs = d.join("photos");
    photos(&imgs, 3, 96, 80);
    let val = d.join("photos_val");
    photos(&val, 2, 96, 80);
    let weights = d.join("w.bin");
    let train_args = [
        "restorer",
        "train",
        "--images",
        s(&imgs),
        "--val",
        s(&val),
        "--psf",
        s(&psf),
        "--config",
        "tiny",
        "--out",
        s(&weights),
        "--steps",
        "3",
        "--batch",
        "1",
        "--val-every",
        "1",
        "--val-crop",
        "64",
    ];
    // A zero-minute budget stops after one step with a checkpoint; --resume finishes the run.
    let mut args = train_args.to_vec();
    args.extend(["--minutes", "0"]);
    let text = ok(&args);
    assert!(
        text.contains("trained to step 1 of 3")
            && text.contains("validation (centred 64 px crops)")
            && text.contains("stopped early"),
        "{text}"
    );
    // Validation on whole photos (`--val-crop 0`) says so, not "0 px crops".
    let whole_weights = d.join("w_whole.bin");
    let mut whole = train_args.to_vec();
    let at = whole.iter().position(|a| *a == "--val-crop").unwrap();
    whole[at + 1] = "0";
    let at = whole.iter().position(|a| *a == "--out").unwrap();
    whole[at + 1] = s(&whole_weights);
    let at = whole.iter().position(|a| *a == "--steps").unwrap();
    whole[at + 1] = "1";
    let text = ok(&whole);
    assert!(text.contains("validation (whole photos)"), "{text}");
    // A resume whose flags say otherwise than the saved run is refused, naming the flag,
    // rather than run with the saved settings in silence.
    let mut other = train_args.to_vec();
    let at = other.iter().position(|a| *a == "--batch").unwrap();
    other[at + 1] = "2";
    other.push("--resume");
    let err = fails(&other);
    assert!(err.contains("--batch 2 (the run has 1)"), "{err}");
    // So is another loss.
    let mut other = train_args.to_vec();
    other.extend(["--loss", "l2", "--resume"]);
    let err = fails(&other);
    assert!(err.contains("--loss l2 (the run has l1)"), "{err}");
    // So is another training crop (the config's field, not the schedule's).
    let mut other = train_args.to_vec();
    other.extend(["--crop", "32", "--resume"]);
    let err = fails(&other);
    assert!(err.contains("--crop 32 (the run has 64)"), "{err}");
    // A crop the config's levels cannot divide is refused before any photo is read.
    let mut other = train_args.to_vec();
    other.extend(["--crop", "40"]);
    let err = fails(&other);
    assert!(
        err.contains("--crop 40") && err.contains("multiple of"),
        "{err}"
    );
    let mut args = train_args.to_vec();
    args.push("--resume");
    let text = ok(&args);
    assert!(
        text.contains("at step 1 of 3")
            && text.contains("trained to step 3 of 3 (2 steps in this run)")
            && text.matches("val PSNR").count() == 2,
        "{text}"
    );
    let err = fails(&args);
    assert!(err.contains("that run finished"), "{err}");
    assert!(weights.exists());

    // Restore one aberrated photo, with a reference to compare against.
    let (abr, out) = (d.join("abr.png"), d.join("restored.png"));
    ok(&[
        "aberrate",
        "--psf",
        s(&psf),
        "--in",
        s(&imgs.join("p0.png")),
        "--out",
        s(&abr),
    ]);
    let restore = |out: &Path, more: &[&str]| {
        let mut args = vec![
            "restore",
            "--psf",
            s(&psf),
            "--weights",
            s(&weights),
            "--in",
            s(&abr),
            "--out",
            s(out),
        ];
        args.extend(more);
        ok(&args)
    };
    let text = restore(&out, &["--reference", s(&imgs.join("p0.png"))]);
    assert!(
        text.contains("restored 96x80") && text.contains("PSNR"),
        "{text}"
    );
    assert_eq!(image::image_dimensions(&out).unwrap(), (96, 80));
    // The same with a two-member self-ensemble: said, and another image than one pass.
    let out2 = d.join("restored2.png");
    let text = restore(&out2, &["--ensemble", "2"]);
    assert!(text.contains("with 'tiny, 2-member ensemble'"), "{text}");
    assert_ne!(std::fs::read(&out).unwrap(), std::fs::read(&out2).unwrap());

    let text = ok(&[
        "restorer",
        "eval",
        "--weights",
        s(&weights),
        "--psf",
        s(&psf),
        "--val",
        s(&imgs),
    ]);
    for row in [
        "aberrated input",
        "best single K",
        "median MAFG",
        "network (tiny)",
        "PSNR on Y",
        "the grid's own sensor",
    ] {
        assert!(text.contains(row), "{row}: {text}");
    }
    // At a chosen blur scale: every photo's PSFs mapped to that many pixels.
    let text = ok(&[
        "restorer",
        "eval",
        "--weights",
        s(&weights),
        "--psf",
        s(&psf),
        "--val",
        s(&imgs),
        "--psf-px",
        "9",
        "--ensemble",
        "2",
    ]);
    for said in [
        "PSFs of 9 px at the photos' size (--psf-px 9)",
        "network (tiny, 2-member ensemble)",
        "2 passes a photo",
    ] {
        assert!(text.contains(said), "{said}: {text}");
    }

    // Weights made for one grid are refused for another, naming the weights file.
    let other = d.join("other.npy");
    let mut args = vec!["psf", "simulate", "--out", s(&other)];
    args.extend(
        SMALL_LENS
            .iter()
            .map(|a| if *a == "10" { "12" } else { *a }),
    );
    ok(&args);
    let err = fails(&[
        "restore",
        "--psf",
        s(&other),
        "--weights",
        s(&weights),
        "--in",
        s(&abr),
        "--out",
        s(&d.join("x.png")),
    ]);
    assert!(
        err.contains("w.bin") && err.contains("trained for one 3x3 grid"),
        "{err}"
    );
    assert!(!d.join("x.png").exists());
    // --any-grid restores through it all the same, to measure the weights there.
    ok(&[
        "restore",
        "--psf",
        s(&other),
        "--weights",
        s(&weights),
        "--any-grid",
        "--in",
        s(&abr),
        "--out",
        s(&d.join("x.png")),
    ]);
    assert_eq!(image::image_dimensions(d.join("x.png")).unwrap(), (96, 80));
    // Fine-tuning to a user's own lens: --init takes weights made for another grid, and the
    // weights it writes serve that grid.
    // `source`: the training and validation flags, and any more.
    let fine_tune = |out: &Path, source: &[&str]| {
        let mut args = vec!["restorer", "train"];
        args.extend_from_slice(source);
        args.extend_from_slice(&[
            "--psf",
            s(&other),
            "--config",
            "tiny",
            "--out",
            s(out),
            "--steps",
            "1",
            "--batch",
            "1",
            "--val-crop",
            "64",
            "--init",
            s(&weights),
        ]);
        ok(&args)
    };
    let photos = ["--images", s(&imgs), "--val", s(&val)];
    let tuned = d.join("tuned.bin");
    let text = fine_tune(&tuned, &photos);
    assert!(
        text.contains("Fine-tuning")
            && text.contains("w.bin")
            && text.contains("trained to step 1"),
        "{text}"
    );
    // Under another residual base and a fixed K: the same parameters load into the moved
    // network, saying so (restoring under them would be refused).
    let rebased = [&photos[..], &["--residual-base", "2", "--fixed-k"]].concat();
    let text = fine_tune(&d.join("rebased.bin"), &rebased);
    assert!(
        text.contains("residual base differs") && text.contains("trained to step 1"),
        "{text}"
    );
    // Fine-tuned networks average into one (here a network with itself: the mean is that
    // network); one under another bank K is refused naming it, nothing written.
    let soup = d.join("soup.bin");
    let err = fails(&[
        "restorer",
        "average",
        s(&tuned),
        s(&d.join("rebased.bin")),
        "--out",
        s(&soup),
    ]);
    assert!(
        err.contains("rebased.bin") && err.contains("config"),
        "{err}"
    );
    assert!(!soup.exists());
    let text = ok(&[
        "restorer",
        "average",
        s(&tuned),
        s(&tuned),
        "--out",
        s(&soup),
    ]);
    assert!(text.contains("the mean of 2 networks"), "{text}");
    ok(&[
        "restore",
        "--psf",
        s(&other),
        "--weights",
        s(&tuned),
        "--in",
        s(&abr),
        "--out",
        s(&d.join("y.png")),
    ]);
    // Or on captured pairs (here made through the other grid), validated on pairs too.
    let (pairs, val_pairs) = (d.join("pairs"), d.join("val_pairs"));
    for (dir, from) in [(&pairs, &imgs), (&val_pairs, &val)] {
        for sub in ["captured", "clean"] {
            std::fs::create_dir_all(dir.join(sub)).unwrap();
        }
        for name in ["p0.png", "p1.png"] {
            std::fs::copy(from.join(name), dir.join("clean").join(name)).unwrap();
            ok(&[
                "aberrate",
                "--psf",
                s(&other),
                "--in",
                s(&from.join(name)),
                "--out",
                s(&dir.join("captured").join(name)),
            ]);
        }
    }
    let paired = d.join("paired.bin");
    let text = fine_tune(&paired, &["--pairs", s(&pairs), "--val", s(&val_pairs)]);
    assert!(
        text.contains("2 captured pairs; 2 validation pairs") && text.contains("trained to step 1"),
        "{text}"
    );
    // A pairs folder without its two folders is refused naming it, before anything is written.
    let err = fails(&[
        "restorer",
        "train",
        "--pairs",
        s(&imgs),
        "--val",
        s(&val),
        "--psf",
        s(&other),
        "--out",
        s(&d.join("never.bin")),
    ]);
    assert!(err.contains("--pairs") && err.contains("captured"), "{err}");
    assert!(!d.join("never.bin").exists());

    // The restorer supplies I_ac to splat training.
    let (clean, capture) = (d.join("clean"), d.join("capture"));
    procedural(&clean, 48, 32, 9);
    aberrate(&clean, &psf, &capture);
    let run = d.join("run");
    let text = ok(&[
        "train",
        "--scene",
        s(&capture),
        "--out",
        s(&run),
        "--mode",
        "restored",
        "--iters",
        "20",
        "--downsample",
        "1",
        "--spiral",
        "2",
        "--restorer",
        s(&weights),
    ]);
    assert!(text.contains("MAFG + STAF restorer"), "{text}");
    let metrics = std::fs::read_to_string(run.join("metrics.json")).unwrap();
    assert!(
        metrics.contains("MAFG + STAF restorer") && metrics.contains("w.bin"),
        "{metrics}"
    );
    // Resuming must not silently change where I_ac comes from.
    let err = fails(&[
        "train",
        "--scene",
        s(&capture),
        "--out",
        s(&run),
        "--mode",
        "restored",
        "--iters",
        "20",
        "--downsample",
        "1",
        "--spiral",
        "2",
        "--restorer",
        "wiener",
        "--resume",
    ]);
    assert!(
        err.contains("cannot resume") && err.contains("i_ac") && err.contains("Wiener K=1e-2"),
        "{err}"
    );
    let err = fails(&[
        "train",
        "--scene",
        s(&capture),
        "--out",
        s(&d.join("run2")),
        "--mode",
        "aware",
        "--iters",
        "5",
        "--downsample",
        "1",
        "--restorer",
        s(&d.join("missing.bin")),
    ]);
    assert!(err.contains("missing.bin"), "{err}");
}

/// Every file under `dir`, recursively.
fn files_under(dir: &Path) -> Vec<std::path::PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                out.push(p);
            }
        }
    }
    out
}

/// Every file under `dir` with its bytes, to prove inputs survive a command.
fn snapshot(dir: &Path) -> Vec<(std::path::PathBuf, Vec<u8>)> {
    let mut out: Vec<_> = files_under(dir)
        .into_iter()
        .map(|p| {
            let bytes = std::fs::read(&p).unwrap();
            (p, bytes)
        })
        .collect();
    out.sort();
    out
}

#[test]
fn outputs_that_alias_inputs_are_refused_and_inputs_survive() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let psf = d.join("psf.npy");
    small_psf(&psf);
    let scene = d.join("scene");
    procedural(&scene, 32, 24, 5);
    let photo = scene.join("images/view000.png");
    let ply = d.join("model.ply");
    splat::formats::ply::write_ply(&ply, &splat::synthetic::random_box_scene(1, 50, 0)).unwrap();
    let weights = Path::new(env!("CARGO_MANIFEST_DIR")).join("restore/weights/tiny.bin");
    let before = snapshot(d);
    let images = scene.join("images");
    let out_png = d.join("fresh.png");
    let cases: Vec<Vec<&str>> = vec![
        vec!["psf", "show", s(&psf), "--out", s(&psf)],
        vec![
            "aberrate",
            "--psf",
            s(&psf),
            "--in",
            s(&photo),
            "--out",
            s(&photo),
        ],
        vec![
            "aberrate",
            "--psf",
            s(&psf),
            "--in",
            s(&photo),
            "--out",
            s(&psf),
        ],
        vec![
            "deconvolve",
            "--psf",
            s(&psf),
            "--in",
            s(&photo),
            "--out",
            s(&photo),
        ],
        vec![
            "deconvolve",
            "--psf",
            s(&psf),
            "--in",
            s(&photo),
            "--out",
            s(&out_png),
            "--bank",
            s(&psf),
        ],
        vec![
            "restore",
            "--psf",
            s(&psf),
            "--weights",
            weights.to_str().unwrap(),
            "--in",
            s(&photo),
            "--out",
            s(&photo),
        ],
        vec![
            "render",
            "--ply",
            s(&ply),
            "--scene",
            s(&scene),
            "--out",
            s(&images),
            "--downsample",
            "1",
        ],
        vec![
            "render",
            "--ply",
            s(&ply),
            "--scene",
            s(&scene),
            "--out",
            s(&scene),
            "--downsample",
            "1",
        ],
        vec!["export", "--in", s(&ply), "--out", s(&ply)],
        vec![
            "scene",
            "aberrate",
            "--scene",
            s(&scene),
            "--psf",
            s(&psf),
            "--out",
            s(&scene),
            "--downsample",
            "1",
        ],
        vec![
            "train",
            "--scene",
            s(&scene),
            "--out",
            s(&scene),
            "--downsample",
            "1",
            "--iters",
            "5",
        ],
        vec![
            "train",
            "--scene",
            s(&scene),
            "--out",
            s(&images),
            "--downsample",
            "1",
            "--iters",
            "5",
        ],
        vec![
            "experiment",
            "llff",
            "--scene",
            s(&scene),
            "--out",
            s(&scene),
            "--iters",
            "5",
        ],
    ];
    for case in &cases {
        let err = fails(case);
        assert!(
            err.contains("--out") || err.contains("--bank"),
            "metasplat {case:?} does not name the flag:\n{err}"
        );
        assert!(err.contains("refusing"), "metasplat {case:?}:\n{err}");
    }
    assert!(snapshot(d) == before, "an input changed");
    eprintln!(
        "{} aliasing outputs refused, every input unchanged",
        cases.len()
    );
}

#[test]
fn a_run_folder_is_continued_or_replaced_never_mixed() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let scene = d.join("scene");
    procedural(&scene, 32, 24, 5);
    let run = d.join("run");
    let train = |extra: &[&str]| -> Vec<String> {
        let mut a: Vec<String> = [
            "train",
            "--scene",
            s(&scene),
            "--out",
            s(&run),
            "--mode",
            "plain",
            "--downsample",
            "1",
            "--iters",
            "10",
            "--spiral",
            "2",
        ]
        .iter()
        .map(|x| x.to_string())
        .collect();
        a.extend(extra.iter().map(|x| x.to_string()));
        a
    };
    fn as_str(v: &[String]) -> Vec<&str> {
        v.iter().map(String::as_str).collect()
    }
    // --resume with nothing to resume says so and makes no folder.
    let err = fails(&as_str(&train(&["--resume"])));
    assert!(
        err.contains("--resume") && err.contains("checkpoint"),
        "{err}"
    );
    assert!(!run.exists(), "a refused run left its folder");
    ok(&as_str(&train(&[])));
    let first = std::fs::read(run.join("point_cloud.ply")).unwrap();
    // A second fresh run into the same folder is refused and changes nothing.
    let err = fails(&as_str(&train(&[])));
    assert!(
        err.contains("--overwrite") && err.contains("--resume"),
        "{err}"
    );
    assert_eq!(std::fs::read(run.join("point_cloud.ply")).unwrap(), first);
    // --save-at keeps the splats along the way; a step past the run's end is refused.
    let err = fails(&as_str(&train(&["--overwrite", "--save-at", "3,11"])));
    assert!(
        err.contains("--save-at 11") && err.contains("10 steps"),
        "{err}"
    );
    let text = ok(&as_str(&train(&["--overwrite", "--save-at", "7,3"])));
    assert!(text.contains("Step 3: kept the splats"), "{text}");
    // Away from a terminal each evaluation is a line of the log.
    assert!(
        text.contains("Step 10 of 10: loss")
            && text.contains("held-out")
            && text.contains("steps/s"),
        "{text}"
    );
    let early = splat::formats::files::read_splats(run.join("point_cloud_3.ply")).unwrap();
    let later = splat::formats::files::read_splats(run.join("point_cloud_7.ply")).unwrap();
    assert_ne!(early.means, later.means, "the snapshots are the same model");
    // --overwrite replaces the run: no stale spiral frames or snapshots survive.
    std::fs::write(run.join("spiral/stale.png"), b"old").unwrap();
    ok(&as_str(&train(&["--overwrite"])));
    assert!(!run.join("spiral/stale.png").exists());
    assert!(!run.join("point_cloud_3.ply").exists());
    assert!(run.join("point_cloud.ply").exists());
    // Another run starts from this one's splats, in any splat format.
    let glb = d.join("start.glb");
    ok(&[
        "export",
        "--in",
        s(&run.join("point_cloud.ply")),
        "--out",
        s(&glb),
    ]);
    let from = d.join("run_from");
    let text = ok(&[
        "train",
        "--scene",
        s(&scene),
        "--out",
        s(&from),
        "--mode",
        "plain",
        "--downsample",
        "1",
        "--iters",
        "5",
        "--spiral",
        "0",
        "--init",
        s(&glb),
    ]);
    assert!(
        text.contains("Starting from the") && text.contains("start.glb"),
        "{text}"
    );
    let config = std::fs::read_to_string(from.join("config.json")).unwrap();
    assert!(config.contains("start.glb"), "{config}");
    // A checkpoint exports as the model training left at its step.
    let from_ckpt = d.join("from_checkpoint.ply");
    let text = ok(&[
        "export",
        "--in",
        s(&run.join("checkpoint.bin")),
        "--out",
        s(&from_ckpt),
    ]);
    assert!(text.contains("checkpoint at step"), "{text}");
    let state = metasplat::train::checkpoint::load(&run.join("checkpoint.bin")).unwrap();
    let exported = splat::formats::files::read_splats(&from_ckpt).unwrap();
    assert_eq!(exported.len(), state.model.len());
    assert_eq!(exported.means, state.model.means);
    let err = fails(&[
        "train",
        "--scene",
        s(&scene),
        "--out",
        s(&d.join("run_x")),
        "--mode",
        "plain",
        "--downsample",
        "1",
        "--init",
        s(&d.join("nothing.ply")),
    ]);
    assert!(
        err.contains("--init") && err.contains("nothing.ply"),
        "{err}"
    );
    assert!(!d.join("run_x").exists());
    // A bad capture leaves no run folder behind.
    let other = d.join("run_bad");
    let err = fails(&[
        "train",
        "--scene",
        s(&d.join("missing")),
        "--out",
        s(&other),
        "--downsample",
        "1",
    ]);
    assert!(err.contains("missing"), "{err}");
    assert!(!other.exists(), "a refused run left its folder");
}

#[test]
fn nonsense_numbers_are_refused_naming_the_flag() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = d.join("out");
    let o = s(&out);
    // Each command with the arguments it needs before the flag under test, then the flags
    // and a value each must refuse.
    let train = ["train", "--scene", "x", "--out", o];
    let restorer = [
        "restorer", "train", "--images", "x", "--val", "x", "--psf", "x", "--out", o,
    ];
    let render = ["render", "--ply", "x.ply", "--scene", "x", "--out", o];
    let psf = ["psf", "simulate", "--out", o];
    type Group<'a> = (&'a [&'a str], &'a [(&'a str, &'a str)]);
    let groups: [Group; 10] = [
        (
            &train,
            &[
                ("--lambda", "-1"),
                ("--lambda", "NaN"),
                ("--lambda-fade", "900:300"),
                ("--lambda-fade", "soon"),
                ("--max-splats", "0"),
                ("--downsample", "0"),
                ("--max-sh-degree", "9"),
                ("--iters", "0"),
                ("--llffhold", "1"),
                ("--spiral", "4294967296"),
            ],
        ),
        (&render, &[("--spiral", "0")]),
        (
            &restorer,
            &[
                ("--lr", "NaN"),
                ("--batch", "0"),
                ("--steps", "0"),
                ("--loss", "l3"),
            ],
        ),
        (
            &psf,
            &[
                ("--fft-size", "100000"),
                ("--grid", "100000"),
                ("--supersample", "0"),
                ("--aperture-um", "-5"),
                ("--max-field-deg", "inf"),
            ],
        ),
        (
            &["scene", "procedural", "--out", o],
            &[("--width", "100000"), ("--views", "0")],
        ),
        (
            &["aberrate", "--psf", "x", "--in", "x", "--out", o],
            &[("--sensor-px", "1")],
        ),
        (
            &["deconvolve", "--psf", "x", "--in", "x", "--out", o],
            &[("--k", "0")],
        ),
        (
            &["restore", "--psf", "x", "--in", "x", "--out", o],
            &[("--ensemble", "3"), ("--ensemble", "0")],
        ),
        (
            &["restorer", "eval", "--psf", "x", "--val", "x"],
            &[("--ensemble", "16")],
        ),
        (
            &["export", "--in", "x.ply", "--out", o],
            &[("--sh-degree", "4")],
        ),
    ];
    let cases: Vec<(&str, Vec<&str>)> = groups
        .iter()
        .flat_map(|(command, flags)| {
            flags.iter().map(|&(flag, value)| {
                let mut args = command.to_vec();
                args.extend([flag, value]);
                (flag, args)
            })
        })
        .collect();
    for (flag, case) in &cases {
        let err = fails(case);
        assert!(
            err.contains(flag),
            "metasplat {case:?} does not name {flag}:\n{err}"
        );
        assert!(!out.exists(), "metasplat {case:?} left {o}");
    }
    eprintln!("{} nonsense flag values refused", cases.len());
}

#[test]
fn render_without_a_capture_frames_the_splats() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let ply = d.join("model.glb");
    splat::formats::glb::write_glb(&ply, &splat::synthetic::random_box_scene(2, 2000, 1)).unwrap();
    let out = d.join("orbit");
    let text = ok(&[
        "render",
        "--ply",
        s(&ply),
        "--out",
        s(&out),
        "--orbit",
        "3",
        "--width",
        "64",
        "--height",
        "48",
        "--device",
        "cpu",
    ]);
    assert!(text.contains("3 images 64x48"), "{text}");
    for k in 0..3 {
        let img = image::open(out.join(format!("orbit{k:03}.png")))
            .unwrap()
            .to_rgb8();
        let lit = img.pixels().filter(|p| p.0.iter().any(|c| *c > 10)).count();
        // The orbit frames the splats: they cover a good part of the image, not all of it.
        assert!(
            lit > 64 * 48 / 10 && lit < 64 * 48,
            "frame {k}: {lit} lit pixels"
        );
    }
    let one = d.join("one");
    ok(&[
        "render",
        "--ply",
        s(&ply),
        "--out",
        s(&one),
        "--camera",
        "0,0,-1,0,0,1",
        "--width",
        "32",
        "--height",
        "24",
        "--device",
        "cpu",
    ]);
    assert!(one.join("camera.png").exists());
    // The frames were staged beside --out and moved in: no staging folder is left.
    let leftovers: Vec<_> = std::fs::read_dir(d)
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().starts_with(".metasplat"))
        .collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");
    let err = fails(&[
        "render",
        "--ply",
        s(&ply),
        "--out",
        s(&one),
        "--camera",
        "1,2,3",
    ]);
    assert!(err.contains("--camera"), "{err}");
}

/// A Kodak validation photo, or None (with the reason printed) when the shared data is absent.
fn kodak(name: &str) -> Option<std::path::PathBuf> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("../shared/data/images/val/{name}"));
    if p.exists() {
        Some(p)
    } else {
        eprintln!(
            "SKIP: {} is absent (the shared data is not here)",
            p.display()
        );
        None
    }
}

fn png_psnr(a: &Path, b: &Path) -> f64 {
    let (a, b) = (
        aberration::Image::load(a).unwrap(),
        aberration::Image::load(b).unwrap(),
    );
    aberration::psnr(&a, &b).unwrap()
}

#[test]
fn the_defaults_improve_a_photo_at_the_papers_noise() {
    let Some(clean) = kodak("kodim05.png") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // The default PSF grid: the one the shipped restorer was trained for.
    let psf = d.join("psf.npy");
    ok(&["psf", "simulate", "--out", s(&psf)]);
    let blurred = d.join("blurred.png");
    ok(&[
        "aberrate",
        "--psf",
        s(&psf),
        "--in",
        s(&clean),
        "--out",
        s(&blurred),
        "--seed",
        "5",
    ]);
    let input_db = png_psnr(&blurred, &clean);

    // deconvolve with no K: the default constant, named, and better than its input.
    let wiener = d.join("wiener.png");
    let text = ok(&[
        "deconvolve",
        "--psf",
        s(&psf),
        "--in",
        s(&blurred),
        "--out",
        s(&wiener),
    ]);
    assert!(text.contains("(the default)"), "{text}");
    let wiener_db = png_psnr(&wiener, &clean);
    assert!(
        wiener_db > input_db + 1.0,
        "deconvolve's default: {input_db:.2} -> {wiener_db:.2} dB"
    );

    // restore with no --weights: the shipped network, said so, far better than its input.
    let restored = d.join("restored.png");
    let text = ok(&[
        "restore",
        "--psf",
        s(&psf),
        "--in",
        s(&blurred),
        "--out",
        s(&restored),
    ]);
    assert!(text.contains("shipped"), "{text}");
    let restored_db = png_psnr(&restored, &clean);
    assert!(
        restored_db > input_db + 3.0,
        "restore's default: {input_db:.2} -> {restored_db:.2} dB"
    );
    assert!(
        restored_db > wiener_db,
        "the network {restored_db:.2} dB, Wiener {wiener_db:.2} dB"
    );

    // Another PSF grid has no shipped network: the refusal names --weights.
    let other = d.join("other.npy");
    small_psf(&other);
    let err = fails(&[
        "restore",
        "--psf",
        s(&other),
        "--in",
        s(&blurred),
        "--out",
        s(&d.join("x.png")),
    ]);
    assert!(err.contains("--weights"), "{err}");
    assert!(!d.join("x.png").exists());
}

#[test]
fn render_finds_the_image_folder_a_capture_has() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let scene = d.join("scene");
    procedural(&scene, 48, 32, 3);
    assert!(scene.join("images").is_dir() && !scene.join("images_8").exists());
    let ply = d.join("truth.ply");
    splat::formats::ply::write_ply(&ply, &metasplat::splats::procedural::ground_truth(0)).unwrap();
    let frames = d.join("frames");
    let text = ok(&[
        "render",
        "--ply",
        s(&ply),
        "--scene",
        s(&scene),
        "--out",
        s(&frames),
        "--device",
        "cpu",
    ]);
    assert!(text.contains("Using images/"), "{text}");
    assert_eq!(std::fs::read_dir(&frames).unwrap().count(), 3);
}

#[test]
fn the_budget_experiment_writes_its_table_and_plot() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (clean, psf, out) = (d.join("clean"), d.join("psf.npy"), d.join("exp"));
    small_psf(&psf);
    ok(&[
        "scene",
        "procedural",
        "--around",
        "--out",
        s(&clean),
        "--width",
        "40",
        "--height",
        "40",
        "--views",
        "10",
    ]);
    let text = ok(&[
        "experiment",
        "budget",
        "--scene",
        s(&clean),
        "--out",
        s(&out),
        "--psf",
        s(&psf),
        "--downsample",
        "1",
        "--iters",
        "30",
        "--budgets",
        "500,unbounded",
        "--mode",
        "plain",
        "--device",
        "cpu",
    ]);
    let table = std::fs::read_to_string(out.join("budget.md")).unwrap();
    let rows: Vec<&str> = table
        .lines()
        .filter(|l| l.starts_with("| 500") || l.starts_with("| unbounded"))
        .collect();
    assert_eq!(rows.len(), 2, "{table}");
    // The capped run keeps at most its budget; the reference row compares with itself.
    let splats = |row: &str| {
        row.split('|')
            .nth(2)
            .unwrap()
            .trim()
            .parse::<usize>()
            .unwrap()
    };
    assert!(splats(rows[0]) <= 500, "{table}");
    assert!(
        rows[1].contains("+0.00") && rows[1].contains("100 %"),
        "{table}"
    );
    assert!(out.join("budget.png").exists() && out.join("budget_500/point_cloud.ply").exists());
    assert!(
        text.contains("Training plain with a budget of 500 splats."),
        "{text}"
    );
    // A budget that is not one is refused by name.
    let err = fails(&[
        "experiment",
        "budget",
        "--scene",
        s(&clean),
        "--out",
        s(&d.join("x")),
        "--budgets",
        "0",
    ]);
    assert!(err.contains("'0' is not a splat budget"), "{err}");
}

#[test]
fn an_experiment_resumes_where_it_stopped() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (clean, psf, out) = (d.join("clean"), d.join("psf.npy"), d.join("exp"));
    small_psf(&psf);
    procedural(&clean, 40, 32, 8);
    let base = vec![
        "experiment",
        "llff",
        "--scene",
        s(&clean),
        "--out",
        s(&out),
        "--psf",
        s(&psf),
        "--downsample",
        "1",
        "--iters",
        "20",
        "--modes",
        "plain",
        "--device",
        "cpu",
    ];
    let exp = |extra: &[&'static str]| [base.clone(), extra.to_vec()].concat();
    ok(&exp(&[]));
    let run = out.join("run_plain");
    let seconds = |run: &Path| {
        let m: serde_json::Value =
            serde_json::from_slice(&std::fs::read(run.join("metrics.json")).unwrap()).unwrap();
        m["train_seconds"].as_f64().unwrap()
    };
    let (before, ply) = (
        seconds(&run),
        std::fs::read(run.join("point_cloud.ply")).unwrap(),
    );
    // Without --resume the finished run is refused, not mixed or replaced.
    let err = fails(&exp(&[]));
    assert!(err.contains("--resume"), "{err}");
    // With it the finished run is evaluated again, not trained again, and the table rebuilt.
    std::fs::remove_file(out.join("table.md")).unwrap();
    ok(&exp(&["--resume"]));
    assert_eq!(seconds(&run), before);
    assert_eq!(std::fs::read(run.join("point_cloud.ply")).unwrap(), ply);
    // The table says per mode where the run came within 0.5 and 0.1 dB of its end.
    let table = std::fs::read_to_string(out.join("table.md")).unwrap();
    assert!(
        table.contains("- plain: within 0.5 dB at step")
            && table.contains("within 0.1 dB at step")
            && table.contains("20 steps in"),
        "{table}"
    );
}

/// Completion scripts for each shell and the man page come from the commands themselves:
/// every subcommand and a deep flag are in them.
#[test]
fn completions_and_the_man_page_name_every_command() {
    for shell in ["bash", "zsh", "fish", "elvish", "powershell"] {
        let script = ok(&["completions", shell]);
        for word in ["metasplat", "train", "render", "experiment", "save-at"] {
            assert!(script.contains(word), "{shell}: no {word}");
        }
    }
    let page = ok(&["man"]);
    assert!(
        page.contains(".TH metasplat 1"),
        "{}",
        &page[..200.min(page.len())]
    );
    assert!(page.contains("train") && page.contains("restorer"));
    let err = fails(&["completions", "tcsh"]);
    assert!(err.contains("tcsh"), "{err}");
}

/// A capture in nerfstudio's transforms.json trains, reports and aberrates as the same
/// capture in LLFF's layout does.
#[test]
fn a_transforms_json_capture_trains_and_aberrates() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let llff = d.join("llff");
    procedural(&llff, 32, 24, 5);
    let capture = scenes::open(
        &llff,
        &scenes::OpenOptions {
            resolution: scenes::Resolution::Downsample(1),
            ..Default::default()
        },
    )
    .unwrap();
    let ns = d.join("ns");
    std::fs::create_dir_all(ns.join("images")).unwrap();
    let mut frames = Vec::new();
    for (c, p) in capture.cameras.iter().zip(&capture.image_paths) {
        let name = p.file_name().unwrap().to_str().unwrap();
        std::fs::copy(p, ns.join("images").join(name)).unwrap();
        let c2w = c.camera_to_world();
        let r = c2w.rotation;
        let (x, y, z, t) = (r.x_axis, -r.y_axis, -r.z_axis, c2w.translation);
        frames.push(serde_json::json!({
            "file_path": format!("images/{name}"),
            "transform_matrix": [[x.x, y.x, z.x, t.x], [x.y, y.y, z.y, t.y], [x.z, y.z, z.z, t.z], [0, 0, 0, 1]],
        }));
    }
    let c = &capture.cameras[0];
    let doc = serde_json::json!({"fl_x": c.fx, "fl_y": c.fy, "cx": c.cx, "cy": c.cy,
        "w": c.width, "h": c.height, "frames": frames});
    std::fs::write(ns.join("transforms.json"), doc.to_string()).unwrap();
    let info = ok(&["scene", "info", s(&ns), "--downsample", "1"]);
    assert!(info.contains("nerfstudio"), "{info}");
    // Masks beside the photos, half of each view kept.
    std::fs::create_dir_all(ns.join("masks")).unwrap();
    for p in &capture.image_paths {
        let stem = p.file_stem().unwrap().to_str().unwrap();
        image::GrayImage::from_fn(32, 24, |x, _| image::Luma([if x < 16 { 0 } else { 255 }]))
            .save(ns.join("masks").join(format!("{stem}.png")))
            .unwrap();
    }
    let run = d.join("run");
    let text = ok(&[
        "train",
        "--scene",
        s(&ns),
        "--out",
        s(&run),
        "--mode",
        "plain",
        "--downsample",
        "1",
        "--iters",
        "5",
        "--spiral",
        "2",
        "--device",
        "cpu",
    ]);
    assert!(
        text.contains("Masks (masks/") && text.contains("4 of 4 training views are composited"),
        "{text}"
    );
    assert!(run.join("point_cloud.ply").is_file() && run.join("spiral").is_dir());
    let psf = d.join("psf.npy");
    small_psf(&psf);
    let abr = d.join("abr");
    ok(&[
        "scene",
        "aberrate",
        "--scene",
        s(&ns),
        "--psf",
        s(&psf),
        "--out",
        s(&abr),
        "--downsample",
        "1",
    ]);
    assert!(abr.join("poses_bounds.npy").is_file());
}

/// `bench restorer` times both kernels of each workload and prints a row per case; bad sizes
/// are refused naming the flag before anything runs.
#[test]
fn restorer_benchmark_times_both_kernels_and_refuses_bad_sizes() {
    let out = ok(&[
        "bench",
        "restorer",
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
    ]);
    let rows: Vec<&str> = out.lines().filter(|l| l.starts_with("tiny")).collect();
    assert_eq!(rows.len(), 2, "{out}");
    for row in rows {
        // The last six columns: reference s, fast s, speed-up, CPU s, s/MP, GFLOP/s, all
        // positive and finite.
        let words: Vec<&str> = row.split_whitespace().collect();
        let numbers: Vec<f64> = words[words.len() - 6..]
            .iter()
            .map(|w| w.trim_end_matches('x').parse().unwrap())
            .collect();
        assert!(numbers.iter().all(|v| v.is_finite() && *v > 0.0), "{row}");
    }
    let err = fails(&["bench", "restorer", "--configs", "tiny", "--sides", "100"]);
    assert!(err.contains("--sides") && err.contains("100 px"), "{err}");
    let err = fails(&["bench", "restorer", "--threads", "0"]);
    assert!(err.contains("--threads"), "{err}");
    let err = fails(&["bench", "restorer", "--train-only", "--batch", "0"]);
    assert!(err.contains("nothing to time"), "{err}");
}

/// `--resume --iters N` extends a finished run: one extension to 600 steps and two (to 400,
/// then 600) give the same splats byte for byte, the log reaches the new end, a shorter
/// `--iters` and a changed setting are refused naming them.
#[test]
fn resume_with_more_iters_extends_a_run_as_one_extension_would() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let clean = d.join("clean");
    procedural(&clean, 48, 32, 9);
    let train = |out: &Path, iters: &str, extra: &[&str]| {
        quick_train(&clean, out, iters, extra)
            .iter()
            .map(|a| a.to_string())
            .collect::<Vec<_>>()
    };
    let (a, b) = (d.join("a"), d.join("b"));
    ok(&train(&a, "200", &[]));
    let text = ok(&train(&a, "600", &["--resume"]));
    assert!(
        text.contains("extended to 600 steps") && text.contains("made for 200"),
        "{text}"
    );
    ok(&train(&b, "200", &[]));
    ok(&train(&b, "400", &["--resume"]));
    ok(&train(&b, "600", &["--resume"]));
    let ply = |r: &Path| std::fs::read(r.join("point_cloud.ply")).unwrap();
    assert_eq!(ply(&a), ply(&b), "two extensions differ from one");
    let log = std::fs::read_to_string(a.join("train_log.csv")).unwrap();
    assert!(log.lines().last().unwrap().starts_with("600,"), "{log}");
    // The same splats as the 200-step run would not do: the extension trained.
    let c = d.join("c");
    ok(&train(&c, "200", &[]));
    assert_ne!(ply(&a), ply(&c));
    let err = fails(&train(&a, "300", &["--resume"]));
    assert!(
        err.contains("--iters 300") && err.contains("600 steps") && err.contains("not shorten"),
        "{err}"
    );
    let err = fails(&train(&a, "800", &["--resume", "--max-sh-degree", "1"]));
    assert!(err.contains("max_sh_degree"), "{err}");
}

/// `render --video`: a GIF without any tool (every frame in it, at the path's length), an
/// .mp4 through the ffmpeg on the PATH (a stand-in here that records its arguments), and
/// without ffmpeg a refusal naming it and the .gif way out before anything is rendered.
/// The path through the capture's cameras and a nerfstudio camera path feed it.
#[test]
fn render_writes_a_video_with_or_without_ffmpeg() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let ply = d.join("scene.ply");
    splat::formats::ply::write_ply(&ply, &metasplat::splats::procedural::ground_truth(0)).unwrap();
    let gif = d.join("orbit.gif");
    let text = ok(&[
        "render",
        "--in",
        s(&ply),
        "--video",
        s(&gif),
        "--orbit",
        "7",
        "--width",
        "40",
        "--height",
        "30",
        "--device",
        "cpu",
    ]);
    assert!(text.contains("7 frames 40x30"), "{text}");
    let decoder = image::codecs::gif::GifDecoder::new(std::io::BufReader::new(
        std::fs::File::open(&gif).unwrap(),
    ))
    .unwrap();
    let frames = image::AnimationDecoder::into_frames(decoder)
        .collect_frames()
        .unwrap();
    assert_eq!(frames.len(), 7);
    assert_eq!(frames[0].buffer().dimensions(), (40, 30));
    assert_ne!(
        frames[0].buffer(),
        frames[3].buffer(),
        "the orbit does not move"
    );
    assert_ordinary_modes(d, &["gif"]);
    // No ffmpeg on the PATH: refused, nothing written.
    let empty = d.join("empty-bin");
    std::fs::create_dir_all(&empty).unwrap();
    let mp4 = d.join("orbit.mp4");
    let out = common::cli::metasplat()
        .env("PATH", &empty)
        .args([
            "render",
            "--in",
            s(&ply),
            "--video",
            s(&mp4),
            "--orbit",
            "3",
        ])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains("ffmpeg") && err.contains(".gif"),
        "{err}"
    );
    assert!(!mp4.exists());
    // A stand-in ffmpeg: it records its arguments and writes the file it is given last.
    let bin = d.join("bin");
    std::fs::create_dir_all(&bin).unwrap();
    let fake = bin.join("ffmpeg");
    std::fs::write(
        &fake,
        format!(
            "#!/bin/sh\necho \"$@\" > {}\nfor last; do :; done\necho video > \"$last\"\n",
            d.join("args").display()
        ),
    )
    .unwrap();
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(&fake, std::fs::Permissions::from_mode(0o755)).unwrap();
    // The path through a capture's cameras, at 12 frames per second.
    let capture = d.join("capture");
    procedural(&capture, 40, 30, 5);
    let out = common::cli::metasplat()
        .env("PATH", &bin)
        .args([
            "render",
            "--in",
            s(&ply),
            "--scene",
            s(&capture),
            "--downsample",
            "1",
            "--video",
            s(&mp4),
            "--through-cameras",
            "9",
            "--fps",
            "12",
            "--device",
            "cpu",
        ])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        text.contains("9 frames") && text.contains("through ffmpeg"),
        "{text}"
    );
    assert_eq!(std::fs::read_to_string(&mp4).unwrap(), "video\n");
    let args = std::fs::read_to_string(d.join("args")).unwrap();
    assert!(
        args.contains("-framerate 12") && args.contains("frame%05d.png"),
        "{args}"
    );
    // A nerfstudio camera path: its size and rate.
    let path = d.join("camera_path.json");
    let key = |x: f64| serde_json::json!({"camera_to_world": [1.0, 0.0, 0.0, x, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 4.0, 0.0, 0.0, 0.0, 1.0], "fov": 50.0, "aspect": 1.5});
    std::fs::write(
        &path,
        serde_json::json!({"render_width": 48, "render_height": 32, "fps": 10,
            "camera_path": [key(-0.5), key(0.0), key(0.5)]})
        .to_string(),
    )
    .unwrap();
    let text = ok(&[
        "render",
        "--in",
        s(&ply),
        "--path",
        s(&path),
        "--video",
        s(&gif),
        "--device",
        "cpu",
    ]);
    assert!(
        text.contains("3 frames 48x32") && text.contains("at 10 frames per second"),
        "{text}"
    );
    // A stand-in that exits 0 and writes nothing: refused, and no empty video is left.
    std::fs::write(&fake, "#!/bin/sh\nexit 0\n").unwrap();
    let empty = d.join("empty.mp4");
    let out = common::cli::metasplat()
        .env("PATH", &bin)
        .args([
            "render",
            "--in",
            s(&ply),
            "--path",
            s(&path),
            "--video",
            s(&empty),
            "--device",
            "cpu",
        ])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains("wrote nothing"),
        "{err}"
    );
    assert!(!empty.exists(), "an empty video was left");
    // A frame rate without a video is refused, naming the flag.
    let err = fails(&[
        "render",
        "--in",
        s(&ply),
        "--path",
        s(&path),
        "--out",
        s(&d.join("frames")),
        "--fps",
        "12",
    ]);
    assert!(err.contains("--fps 12") && err.contains("--video"), "{err}");
}

/// `train` without `--downsample` trains at the folder the capture has: `images/` for a
/// capture that has no `images_8/` (it used to be shrunk eight times), and says so.
#[test]
fn train_without_downsample_uses_the_folder_the_capture_has() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let capture = d.join("capture");
    procedural(&capture, 64, 48, 9);
    let run = d.join("run");
    let text = ok(&[
        "train",
        "-s",
        s(&capture),
        "-o",
        s(&run),
        "-m",
        "plain",
        "-n",
        "20",
        "--spiral",
        "0",
        "-d",
        "cpu",
    ]);
    assert!(text.contains("Using images/ of"), "{text}");
    assert!(text.contains("64x48"), "{text}");
    let render = image::open(run.join("test").join("view000.png")).unwrap();
    assert_eq!((render.width(), render.height()), (64, 48));
}

#[test]
fn iters_auto_stops_when_training_stops_paying_and_says_so() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let clean = d.join("clean");
    procedural(&clean, 48, 32, 9);
    let run = d.join("run");
    // Forty splats without SH bands: the model is soon as good as it can get.
    let args = [
        "train",
        "--scene",
        s(&clean),
        "--out",
        s(&run),
        "--mode",
        "plain",
        "--iters",
        "auto",
        "--downsample",
        "1",
        "--spiral",
        "1",
        "--max-splats",
        "40",
        "--max-sh-degree",
        "0",
    ];
    let text = ok(&args);
    // 7 training views: schedules for 1050 steps, densification until 525, windows of 105.
    assert!(
        text.contains("--iters auto: schedules made for 1050 steps")
            && text.contains("from step 525 on")
            && text.contains("at most 3150 steps"),
        "{text}"
    );
    assert!(text.contains("--iters auto: stopped at step"), "{text}");
    let metrics: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("metrics.json")).unwrap()).unwrap();
    let steps = metrics["iters"].as_u64().unwrap();
    let stopped = metrics["stopped"].as_str().unwrap();
    // Never before two whole windows past densification, plus the final phase; before the cap.
    assert!((525 + 2 * 105 + 105..3150).contains(&steps), "{steps}");
    let at: u64 = stopped
        .strip_prefix("stopped at step ")
        .and_then(|r| r.split_whitespace().next())
        .and_then(|n| n.parse().ok())
        .unwrap();
    assert_eq!(at + 105, steps, "{stopped}");
    assert!(at.is_multiple_of(105), "windows are whole epochs: {at}");
    // An auto run resumes as one, and a fixed count is refused naming the way.
    let mut fixed = args.to_vec();
    let at_iters = fixed.iter().position(|a| *a == "auto").unwrap();
    fixed[at_iters] = "5000";
    fixed.push("--resume");
    let err = fails(&fixed);
    assert!(
        err.contains("--iters 5000") && err.contains("made with --iters auto"),
        "{err}"
    );
}

/// `restore --psf PSF --in IN --out OUT --any-grid` and `extra`.
fn restore_args(psf: &Path, input: &Path, out: &Path, extra: &[&str]) -> Vec<String> {
    let mut args = vec![
        "restore",
        "--psf",
        s(psf),
        "--in",
        s(input),
        "--out",
        s(out),
        "--any-grid",
    ];
    args.extend_from_slice(extra);
    args.iter().map(|a| a.to_string()).collect()
}

/// `restore --in DIR` restores every frame of a folder into `--out` (a folder), each exactly as
/// `restore` makes it alone; a second run is refused unless `--resume`, which restores only
/// the frames missing.
#[test]
fn restore_a_folder_of_frames_as_each_alone_and_resume_the_rest() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let scene = d.join("scene");
    procedural(&scene, 48, 32, 3);
    let frames = scene.join("images");
    let psf = d.join("psf.npy");
    small_psf(&psf);
    let out = d.join("restored");
    let folder = |extra: &[&str]| restore_args(&psf, &frames, &out, extra);
    // Steadying off: each frame exactly as alone.
    let text = ok(&folder(&["--steady", "0"]));
    assert!(text.contains("restored 3 frames 48x32"), "{text}");
    for f in std::fs::read_dir(&frames).unwrap() {
        let f = f.unwrap().path();
        let alone = d.join("alone.png");
        ok(&[
            "restore",
            "--psf",
            s(&psf),
            "--in",
            s(&f),
            "--out",
            s(&alone),
            "--any-grid",
        ]);
        let name = f.file_stem().unwrap().to_str().unwrap().to_string() + ".png";
        assert_eq!(
            std::fs::read(&alone).unwrap(),
            std::fs::read(out.join(&name)).unwrap(),
            "{name}"
        );
        std::fs::remove_file(&alone).unwrap();
    }
    let err = fails(&folder(&[]));
    assert!(err.contains("exists") && err.contains("--resume"), "{err}");
    let first = std::fs::read_dir(&out)
        .unwrap()
        .next()
        .unwrap()
        .unwrap()
        .path();
    std::fs::remove_file(&first).unwrap();
    let text = ok(&folder(&["--resume", "--steady", "0"]));
    assert!(
        text.contains("2 of 3 frames were restored before") && text.contains("restored 1 frames"),
        "{text}"
    );
    assert!(first.exists());
    // The restored clip scored against the clean one: a row per frame, and flicker 0 for the
    // clean clip against itself.
    let text = ok(&[
        "restorer",
        "eval-video",
        "--restored",
        s(&out),
        "--clean",
        s(&frames),
    ]);
    assert_eq!(
        text.lines().filter(|l| l.starts_with("| view")).count(),
        3,
        "{text}"
    );
    assert!(
        text.contains("| mean |") && text.contains("flicker:"),
        "{text}"
    );
    let text = ok(&[
        "restorer",
        "eval-video",
        "--restored",
        s(&frames),
        "--clean",
        s(&frames),
    ]);
    assert!(text.contains("differ by 0.00000 more"), "{text}");
    let err = fails(&[
        "restorer",
        "eval-video",
        "--restored",
        s(&out),
        "--clean",
        s(&scene.join("sparse")),
    ]);
    assert!(err.contains("--clean"), "{err}");
}

/// `restore --in DIR --steady S` blends each restored frame with the previous one: the frames
/// after the first differ from frame-by-frame restoration, the first does not, and a clip
/// resumed after a stop gets the very bytes an unbroken run writes. A strength outside [0, 1)
/// and steadying a single photo are refused before anything is written.
#[test]
fn restore_a_folder_steadied_over_time_and_resume_it_unbroken() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // A short pan: a smooth texture moving a pixel right and half a pixel down per frame.
    let frames = d.join("frames");
    std::fs::create_dir(&frames).unwrap();
    for t in 0..4 {
        aberration::Image::from_fn(48, 32, |x, y| {
            let (u, v) = (x as f32 + t as f32, y as f32 + 0.5 * t as f32);
            let a = 0.5 + 0.25 * (0.3 * u + 0.2 * v).sin() + 0.2 * (0.13 * u - 0.4 * v).cos();
            [a, 0.7 * a + 0.1, 1.0 - a]
        })
        .save_png(&frames.join(format!("f{t}.png")))
        .unwrap();
    }
    let psf = d.join("psf.npy");
    small_psf(&psf);
    let run = |out: &Path, extra: &[&str]| restore_args(&psf, &frames, out, extra);
    let (plain, steady, resumed) = (d.join("plain"), d.join("steady"), d.join("resumed"));
    let text = ok(&run(&plain, &["--steady", "0"]));
    assert!(!text.contains("Steadying"), "{text}");
    let text = ok(&run(&steady, &["--steady", "0.6"]));
    assert!(
        text.contains("Steadying over time (--steady 0.6)"),
        "{text}"
    );
    // Without the flag a clip is steadied at the default strength, and says so.
    let default = d.join("default");
    let text = ok(&run(&default, &[]));
    assert!(
        text.contains("--steady 0.5, the default for clips"),
        "{text}"
    );
    let explicit = d.join("explicit");
    ok(&run(&explicit, &["--steady", "0.5"]));
    let mut names: Vec<_> = std::fs::read_dir(&plain)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    names.sort();
    assert_eq!(names.len(), 4);
    let bytes = |dir: &Path, n: &std::ffi::OsStr| std::fs::read(dir.join(n)).unwrap();
    assert!(bytes(&plain, &names[0]) == bytes(&steady, &names[0]));
    for n in &names[1..] {
        assert!(
            bytes(&plain, n) != bytes(&steady, n),
            "{n:?} was not steadied"
        );
    }
    for n in &names {
        assert!(bytes(&default, n) == bytes(&explicit, n), "{n:?}");
    }
    // A stop after two frames, then --resume: the same bytes as the unbroken run.
    std::fs::create_dir(&resumed).unwrap();
    for n in &names[..2] {
        std::fs::copy(steady.join(n), resumed.join(n)).unwrap();
    }
    ok(&run(&resumed, &["--steady", "0.6", "--resume"]));
    for n in &names {
        assert!(
            bytes(&steady, n) == bytes(&resumed, n),
            "{n:?} differs when resumed"
        );
    }
    for bad in ["1", "-0.2", "NaN"] {
        let out = d.join(format!("bad{bad}"));
        let err = fails(&run(&out, &[&format!("--steady={bad}")]));
        assert!(err.contains("--steady") && err.contains("[0, 1)"), "{err}");
        assert!(!out.exists());
    }
    let photo = std::fs::read_dir(&frames)
        .unwrap()
        .next()
        .unwrap()
        .unwrap()
        .path();
    let out = d.join("one.png");
    let err = fails(&restore_args(&psf, &photo, &out, &["--steady", "0.5"]));
    assert!(
        err.contains("--steady") && err.contains("one photo"),
        "{err}"
    );
    assert!(!out.exists());
}

/// `restore --in clip.gif --out restored.gif` restores every frame of an animated GIF, keeps
/// its frame times, and each frame is the restoration of that frame alone through the GIF's
/// palette.
#[test]
fn restore_an_animated_gif_frame_by_frame() {
    use image::AnimationDecoder;
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let scene = d.join("scene");
    procedural(&scene, 48, 32, 3);
    let psf = d.join("psf.npy");
    small_psf(&psf);
    let decode = |p: &Path| {
        image::codecs::gif::GifDecoder::new(std::io::BufReader::new(
            std::fs::File::open(p).unwrap(),
        ))
        .unwrap()
        .into_frames()
        .collect_frames()
        .unwrap()
    };
    // A three-frame clip of the scene's views, a tenth of a second each.
    let clip = d.join("clip.gif");
    {
        let mut bytes = Vec::new();
        let mut encoder = image::codecs::gif::GifEncoder::new(&mut bytes);
        let delay = image::Delay::from_numer_denom_ms(100, 1);
        for k in 0..3 {
            let f = image::open(scene.join("images").join(format!("view{k:03}.png")))
                .unwrap()
                .to_rgba8();
            encoder
                .encode_frame(image::Frame::from_parts(f, 0, 0, delay))
                .unwrap();
        }
        drop(encoder);
        std::fs::write(&clip, bytes).unwrap();
    }
    let restored = d.join("restored.gif");
    let text = ok(&[
        "restore",
        "--psf",
        s(&psf),
        "--in",
        s(&clip),
        "--out",
        s(&restored),
        "--any-grid",
        "--steady",
        "0",
    ]);
    assert!(text.contains("restored 3 frames 48x32"), "{text}");
    let (input, output) = (decode(&clip), decode(&restored));
    assert_eq!(output.len(), 3);
    for (k, (i, o)) in input.iter().zip(&output).enumerate() {
        assert_eq!(i.delay(), o.delay(), "frame {k}");
        // The frame alone, through the same restorer.
        let frame = d.join(format!("frame{k}.png"));
        image::DynamicImage::ImageRgba8(i.buffer().clone())
            .to_rgb8()
            .save(&frame)
            .unwrap();
        let alone = d.join(format!("alone{k}.png"));
        ok(&[
            "restore",
            "--psf",
            s(&psf),
            "--in",
            s(&frame),
            "--out",
            s(&alone),
            "--any-grid",
        ]);
        // The frame restored alone, through the GIF's palette (what any GIF of it holds): the
        // same pixels as the clip's frame.
        let a = image::open(&alone).unwrap().to_rgba8();
        let mut bytes = Vec::new();
        {
            let mut e = image::codecs::gif::GifEncoder::new_with_speed(&mut bytes, 10);
            e.encode_frame(image::Frame::new(a)).unwrap();
        }
        let through_palette = image::codecs::gif::GifDecoder::new(std::io::Cursor::new(bytes))
            .unwrap()
            .into_frames()
            .collect_frames()
            .unwrap();
        assert!(
            through_palette[0].buffer() == o.buffer(),
            "frame {k} differs from the frame restored alone"
        );
    }
    let err = fails(&[
        "restore",
        "--psf",
        s(&psf),
        "--in",
        s(&clip),
        "--out",
        s(&d.join("r.png")),
        "--any-grid",
    ]);
    assert!(err.contains(".gif"), "{err}");
}

/// `restore --in clip.mp4 --out restored.mp4`: the frames come out through ffmpeg (a stand-in
/// here that hands out a procedural scene's views and says "12 fps"), are restored as a folder
/// would be, and go back in at the clip's rate; the parts folder goes when the video is
/// written. Without ffmpeg the request is refused, naming the .gif and folder ways.
#[test]
fn restore_a_video_through_ffmpeg_at_its_rate() {
    use std::os::unix::fs::PermissionsExt;
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let scene = d.join("scene");
    procedural(&scene, 48, 32, 3);
    let psf = d.join("psf.npy");
    small_psf(&psf);
    let clip = d.join("clip.mp4");
    std::fs::write(&clip, b"not decoded by the stand-in").unwrap();
    let restored = d.join("restored.mp4");
    let args = [
        "restore",
        "--psf",
        s(&psf),
        "--in",
        s(&clip),
        "--out",
        s(&restored),
        "--any-grid",
    ];
    // No ffmpeg on the PATH.
    let empty = d.join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    let out = common::cli::metasplat()
        .env("PATH", &empty)
        .args(args)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success()
            && err.contains("ffmpeg")
            && err.contains(".gif")
            && err.contains("folder"),
        "{err}"
    );
    let bin = d.join("bin");
    std::fs::create_dir_all(&bin).unwrap();
    let fake = bin.join("ffmpeg");
    std::fs::write(
        &fake,
        format!(
            "#!/bin/sh\nfor last; do :; done\ncase \"$last\" in\n  *%05d.png) i=1; for f in '{frames}'/*.png; do /bin/cp \"$f\" \"${{last%/*}}/$(printf 'frame%05d.png' $i)\"; i=$((i+1)); done ;;\n  *.mp4) if [ \"$last\" = '{clip}' ]; then echo '  Stream #0:0: Video: h264, yuv420p, 48x32, 12 fps, 12 tbr' >&2; exit 1; fi; echo \"$@\" > '{args}'; echo video > \"$last\" ;;\nesac\n",
            frames = scene.join("images").display(),
            clip = clip.display(),
            args = d.join("args").display()
        ),
    )
    .unwrap();
    std::fs::set_permissions(&fake, std::fs::Permissions::from_mode(0o755)).unwrap();
    let out = common::cli::metasplat()
        .env("PATH", &bin)
        .args(args)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(text.contains("restored 3 frames 48x32"), "{text}");
    assert_eq!(std::fs::read_to_string(&restored).unwrap(), "video\n");
    let encoded = std::fs::read_to_string(d.join("args")).unwrap();
    assert!(encoded.contains("-framerate 12"), "{encoded}");
    assert!(
        !d.join("restored.mp4.parts").exists(),
        "the parts folder was left"
    );
}

/// `aberrate --in DIR --out DIR` makes a clip's aberrated twin: frame `i` as `aberrate` makes
/// it alone with the seed `mix64(seed ^ i)` (noise of its own per frame); the twin restores
/// and scores as a clip.
#[test]
fn aberrate_a_folder_of_frames_with_noise_of_their_own() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let scene = d.join("scene");
    procedural(&scene, 48, 32, 3);
    let frames = scene.join("images");
    let psf = d.join("psf.npy");
    small_psf(&psf);
    let abr = d.join("abr");
    let text = ok(&[
        "aberrate",
        "--psf",
        s(&psf),
        "--in",
        s(&frames),
        "--out",
        s(&abr),
        "--seed",
        "4",
    ]);
    assert!(text.contains("3 frames 48x32"), "{text}");
    for k in 0..3u64 {
        let alone = d.join(format!("alone{k}.png"));
        let seed = base::mix64(4 ^ k).to_string();
        ok(&[
            "aberrate",
            "--psf",
            s(&psf),
            "--in",
            s(&frames.join(format!("view{k:03}.png"))),
            "--out",
            s(&alone),
            "--seed",
            &seed,
        ]);
        assert_eq!(
            std::fs::read(&alone).unwrap(),
            std::fs::read(abr.join(format!("view{k:03}.png"))).unwrap(),
            "frame {k}"
        );
    }
    let restored = d.join("restored");
    ok(&[
        "restore",
        "--psf",
        s(&psf),
        "--in",
        s(&abr),
        "--out",
        s(&restored),
        "--any-grid",
    ]);
    let text = ok(&[
        "restorer",
        "eval-video",
        "--restored",
        s(&restored),
        "--clean",
        s(&frames),
    ]);
    assert!(text.contains("flicker:"), "{text}");
    // An existing frame is not overwritten.
    let err = fails(&[
        "aberrate",
        "--psf",
        s(&psf),
        "--in",
        s(&frames),
        "--out",
        s(&abr),
    ]);
    assert!(err.contains("exists"), "{err}");
}

/// `render --aberrate PSF` makes a clean and aberrated clip pair in one step: `clean/` holds
/// what `render` alone draws, `aberrated/` what `aberrate --in DIR` makes of it with the
/// same seed; the imaging flags without `--aberrate`, and `--aberrate` with `--video`, are
/// refused before anything is written.
#[test]
fn render_aberrate_makes_a_clean_and_aberrated_clip_pair() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let ply = d.join("model.glb");
    splat::formats::glb::write_glb(&ply, &splat::synthetic::random_box_scene(2, 2000, 1)).unwrap();
    let psf = d.join("psf.npy");
    small_psf(&psf);
    let orbit = [
        "--orbit", "3", "--width", "64", "--height", "48", "--device", "cpu",
    ];
    let render = |out: &Path, extra: &[&str]| {
        let mut args = vec!["render", "--ply", s(&ply), "--out", s(out)];
        args.extend_from_slice(&orbit);
        args.extend_from_slice(extra);
        args.iter().map(|a| a.to_string()).collect::<Vec<_>>()
    };
    let pair = d.join("pair");
    let text = ok(&render(&pair, &["--aberrate", s(&psf), "--seed", "5"]));
    assert!(text.contains("aberrated twin"), "{text}");
    let alone = d.join("alone");
    ok(&render(&alone, &[]));
    let twin = d.join("twin");
    ok(&[
        "aberrate",
        "--psf",
        s(&psf),
        "--in",
        s(&alone),
        "--out",
        s(&twin),
        "--seed",
        "5",
    ]);
    for k in 0..3 {
        let name = format!("orbit{k:03}.png");
        let read = |p: std::path::PathBuf| std::fs::read(p).unwrap();
        assert_eq!(
            read(pair.join("clean").join(&name)),
            read(alone.join(&name))
        );
        assert_eq!(
            read(pair.join("aberrated").join(&name)),
            read(twin.join(&name))
        );
        assert_ne!(
            read(pair.join("clean").join(&name)),
            read(pair.join("aberrated").join(&name))
        );
    }
    let refused = d.join("refused");
    let err = fails(&render(&refused, &["--seed", "5"]));
    assert!(err.contains("--aberrate"), "{err}");
    let err = fails(&[
        "render",
        "--ply",
        s(&ply),
        "--video",
        s(&d.join("clip.gif")),
        "--aberrate",
        s(&psf),
    ]);
    assert!(
        err.contains("--aberrate") && err.contains("--video"),
        "{err}"
    );
    assert!(!refused.exists() && !d.join("clip.gif").exists());
}

/// `bench step --refine-psf` outside aware mode is refused before any scene is read or any
/// step timed.
#[test]
fn bench_step_refuses_refine_psf_outside_aware_mode_first() {
    let err = fails(&[
        "bench",
        "step",
        "--scene",
        "/nonexistent/scene",
        "--mode",
        "plain",
        "--refine-psf",
    ]);
    assert!(
        err.contains("--refine-psf") && !err.contains("nonexistent"),
        "{err}"
    );
}
