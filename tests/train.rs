//! The training pipeline on a tiny procedural scene: aware beats plain, resume is exact,
//! `L_abr`'s gradient (through the blur's adjoint) matches finite differences, bad input.

mod common;

use std::path::PathBuf;
use std::sync::OnceLock;

use aberration::optics::{SimConfig, simulate_grid};
use metasplat::settings::DataOptions;
use metasplat::splats::device::Device;
use metasplat::splats::procedural::ProceduralOptions;
use metasplat::train::config::{Mode, Strategy, TrainConfig};
use metasplat::train::data::{self, Dataset};
use metasplat::train::eval::Against;
use metasplat::train::objective::{self, Objective};
use metasplat::train::{self, Event};
use splat::{RenderSettings, render, render_backward, render_for_backward};

struct Fixture {
    _dir: tempfile::TempDir,
    clean: PathBuf,
    aberrated: PathBuf,
    other_psf: PathBuf,
}

/// Built once per test binary: a 64×48 procedural capture and its aberrated copy.
fn fixture() -> &'static Fixture {
    static F: OnceLock<Fixture> = OnceLock::new();
    F.get_or_init(|| {
        let c = common::small_capture(1);
        let (other, _) = simulate_grid(&SimConfig::small(15), &|_, _| {}).unwrap();
        let other_psf = c.dir.path().join("other.npy");
        other.save_npy(&other_psf).unwrap();
        Fixture {
            _dir: c.dir,
            clean: c.clean,
            aberrated: c.aberrated,
            other_psf,
        }
    })
}

fn options() -> DataOptions {
    DataOptions {
        downsample: 1,
        ..DataOptions::default()
    }
}

fn config(mode: Mode, iters: u64, data: &Dataset) -> TrainConfig {
    let settings = metasplat::settings::TrainSettings {
        mode,
        iters: metasplat::settings::Iters::Steps(iters),
        eval_every: Some(0),
        checkpoint_every: Some(0),
        ..Default::default()
    };
    TrainConfig::build(&settings, 0, data)
}

fn mean_psnr(mode: Mode, iters: u64, lambda: f32) -> f64 {
    mean_psnr_on(&Device::Cpu, mode, iters, lambda)
}

fn mean_psnr_on(device: &Device, mode: Mode, iters: u64, lambda: f32) -> f64 {
    let data = data::load(&fixture().aberrated, mode, &options()).unwrap();
    let mut cfg = config(mode, iters, &data);
    cfg.lambda = lambda;
    let out = train::train(&cfg, &data, device, None, false, &mut |_| {}).unwrap();
    assert!(out.model.means.iter().all(|m| m.is_finite()));
    let m =
        metasplat::train::eval::evaluate(&out.model, &data.test, &out.settings, &Device::Cpu, None)
            .unwrap()
            .expect("the aberrated capture has clean images");
    m.mean_psnr
}

#[test]
fn aware_beats_plain_on_held_out_views() {
    let plain = mean_psnr(Mode::Plain, 600, 0.0);
    // λ = 0: at 64×48 the median-Wiener stand-in for I_ac is worse than the blurred input,
    // so this checks the physics term L_abr on its own.
    let aware = mean_psnr(Mode::Aware, 600, 0.0);
    let data = data::load(&fixture().aberrated, Mode::Plain, &options()).unwrap();
    let observed: f64 = data
        .test
        .iter()
        .map(|v| base::psnr_rgb(&v.observed, v.clean.as_ref().unwrap()).unwrap())
        .sum::<f64>()
        / data.test.len() as f64;
    eprintln!("observed {observed:.2} dB, plain {plain:.2} dB, aware {aware:.2} dB");
    // Plain 3DGS can at best reproduce the blur; aware training undoes it.
    assert!(
        plain < observed + 1.0,
        "plain {plain} vs observed {observed}"
    );
    assert!(aware > plain + 2.0, "aware {aware} vs plain {plain}");
}

#[test]
fn training_on_the_gpu_reaches_the_cpu_result() {
    let Some(device) = gpu_device() else { return };
    let cpu = mean_psnr(Mode::Aware, 300, 0.0);
    let gpu = mean_psnr_on(&device, Mode::Aware, 300, 0.0);
    eprintln!("aware, 300 steps: CPU {cpu:.3} dB, GPU {gpu:.3} dB");
    assert!((cpu - gpu).abs() <= 0.3, "CPU {cpu} dB vs GPU {gpu} dB");
}

fn gpu_device() -> Option<Device> {
    match Device::choose(metasplat::splats::device::DeviceChoice::Gpu) {
        Ok((d, note)) => {
            eprintln!("{note}");
            Some(d)
        }
        Err(e) if std::env::var("METASPLAT_REQUIRE_GPU").is_ok_and(|v| v == "1") => {
            panic!("METASPLAT_REQUIRE_GPU=1 but there is no GPU: {e}")
        }
        Err(e) => {
            eprintln!("SKIP: training on the GPU needs a wgpu adapter: {e}");
            None
        }
    }
}

/// The model and optimiser stay on the GPU between the steps that need them on the host;
/// a checkpoint written from there resumes bit for bit on the GPU (whose passes are
/// deterministic) and carries on on the CPU.
#[test]
fn a_gpu_run_resumes_exactly_and_carries_on_on_the_cpu() {
    let Some(gpu) = gpu_device() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let data = data::load(&fixture().aberrated, Mode::Aware, &options()).unwrap();
    let mut cfg = config(Mode::Aware, 240, &data);
    cfg.checkpoint_every = 100;
    cfg.opacity_reg = 0.01;
    // Densification, an opacity reset, epoch boundaries and SH steps on both sides of the
    // checkpoint.
    cfg.recipe.densify_from = 50;
    cfg.recipe.densify_every = 50;
    cfg.recipe.densify_until = 200;
    cfg.recipe.opacity_reset_every = Some(150);
    cfg.recipe.sh_every = 70;
    let ckpt = tmp.path().join("ckpt.bin");
    let kept = tmp.path().join("at100.bin");
    let (mut densified, mut sh) = (0, 0);
    let full = train::train(&cfg, &data, &gpu, Some(&ckpt), false, &mut |e| {
        match e {
            Event::Densified { .. } => densified += 1,
            Event::Sh { .. } => sh += 1,
            _ => {}
        }
        if let Event::Checkpoint { step: 100 } = e {
            std::fs::copy(&ckpt, &kept).unwrap();
        }
    })
    .unwrap();
    assert!(
        densified >= 2 && sh >= 2,
        "{densified} densifications, {sh} SH events"
    );
    let resumed = train::train(&cfg, &data, &gpu, Some(&kept), true, &mut |_| {}).unwrap();
    assert_eq!(resumed.resumed_from, Some(100));
    assert_eq!(full.model, resumed.model, "the resumed GPU run diverged");
    let on_cpu = train::train(&cfg, &data, &Device::Cpu, Some(&kept), true, &mut |_| {}).unwrap();
    let psnr = |m: &splat::Gaussians, s: &RenderSettings| {
        metasplat::train::eval::evaluate(m, &data.test, s, &Device::Cpu, None)
            .unwrap()
            .unwrap()
            .mean_psnr
    };
    let (a, b) = (
        psnr(&full.model, &full.settings),
        psnr(&on_cpu.model, &on_cpu.settings),
    );
    eprintln!("GPU throughout {a:.3} dB, GPU then CPU {b:.3} dB");
    assert!((a - b).abs() <= 0.3, "{a} vs {b}");
}

#[test]
fn resuming_from_a_checkpoint_gives_the_same_splats() {
    let tmp = tempfile::tempdir().unwrap();
    let data = data::load(&fixture().aberrated, Mode::Aware, &options()).unwrap();
    let mut cfg = config(Mode::Aware, 300, &data);
    cfg.checkpoint_every = 100;
    // Densification, an epoch boundary and an SH step all fall between checkpoint and end.
    cfg.recipe.densify_from = 50;
    cfg.recipe.densify_every = 50;
    cfg.recipe.densify_until = 250;
    cfg.recipe.sh_every = 120;
    let ckpt = tmp.path().join("ckpt.bin");
    let kept = tmp.path().join("at100.bin");
    let full = train::train(&cfg, &data, &Device::Cpu, Some(&ckpt), false, &mut |e| {
        if let Event::Checkpoint { step: 100 } = e {
            std::fs::copy(&ckpt, &kept).unwrap();
        }
    })
    .unwrap();
    // The resumed run goes on writing its checkpoint over this one.
    let at100 = std::fs::read(&kept).unwrap();
    let resumed = train::train(&cfg, &data, &Device::Cpu, Some(&kept), true, &mut |_| {}).unwrap();
    assert_eq!(resumed.resumed_from, Some(100));
    assert!(!full.model.is_empty());
    assert_eq!(full.model, resumed.model, "resumed run diverged");

    // Other settings cannot resume this checkpoint.
    let mut other = cfg.clone();
    other.lambda = 0.5;
    let err = train::train(&other, &data, &Device::Cpu, Some(&kept), true, &mut |_| {})
        .err()
        .expect("must refuse")
        .to_string();
    assert!(err.contains("lambda") && err.contains("at100.bin"), "{err}");
    // A damaged checkpoint (one flipped byte, or bytes added) is refused by its checksum.
    let good = std::fs::read(&kept).unwrap();
    for damage in [0usize, 1] {
        let mut bad = good.clone();
        if damage == 0 {
            let i = bad.len() / 2;
            bad[i] ^= 0x10;
        } else {
            bad.extend_from_slice(b"garbage");
        }
        std::fs::write(&kept, &bad).unwrap();
        let err = train::train(&cfg, &data, &Device::Cpu, Some(&kept), true, &mut |_| {})
            .err()
            .expect("must refuse")
            .to_string();
        assert!(
            (err.contains("checksum") || err.contains("damaged")) && err.contains("at100.bin"),
            "{err}"
        );
    }
    // The file is plain safetensors: its header, read here by hand, names the arrays with
    // their shapes, and the run's settings ride in its metadata.
    let header_len = u64::from_le_bytes(at100[..8].try_into().unwrap()) as usize;
    let header: serde_json::Value = serde_json::from_slice(&at100[8..8 + header_len]).unwrap();
    std::fs::write(&kept, &at100).unwrap();
    let state = metasplat::train::checkpoint::load(&kept).unwrap();
    assert_eq!(state.progress.step, 100);
    let means = &header["model.means"];
    assert_eq!(means["dtype"], "F32");
    assert_eq!(means["shape"], serde_json::json!([state.model.len(), 3]));
    let [a, b] = [0, 1].map(|k| means["data_offsets"][k].as_u64().unwrap() as usize);
    let first = f32::from_le_bytes(at100[8 + header_len + a..][..4].try_into().unwrap());
    assert_eq!(b - a, 12 * state.model.len());
    assert_eq!(first, state.model.means[0].x);
    assert!(
        header["__metadata__"]["metasplat"]
            .as_str()
            .unwrap()
            .contains("\"lambda\"")
    );
    // A checkpoint in the layout before safetensors, naming its capture as runs before XXH3
    // did, still resumes, to the same splats.
    let legacy = tmp.path().join("v2.bin");
    let mut then = state.config.clone();
    then.capture = Some(metasplat::train::config::legacy_capture_fingerprint(&data));
    assert_ne!(then.capture, state.config.capture);
    metasplat::train::checkpoint::save_v2(
        &legacy,
        &then,
        &state.progress,
        &state.model,
        &state.adam,
    )
    .unwrap();
    assert_eq!(&std::fs::read(&legacy).unwrap()[..16], b"metasplat-ckpt02");
    let again = train::train(&cfg, &data, &Device::Cpu, Some(&legacy), true, &mut |_| {}).unwrap();
    assert_eq!(again.resumed_from, Some(100));
    assert_eq!(
        full.model, again.model,
        "the version-2 checkpoint resumed elsewhere"
    );
    std::fs::write(&kept, b"metasplat-ckpt01 truncated").unwrap();
    let err = train::train(&cfg, &data, &Device::Cpu, Some(&kept), true, &mut |_| {})
        .err()
        .expect("must refuse")
        .to_string();
    assert!(err.contains("at100.bin"), "{err}");
    // Checkpoints edited and saved again, so their checksum holds, that lie: a value that is
    // not finite, a scale that overflows, a step past the run's end. Each is refused at
    // load, naming the file and the problem.
    type Edit = fn(&mut metasplat::train::checkpoint::State);
    let edits: [(&str, Edit, &str); 3] = [
        (
            "a NaN rotation",
            |s| s.model.rotations[0][1] = f32::NAN,
            "not finite",
        ),
        (
            "a huge scale",
            |s| s.model.log_scales[0].x = 85.0,
            "overflows",
        ),
        (
            "a step past the end",
            |s| s.progress.step = 10_000,
            "past the run's",
        ),
    ];
    for (what, edit, says) in edits {
        let mut s = metasplat::train::checkpoint::load(&tmp.path().join("v2.bin")).unwrap();
        edit(&mut s);
        metasplat::train::checkpoint::save(&kept, &s.config, &s.progress, &s.model, &s.adam)
            .unwrap();
        let err = train::train(&cfg, &data, &Device::Cpu, Some(&kept), true, &mut |_| {})
            .err()
            .unwrap_or_else(|| panic!("{what}: resumed"))
            .to_string();
        assert!(
            err.contains("at100.bin") && err.contains(says),
            "{what}: {err}"
        );
    }
}

#[test]
fn l_abr_gradient_through_the_blur_adjoint_matches_finite_differences() {
    let data = data::load(&fixture().aberrated, Mode::Aware, &options()).unwrap();
    let view = &data.train[0];
    // A few opaque-ish splats well inside the view, away from the renderer's thresholds
    // (1/255 alpha cut, 0.99 cap) that finite differences cannot straddle.
    let mut model = splat::Gaussians::new(1);
    let mut rng = base::SplitMix64::new(9);
    let cam = &view.camera;
    for _ in 0..8 {
        let depth = rng.uniform(5.0, 8.0) as f32;
        let (u, v) = (
            rng.uniform(16.0, 48.0) as f32,
            rng.uniform(12.0, 36.0) as f32,
        );
        let p_cam = glam::Vec3::new(
            (u - cam.cx) / cam.fx * depth,
            (v - cam.cy) / cam.fy * depth,
            depth,
        );
        let world = cam.rotation.transpose() * (p_cam - cam.translation);
        let rest: Vec<glam::Vec3> = (0..3)
            .map(|_| glam::Vec3::splat(rng.uniform(-0.1, 0.1) as f32))
            .collect();
        model.push(
            world,
            glam::Vec3::new(
                rng.uniform(-0.9, -0.5) as f32,
                rng.uniform(-0.9, -0.5) as f32,
                -1.2,
            ),
            [
                1.0,
                rng.uniform(-0.3, 0.3) as f32,
                rng.uniform(-0.3, 0.3) as f32,
                0.1,
            ],
            rng.uniform(-0.5, 1.0) as f32,
            glam::Vec3::new(
                rng.uniform(-1.0, 1.0) as f32,
                rng.uniform(-1.0, 1.0) as f32,
                0.5,
            ),
            &rest,
        );
    }
    let settings = RenderSettings {
        sh_degree: 1,
        ..RenderSettings::default()
    };
    for lambda in [0.0, 0.75] {
        let objective = Objective {
            mode: Mode::Aware,
            lambda,
            dssim_weight: 0.2,
            imaging: data.imaging.as_ref(),
            width: data.width,
            height: data.height,
            outside: None,
        };
        let loss = |m: &splat::Gaussians| -> f64 {
            let out = render(m, &view.camera, &settings).unwrap();
            objective.evaluate(&out.color, view).unwrap().0.total as f64
        };
        let (out, saved) = render_for_backward(&model, &view.camera, &settings).unwrap();
        let (parts, v) = objective.evaluate(&out.color, view).unwrap();
        // The value-only path the SH probes use gives the same bits.
        assert_eq!(
            objective.value(&out.color, view).unwrap().to_bits(),
            parts.total.to_bits()
        );
        // The paper's sum of the two terms, each as the one-term modes score it.
        let one_term = |mode| Objective {
            mode,
            lambda: 0.0,
            ..objective
        };
        let l_abr = one_term(Mode::Plain)
            .value(
                &objective
                    .as_observed(&out.color, view.mask.as_deref())
                    .unwrap(),
                view,
            )
            .unwrap() as f64;
        let l_ac = one_term(Mode::Restored).value(&out.color, view).unwrap() as f64;
        let want = l_abr + lambda as f64 * l_ac;
        assert!(
            (parts.total as f64 - want).abs() <= 1e-6 * want,
            "λ {lambda}: total {} against {l_abr} + λ·{l_ac} = {want}",
            parts.total
        );
        let g = render_backward(&model, &saved, &v, None, None).unwrap();
        // The Gaussians with the largest mean gradients: well above f32 noise.
        let mut order: Vec<usize> = (0..model.len()).collect();
        order.sort_by(|a, b| {
            g.params.means[*b]
                .length()
                .total_cmp(&g.params.means[*a].length())
        });
        let mut checked = 0;
        for &i in order.iter().take(4) {
            // Relative tolerances: colour is smooth; position, opacity and above all scale move
            // the α ≥ 1/255 cut-off ring, a jump the analytic gradient (as gsplat's) ignores.
            type Nudge = Box<dyn Fn(&mut splat::Gaussians, f32)>;
            let probes: [(&str, f64, f64, Nudge); 5] = [
                (
                    "mean.x",
                    g.params.means[i].x as f64,
                    0.03,
                    Box::new(move |m, e| m.means[i].x += e),
                ),
                (
                    "log_scale.y",
                    g.params.log_scales[i].y as f64,
                    0.07,
                    Box::new(move |m, e| m.log_scales[i].y += e),
                ),
                (
                    "opacity",
                    g.params.logit_opacities[i] as f64,
                    0.05,
                    Box::new(move |m, e| m.logit_opacities[i] += e),
                ),
                (
                    "sh_dc.g",
                    g.params.sh_dc[i].y as f64,
                    0.01,
                    Box::new(move |m, e| m.sh_dc[i].y += e),
                ),
                (
                    "sh_rest[1].b",
                    g.params.sh_rest[i * 3 + 1].z as f64,
                    0.02,
                    Box::new(move |m, e| m.sh_rest[i * 3 + 1].z += e),
                ),
            ];
            for (what, analytic, rel, nudge) in probes {
                let eps = 1e-2f32;
                let mut plus = model.clone();
                nudge(&mut plus, eps);
                let mut minus = model.clone();
                nudge(&mut minus, -eps);
                let fd = (loss(&plus) - loss(&minus)) / (2.0 * eps as f64);
                let tol = rel * fd.abs().max(analytic.abs()) + 1e-6;
                assert!(
                    (fd - analytic).abs() <= tol,
                    "λ={lambda} splat {i} {what}: analytic {analytic:e}, finite difference {fd:e}"
                );
                checked += 1;
            }
        }
        assert_eq!(checked, 20);
    }
}

#[test]
fn bad_input_is_reported_clearly() {
    let f = fixture();
    // A clean capture has no clean/ copies: training runs, and the held-out views are compared
    // with their own photos (the 3DGS report), said so in the metrics.
    let opts = DataOptions {
        psf: Some(f.aberrated.join("psf.npy")),
        ..options()
    };
    let data = data::load(&f.clean, Mode::Aware, &opts).unwrap();
    assert_eq!(
        metasplat::train::eval::reference(&data.test),
        Some(Against::Photos)
    );
    let cfg = config(Mode::Aware, 20, &data);
    let out = train::train(&cfg, &data, &Device::Cpu, None, false, &mut |_| {}).unwrap();
    let m =
        metasplat::train::eval::evaluate(&out.model, &data.test, &out.settings, &Device::Cpu, None)
            .unwrap()
            .unwrap();
    assert_eq!(m.against, Against::Photos);
    let v = &data.test[0];
    let render = Device::Cpu
        .render(&out.model, &v.camera, &out.settings)
        .unwrap()
        .color;
    let (psnr, _) =
        metasplat::train::eval::compare(&render, &v.observed, v.camera.width, v.camera.height)
            .unwrap();
    assert!(
        (m.views[0].psnr - psnr).abs() < 1e-9,
        "{} vs {psnr}",
        m.views[0].psnr
    );
    // The aberrated capture has clean copies, and is compared with them.
    let aberrated = data::load(&f.aberrated, Mode::Aware, &options()).unwrap();
    assert_eq!(
        metasplat::train::eval::reference(&aberrated.test),
        Some(Against::Clean)
    );

    // Aware mode needs a PSF: a clean capture without --psf is refused, naming the folder.
    let err = data::load(&f.clean, Mode::Aware, &options())
        .err()
        .unwrap()
        .to_string();
    assert!(
        err.contains("needs the PSF grid") && err.contains("clean"),
        "{err}"
    );
    // A PSF grid other than the capture's own.
    let opts = DataOptions {
        psf: Some(f.other_psf.clone()),
        ..options()
    };
    let err = data::load(&f.aberrated, Mode::Aware, &opts)
        .err()
        .unwrap()
        .to_string();
    assert!(
        err.contains("other.npy") && err.contains("not the one"),
        "{err}"
    );
    // The wrong resolution of an aberrated capture.
    let opts = DataOptions {
        downsample: 2,
        ..options()
    };
    assert!(data::load(&f.aberrated, Mode::Plain, &opts).is_err());
    // An unwritable run folder fails before any training.
    let blocker = f._dir.path().join("a-file");
    std::fs::write(&blocker, b"x").unwrap();
    let err = metasplat::output::prepare_run_dir(&blocker.join("run"), "train")
        .err()
        .unwrap()
        .to_string();
    assert!(err.contains("a-file"), "{err}");
}

#[test]
fn the_first_non_finite_value_stops_the_run_and_keeps_the_last_checkpoint() {
    let tmp = tempfile::tempdir().unwrap();
    let mut data = data::load(&fixture().aberrated, Mode::Plain, &options()).unwrap();
    let mut cfg = config(Mode::Plain, 40, &data);
    cfg.checkpoint_every = 100;
    let ckpt = tmp.path().join("ckpt.bin");
    // A good run writes its checkpoint; then one NaN pixel in every view.
    train::train(&cfg, &data, &Device::Cpu, Some(&ckpt), false, &mut |_| {}).unwrap();
    let good = std::fs::read(&ckpt).unwrap();
    for v in &mut data.train {
        v.observed[7] = glam::Vec3::NAN;
    }
    let err = train::train(&cfg, &data, &Device::Cpu, Some(&ckpt), false, &mut |_| {})
        .err()
        .unwrap()
        .to_string();
    assert!(
        err.contains("step 1") && err.contains("loss is not finite") && err.contains("checkpoint"),
        "{err}"
    );
    assert_eq!(
        std::fs::read(&ckpt).unwrap(),
        good,
        "the checkpoint changed"
    );
}

/// The capture's geometry sets two defaults: cameras all around the scene get opacity resets
/// and twice the splat budget of a forward-facing capture of the same image size.
/// A capture taken all around gets twice the budget; without SfM points `auto` trains it as
/// MCMC (no resets), and the adaptive strategy asked for resets its opacities.
#[test]
fn a_capture_taken_all_around_gets_a_larger_budget_and_mcmc_or_resets() {
    let dir = tempfile::tempdir().unwrap();
    let o = ProceduralOptions {
        width: 64,
        height: 48,
        views: 12,
        seed: 2,
    };
    let facing =
        metasplat::splats::procedural::write_capture(&dir.path().join("facing"), &o).unwrap();
    let around =
        metasplat::splats::procedural::write_capture_around(&dir.path().join("around"), &o)
            .unwrap();
    let build = |capture: &std::path::Path, strategy| {
        let data = data::load(capture, Mode::Plain, &options()).unwrap();
        let settings = metasplat::settings::TrainSettings {
            mode: Mode::Plain,
            iters: metasplat::settings::Iters::Steps(1000),
            strategy,
            ..Default::default()
        };
        TrainConfig::build(&settings, 0, &data)
    };
    let auto = metasplat::settings::StrategyChoice::Auto;
    let (f, a) = (build(&facing, auto), build(&around, auto));
    assert_eq!(f.max_splats, 64 * 48 / 2);
    assert_eq!(a.max_splats, 2 * f.max_splats);
    // The forward-facing capture has SfM points: adaptive, without resets.
    assert_eq!(f.strategy, Strategy::Adaptive);
    assert!(f.recipe.opacity_reset_every.is_none());
    assert!(matches!(a.strategy, Strategy::Mcmc(_)));
    assert!(a.recipe.opacity_reset_every.is_none());
    let adaptive = build(&around, metasplat::settings::StrategyChoice::Adaptive);
    assert_eq!(adaptive.strategy, Strategy::Adaptive);
    assert!(adaptive.recipe.opacity_reset_every.is_some());
    assert_eq!((adaptive.opacity_reg, adaptive.scale_reg), (0.0, 0.0));
}

/// With the Wiener stand-in as `I_ac` and no λ given, aware's λ holds for the first thousand
/// steps and falls to zero by the end of densification; other modes, other restorers and a λ
/// given keep a constant λ; `--lambda-fade` overrides the rule.
#[test]
fn the_stand_in_restorer_fades_lambda_out() {
    let data = data::load(&fixture().aberrated, Mode::Aware, &options()).unwrap();
    assert!(matches!(
        data.restorer,
        Some(metasplat::train::iac::IacSource::Wiener)
    ));
    // A run of the default length: held for the first thousand steps, zero by the end of
    // densification.
    let cfg = config(Mode::Aware, 7000, &data);
    assert_eq!(cfg.lambda_fade_until, Some(3500));
    assert_eq!(cfg.lambda_hold_until, 1000);
    assert_eq!(cfg.lambda_at(0), cfg.lambda);
    assert_eq!(cfg.lambda_at(1000), cfg.lambda);
    assert!((cfg.lambda_at(2250) - cfg.lambda / 2.0).abs() < 1e-6);
    assert_eq!(cfg.lambda_at(3500), 0.0);
    assert_eq!(cfg.lambda_at(6000), 0.0);
    // A short run keeps λ throughout.
    let cfg = config(Mode::Aware, 1000, &data);
    assert!((0..=1000).all(|t| cfg.lambda_at(t) == cfg.lambda));
    // One ending between the hold and the end of densification: λ stops at the hold.
    let cfg = config(Mode::Aware, 1500, &data);
    assert_eq!(cfg.lambda_at(1000), cfg.lambda);
    assert_eq!(cfg.lambda_at(1001), 0.0);
    let plain = data::load(&fixture().aberrated, Mode::Plain, &options()).unwrap();
    let cfg = config(Mode::Plain, 1000, &plain);
    assert_eq!(cfg.lambda_fade_until, None);
    // A λ given explicitly is used as given.
    let settings = metasplat::settings::TrainSettings {
        mode: Mode::Aware,
        iters: metasplat::settings::Iters::Steps(1000),
        lambda: Some(0.25),
        ..Default::default()
    };
    let cfg = TrainConfig::build(&settings, 0, &data);
    assert_eq!(cfg.lambda_fade_until, None);
    assert_eq!(cfg.lambda_at(900), 0.25);
    // --lambda-fade overrides the rule, in either direction.
    use metasplat::settings::LambdaFade;
    for (fade, want) in [
        (LambdaFade::Never, None),
        (LambdaFade::End, Some(1000)),
        (LambdaFade::Step(300), Some(300)),
    ] {
        let settings = metasplat::settings::TrainSettings {
            mode: Mode::Aware,
            iters: metasplat::settings::Iters::Steps(1000),
            lambda_fade: fade,
            ..Default::default()
        };
        let cfg = TrainConfig::build(&settings, 0, &data);
        assert_eq!(cfg.lambda_fade_until, want, "{fade}");
    }
    // Held, then falling: FROM:TO.
    let settings = metasplat::settings::TrainSettings {
        mode: Mode::Aware,
        iters: metasplat::settings::Iters::Steps(1000),
        lambda: Some(0.4),
        lambda_fade: LambdaFade::Range(200, 600),
        ..Default::default()
    };
    let cfg = TrainConfig::build(&settings, 0, &data);
    assert_eq!(cfg.lambda_at(200), 0.4);
    assert!((cfg.lambda_at(400) - 0.2).abs() < 1e-6);
    assert_eq!(cfg.lambda_at(600), 0.0);
    assert_eq!(
        "200:600".parse::<LambdaFade>(),
        Ok(LambdaFade::Range(200, 600))
    );
    assert!("600:200".parse::<LambdaFade>().is_err());
    assert_eq!("end".parse::<LambdaFade>(), Ok(LambdaFade::End));
    assert_eq!("250".parse::<LambdaFade>(), Ok(LambdaFade::Step(250)));
    assert!("soon".parse::<LambdaFade>().unwrap_err().contains("soon"));
}

/// SH bands are judged on the loss the step minimises: once λ has faded to zero the probes
/// must leave `L(render, I_ac)` out. The band's gain is recomputed here from the final model
/// with the objective at the last step; with the configured λ it would be another number.
#[test]
fn sh_bands_are_judged_on_the_loss_training_minimises() {
    use metasplat::train::sh::ShEvent;
    let data = data::load(&fixture().aberrated, Mode::Aware, &options()).unwrap();
    assert!(data.train.iter().all(|v| v.restored.is_some()));
    // Band 1 comes at step 100 and trains until the end judges it.
    let mut cfg = config(Mode::Aware, 200, &data);
    cfg.max_sh_degree = 1;
    cfg.lambda = 1.0;
    cfg.lambda_hold_until = 0;
    cfg.lambda_fade_until = Some(50);
    cfg.recipe.sh_every = 100;
    // Every band tested is kept, so the final model still holds the band the end judged.
    cfg.recipe.sh_min_gain = -1e9;
    let out = train::train(&cfg, &data, &Device::Cpu, None, false, &mut |_| {}).unwrap();
    let Some(&ShEvent::Kept { degree: 1, gain }) = out.sh_events.last() else {
        panic!("band 1 was not judged at the end: {:?}", out.sh_events);
    };
    assert_eq!(out.model.sh_degree, 1);
    let gain_with = |lambda: f32| {
        let objective = Objective {
            mode: Mode::Aware,
            lambda,
            dssim_weight: cfg.recipe.dssim_weight,
            imaging: data.imaging.as_ref(),
            width: data.width,
            height: data.height,
            outside: None,
        };
        let (n, m) = (data.train.len(), data.train.len().min(8));
        let loss = |degree: u32| {
            let s = RenderSettings {
                sh_degree: degree,
                ..out.settings
            };
            (0..m)
                .map(|k| {
                    let v = &data.train[k * n / m];
                    let image = render(&out.model, &v.camera, &s).unwrap().color;
                    objective.value(&image, v).unwrap() as f64
                })
                .sum::<f64>()
                / m as f64
        };
        let (with, without) = (loss(1), loss(0));
        (without - with) / with.abs().max(1e-12)
    };
    let (right, configured) = (gain_with(cfg.lambda_at(200)), gain_with(cfg.lambda));
    eprintln!(
        "band 1: gain {gain:e}; at the step's λ {right:e}, at the configured λ {configured:e}"
    );
    assert_eq!(cfg.lambda_at(200), 0.0);
    assert!(
        (right - configured).abs() > 1e-6,
        "the two losses judge the band alike: the test cannot tell them apart"
    );
    assert!(
        (gain - right).abs() <= 1e-9 * right.abs().max(1e-9),
        "{gain:e} vs {right:e}"
    );
}

/// A resume with other settings names each changed setting once, by its path, with both
/// values: a sentence, not two copies of the nested settings.
#[test]
fn a_refused_resume_names_each_changed_setting_by_its_path() {
    let data = data::load(&fixture().aberrated, Mode::Plain, &options()).unwrap();
    let then = config(Mode::Plain, 10, &data);
    assert!(train::config_differences(&then, &then).is_empty());
    let mut now = then.clone();
    now.seed = 7;
    now.recipe.densify_until += 1;
    let diff = train::config_differences(&now, &then);
    assert_eq!(
        diff,
        vec![
            format!(
                "recipe.densify_until (checkpoint {}, now {})",
                then.recipe.densify_until, now.recipe.densify_until
            ),
            "seed (checkpoint 0, now 7)".to_string(),
        ]
    );
    // A checkpoint written before captures were recorded does not stop a resume.
    let mut old = then.clone();
    old.capture = None;
    assert!(train::config_differences(&then, &old).is_empty());
    let mut other = then.clone();
    other.capture = Some("another capture".into());
    assert_eq!(train::config_differences(&other, &then).len(), 1);
    // When the splats are kept, checkpointed and evaluated changes none of them.
    let mut cadence = then.clone();
    cadence.save_at = vec![5];
    cadence.checkpoint_every = 3;
    cadence.eval_every = 2;
    assert!(train::config_differences(&cadence, &then).is_empty());
}

/// The log file grows with the run: after each evaluation `train_log.csv` already holds a
/// row for every evaluation so far (so `tail -f` follows a run away from a terminal).
#[test]
fn the_log_file_holds_every_evaluation_while_the_run_trains() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    let mut request = metasplat::settings::RunRequest::new(&fixture().aberrated, &out);
    request.data.downsample = 1;
    request.training.mode = Mode::Plain;
    request.training.iters = metasplat::settings::Iters::Steps(30);
    request.training.eval_every = Some(10);
    request.spiral = 0;
    let mut prepared = metasplat::run::prepare(&request).unwrap();
    let log = out.join(metasplat::output::LOG_FILE);
    let mut seen = Vec::new();
    prepared
        .run(&mut |e| {
            if let Event::Evaluated { step, .. } = e {
                seen.push(step);
            }
            if let Event::Step { step, .. } = e
                && step % 10 == 5
            {
                // Between evaluations: one row per evaluation so far, and a header.
                let text = std::fs::read_to_string(&log).unwrap_or_default();
                let rows = text.lines().count().saturating_sub(1);
                assert_eq!(rows, seen.len(), "at step {step}: {text}");
            }
        })
        .unwrap();
    assert_eq!(seen, [10, 20, 30]);
}

/// A mask leaves pixels out of the loss: where it is 0 the loss does not change with the render
/// and the gradient is exactly zero; where it keeps or blends, the gradient matches finite
/// differences of the loss, in plain and in aware mode (through the blur and its adjoint).
#[test]
fn masked_pixels_leave_the_loss_and_the_gradient_matches_finite_differences() {
    let through = Some(glam::Vec3::new(0.2, 0.1, 0.0));
    for (mode, outside) in [
        (Mode::Plain, None),
        (Mode::Aware, None),
        (Mode::Aware, through),
    ] {
        let mut data = data::load(&fixture().aberrated, mode, &options()).unwrap();
        let cfg = config(mode, 10, &data);
        let (w, h) = (data.width, data.height);
        let n = (w * h) as usize;
        let mask: Vec<f32> = (0..n)
            .map(|i| match (i % w as usize) * 3 / w as usize {
                0 => 0.0,
                1 => 0.5,
                _ => 1.0,
            })
            .collect();
        data.train[0].mask = Some(mask.clone());
        let view = &data.train[0];
        let objective = Objective {
            mode,
            lambda: cfg.lambda,
            // D-SSIM alone: L1's kinks would make finite differences straddle, whatever the mask.
            dssim_weight: 1.0,
            imaging: data.imaging.as_ref(),
            width: w,
            height: h,
            outside,
        };
        let rendered: Vec<glam::Vec3> = view
            .observed
            .iter()
            .enumerate()
            .map(|(i, p)| *p * 0.7 + glam::Vec3::splat(0.1 + ((i * 37) % 11) as f32 / 50.0))
            .collect();
        let (parts, grad) = objective.evaluate(&rendered, view).unwrap();
        assert!((parts.total - objective.value(&rendered, view).unwrap()).abs() < 1e-6);
        // Directional derivatives along a pattern inside each block of the mask: many pixels'
        // contributions, far above f32 noise.
        for keep in [0.0f32, 0.5, 1.0] {
            let d: Vec<glam::Vec3> = (0..n)
                .map(|i| {
                    if mask[i] == keep {
                        glam::Vec3::new(1.0, -0.5, 0.25) * (((i * 13) % 7) as f32 / 7.0 - 0.4)
                    } else {
                        glam::Vec3::ZERO
                    }
                })
                .collect();
            let eps = 1e-2f32;
            let at = |t: f32| {
                let r: Vec<glam::Vec3> =
                    rendered.iter().zip(&d).map(|(p, q)| *p + *q * t).collect();
                objective.value(&r, view).unwrap() as f64
            };
            let fd = (at(eps) - at(-eps)) / (2.0 * eps as f64);
            let g: f64 = grad.iter().zip(&d).map(|(a, b)| a.dot(*b) as f64).sum();
            // Through the lens a masked pixel still reaches the kept ones, unless the lens is
            // known to have seen a constant there.
            if keep == 0.0 && (mode == Mode::Plain || outside.is_some()) {
                assert!(
                    d.iter()
                        .zip(&grad)
                        .all(|(q, a)| *q == glam::Vec3::ZERO || *a == glam::Vec3::ZERO),
                    "a masked pixel got a gradient"
                );
                assert_eq!(fd, 0.0, "masked pixels changed the loss");
            } else {
                // The loss is an f32 sum over every pixel: its finite differences scatter by a
                // few per cent where the probe moves it little (the blur's leak out of a masked
                // block), so the bound is that, not the gradient's own error.
                assert!(
                    (g - fd).abs() <= 5e-2 * fd.abs() + 1e-5,
                    "{mode} ({outside:?} outside) mask {keep}: gradient {g:e}, finite differences {fd:e}"
                );
                assert!(
                    fd.abs() > 1e-4,
                    "{mode} mask {keep}: the probe moves nothing ({fd:e})"
                );
            }
        }
    }
}

/// Aware mode with `loss` masks on a copy composited over a colour before the blur: the
/// render is composited over it outside the mask before the blur, so a render that is right
/// inside the mask matches the observation exactly (`L_abr` at its floor) whatever it shows
/// outside, where blurring the render as it is does not.
#[test]
fn the_lens_sees_the_composite_colour_outside_loss_masks() {
    let data = data::load(&fixture().aberrated, Mode::Aware, &options()).unwrap();
    let imaging = data.imaging.as_ref().unwrap();
    let (w, h) = (data.width, data.height);
    let n = (w * h) as usize;
    // A border two pixels wide leaves the loss, as undistortion's does.
    let mask: Vec<f32> = (0..n)
        .map(|i| {
            let (x, y) = (i as u32 % w, i as u32 / w);
            let inside = x >= 2 && y >= 2 && x + 2 < w && y + 2 < h;
            if inside { 1.0 } else { 0.0 }
        })
        .collect();
    let c0 = glam::Vec3::new(0.0, 0.05, 0.1);
    let clean: Vec<glam::Vec3> = data.train[0]
        .observed
        .iter()
        .enumerate()
        .map(|(i, p)| (*p + glam::Vec3::splat(((i * 7) % 5) as f32 / 40.0)).min(glam::Vec3::ONE))
        .collect();
    let composite: Vec<glam::Vec3> = clean
        .iter()
        .zip(&mask)
        .map(|(p, &m)| *p * m + c0 * (1.0 - m))
        .collect();
    let mut view = data.train[0].clone();
    view.observed = imaging.blur_pixels(&composite).unwrap();
    view.mask = Some(mask.clone());
    // The render: right inside, bright outside (nothing there constrains it).
    let rendered: Vec<glam::Vec3> = clean
        .iter()
        .zip(&mask)
        .map(|(p, &m)| if m > 0.0 { *p } else { glam::Vec3::ONE })
        .collect();
    let l_abr = |outside| {
        let objective = Objective {
            mode: Mode::Aware,
            lambda: 0.0,
            dssim_weight: 0.2,
            imaging: Some(imaging),
            width: w,
            height: h,
            outside,
        };
        objective.value(&rendered, &view).unwrap()
    };
    let (exact, as_is) = (l_abr(Some(c0)), l_abr(None));
    assert!(exact < 1e-5, "composited before the blur: L_abr {exact:e}");
    assert!(
        as_is > 100.0 * exact.max(1e-6),
        "the render blurred as it is should miss the observation: {as_is:e} against {exact:e}"
    );
    // Which runs composite: aware ones whose masks leave pixels out of the loss (none here, as
    // undistortion's border, or `--mask-mode loss`), not object runs (their own targets), not
    // the other modes, and only on a copy that says what it was composited over.
    let c = Some(c0.to_array());
    let mut cfg = config(Mode::Aware, 10, &data);
    for (masks, want) in [
        (None, Some(c0)),
        (Some(metasplat::settings::MaskUse::Loss), Some(c0)),
        (Some(metasplat::settings::MaskUse::Object), None),
    ] {
        cfg.masks = masks;
        assert_eq!(objective::outside_colour(&cfg, c), want, "{masks:?}");
        assert_eq!(objective::outside_colour(&cfg, None), None, "{masks:?}");
    }
    cfg.masks = None;
    cfg.mode = Mode::Restored;
    assert_eq!(objective::outside_colour(&cfg, c), None);
}

/// `--background random`: a render can no longer match a pixel by letting the background
/// show through, so the model ends opaque where one trained on black leaves it see-through
/// (measured as the mean transmittance: a render on white minus the same render on black).
#[test]
fn a_random_background_leaves_no_see_through_pixels() {
    let data = data::load(&fixture().clean, Mode::Plain, &options()).unwrap();
    let run = |random: bool| {
        let mut cfg = config(Mode::Plain, 400, &data);
        cfg.background = [0.0; 3];
        cfg.random_background = random;
        let out = train::train(&cfg, &data, &Device::Cpu, None, false, &mut |_| {}).unwrap();
        assert_eq!(out.settings.background, glam::Vec3::ZERO);
        let on = |c: f32| RenderSettings {
            background: glam::Vec3::splat(c),
            ..out.settings
        };
        let (mut sum, mut n) = (0.0f64, 0usize);
        for v in data.train.iter().chain(&data.test) {
            let black = render(&out.model, &v.camera, &on(0.0)).unwrap().color;
            let white = render(&out.model, &v.camera, &on(1.0)).unwrap().color;
            for (b, w) in black.iter().zip(&white) {
                sum += ((*w - *b).element_sum() / 3.0) as f64;
                n += 1;
            }
        }
        let psnr = metasplat::train::eval::evaluate(
            &out.model,
            &data.test,
            &out.settings,
            &Device::Cpu,
            None,
        )
        .unwrap()
        .map(|m| m.mean_psnr);
        (sum / n as f64, psnr)
    };
    let (black, black_psnr) = run(false);
    let (random, random_psnr) = run(true);
    eprintln!(
        "mean transmittance: trained on black {black:.4} (held-out {black_psnr:?}), on random colours {random:.4} ({random_psnr:?})"
    );
    assert!(random < 0.5 * black, "{random} vs {black}");
    let a = metasplat::train::config::random_background(0, 7);
    assert!(a.iter().all(|c| (0.0..1.0).contains(c)));
    assert_ne!(a, metasplat::train::config::random_background(0, 8));
    assert_ne!(a, metasplat::train::config::random_background(1, 7));
    assert_eq!(a, metasplat::train::config::random_background(0, 7));
}

/// A capture whose photos went through a known lens distortion (OPENCV in its COLMAP
/// cameras file): undistorted at load it trains a scene closer to the pinhole truth than
/// with the photos as taken (`--keep-distortion`), judged by rendering the held-out cameras
/// against the undistorted procedural images.
#[test]
fn a_distorted_capture_trains_better_undistorted_at_load() {
    use scenes::{CameraModel, Distortion, Photo};
    let dir = tempfile::tempdir().unwrap();
    let o = ProceduralOptions {
        width: 96,
        height: 72,
        views: 12,
        seed: 2,
    };
    let clean =
        metasplat::splats::procedural::write_capture(&dir.path().join("clean"), &o).unwrap();
    let open = |d: &std::path::Path| {
        scenes::open(
            d,
            &scenes::OpenOptions {
                resolution: scenes::Resolution::Downsample(1),
                ..Default::default()
            },
        )
        .unwrap()
    };
    let truth = open(&clean);
    let lens = Distortion {
        model: CameraModel::OpenCv,
        k1: 0.25,
        k2: 0.0,
        p1: 0.004,
        p2: -0.003,
        rational: [0.0; 4],
    };
    // The distorted capture: the same poses and points, photos seen through the lens.
    let taken = dir.path().join("taken");
    std::fs::create_dir_all(taken.join("images")).unwrap();
    std::fs::create_dir_all(taken.join("sparse/0")).unwrap();
    std::fs::copy(
        clean.join("poses_bounds.npy"),
        taken.join("poses_bounds.npy"),
    )
    .unwrap();
    std::fs::copy(
        clean.join("sparse/0/points3D.txt"),
        taken.join("sparse/0/points3D.txt"),
    )
    .unwrap();
    let c = &truth.cameras[0];
    scenes::colmap::binary::write_cameras(
        &taken.join("sparse/0/cameras.bin"),
        &[scenes::colmap::ColmapCamera {
            id: 1,
            model: CameraModel::OpenCv,
            width: c.width as u64,
            height: c.height as u64,
            params: vec![c.fx, c.fy, c.cx, c.cy, lens.k1, lens.k2, lens.p1, lens.p2],
        }],
    )
    .unwrap();
    let (w, h) = (c.width, c.height);
    let mut pinhole = Vec::new();
    for (i, path) in truth.image_paths.iter().enumerate() {
        let img = truth.load_image(i).unwrap();
        let mut data = Vec::with_capacity(img.data.len());
        for y in 0..h {
            for x in 0..w {
                // The ray this sensor pixel shows, by fixed-point iteration, sampled
                // bilinearly in the pinhole image.
                let (xd, yd) = (
                    (x as f64 + 0.5 - c.cx) / c.fx,
                    (y as f64 + 0.5 - c.cy) / c.fy,
                );
                let (mut u, mut v) = (xd, yd);
                for _ in 0..100 {
                    let (a, b) = lens.distort(u, v);
                    u -= a - xd;
                    v -= b - yd;
                }
                let (px, py) = (u * c.fx + c.cx - 0.5, v * c.fy + c.cy - 0.5);
                let (x0, y0) = (px.floor(), py.floor());
                let (tx, ty) = ((px - x0) as f32, (py - y0) as f32);
                let at = |x: f64, y: f64| {
                    img.pixel(
                        (x as i64).clamp(0, w as i64 - 1) as u32,
                        (y as i64).clamp(0, h as i64 - 1) as u32,
                    )
                };
                let (p00, p10, p01, p11) = (
                    at(x0, y0),
                    at(x0 + 1.0, y0),
                    at(x0, y0 + 1.0),
                    at(x0 + 1.0, y0 + 1.0),
                );
                for k in 0..3 {
                    let top = p00[k] * (1.0 - tx) + p10[k] * tx;
                    let bottom = p01[k] * (1.0 - tx) + p11[k] * tx;
                    data.push(top * (1.0 - ty) + bottom * ty);
                }
            }
        }
        let name = path.file_name().unwrap();
        scenes::images::write_png(
            &taken.join("images").join(name),
            &Photo {
                width: w,
                height: h,
                data,
            },
            scenes::BitDepth::Sixteen,
        )
        .unwrap();
        pinhole.push(img);
    }
    let reopened = open(&taken);
    assert!(
        reopened.undistorted(),
        "the OPENCV camera was not undistorted"
    );
    assert!(
        reopened
            .summary()
            .to_string()
            .contains("undistorted at load")
    );
    let psnr_of = |keep_distortion: bool| {
        let options = DataOptions {
            downsample: 1,
            keep_distortion,
            ..DataOptions::default()
        };
        let data = data::load(&taken, Mode::Plain, &options).unwrap();
        let cfg = config(Mode::Plain, 600, &data);
        let out = train::train(&cfg, &data, &Device::Cpu, None, false, &mut |_| {}).unwrap();
        let mut sum = 0.0;
        for &i in &truth.split.test {
            let camera = &data
                .test
                .iter()
                .find(|v| v.name == truth.cameras[i].name)
                .unwrap()
                .camera;
            let image = render(&out.model, camera, &out.settings).unwrap().color;
            let want: Vec<glam::Vec3> = pinhole[i]
                .data
                .chunks_exact(3)
                .map(|p| glam::Vec3::new(p[0], p[1], p[2]))
                .collect();
            sum += base::metrics::psnr_rgb(&image, &want).unwrap();
        }
        sum / truth.split.test.len() as f64
    };
    let (undistorted, kept) = (psnr_of(false), psnr_of(true));
    eprintln!(
        "held-out PSNR against the pinhole truth: undistorted {undistorted:.2} dB, as taken {kept:.2} dB"
    );
    assert!(undistorted > kept + 0.5, "{undistorted} vs {kept}");
}

/// Aware mode's penalties weigh against the loss's total weight `1 + λ` (the step's λ, as it
/// fades), the other modes' against their one term.
#[test]
fn aware_weighs_the_splat_penalties_by_the_loss_total_weight() {
    let data = data::load(&fixture().aberrated, Mode::Aware, &options()).unwrap();
    let mut aware = config(Mode::Aware, 100, &data);
    aware.lambda = 0.75;
    aware.lambda_hold_until = 20;
    aware.lambda_fade_until = Some(60);
    for (step, want) in [(0, 1.75), (20, 1.75), (40, 1.375), (60, 1.0), (99, 1.0)] {
        let got = aware.penalty_weight_at(step);
        assert!(
            (got - want).abs() < 1e-6,
            "step {step}: {got} against {want}"
        );
    }
    for mode in [Mode::Plain, Mode::Restored] {
        let mut c = config(mode, 100, &data);
        c.lambda = 0.75;
        assert_eq!(c.penalty_weight_at(0), 1.0, "{mode:?}");
    }
}

/// An `--iters auto` run built for another horizon (the one an earlier version made it for,
/// so that it resumes as made) has that horizon's schedules, those of a fixed run of that
/// length, and no stop before its own densification ends.
#[test]
fn an_auto_run_is_built_for_the_horizon_it_was_made_for() {
    let data = data::load(&fixture().clean, Mode::Plain, &options()).unwrap();
    let settings = metasplat::settings::TrainSettings {
        mode: Mode::Plain,
        iters: metasplat::settings::Iters::Auto,
        ..Default::default()
    };
    let own = TrainConfig::build(&settings, 0, &data);
    let h = own.schedule_iters.unwrap();
    let other = TrainConfig::build_with_horizon(&settings, 0, &data, Some(h + 400));
    assert_eq!(other.schedule_iters, Some(h + 400));
    assert_eq!(other.iters, 3 * (h + 400));
    let fixed = TrainConfig::build(
        &metasplat::settings::TrainSettings {
            iters: metasplat::settings::Iters::Steps(h + 400),
            ..settings.clone()
        },
        0,
        &data,
    );
    assert_eq!(other.recipe, fixed.recipe);
    assert_ne!(other.recipe, own.recipe);
    let (a, b) = (own.stop.unwrap(), other.stop.unwrap());
    assert!(b.not_before > a.not_before, "{a:?} {b:?}");
    assert_eq!(
        TrainConfig::build_with_horizon(&settings, 0, &data, Some(h)),
        own
    );
}
