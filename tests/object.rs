//! Object captures (`--mask-mode object`): a turntable-like capture whose backdrop moves
//! against the poses trains to the object alone; through the lens, the targets are the blur
//! of the object composited over the step's background; a pixel outside the mask pulls the
//! render towards the background.

mod common;

use std::path::{Path, PathBuf};

use glam::Vec3;
use metasplat::settings::MaskUse;
use metasplat::settings::{DataOptions, MaskChoice, TrainSettings};
use metasplat::splats::convert::{pixels_to_rgb, splat_camera};
use metasplat::splats::device::Device;
use metasplat::splats::procedural::{ProceduralOptions, cameras_around, ground_truth_around};
use metasplat::train::config::{Mode, TrainConfig};
use metasplat::train::data::{self, View};
use metasplat::train::object::{ObjectTargets, over};
use metasplat::train::objective::Objective;
use metasplat::train::{self, eval};
use splat::RenderSettings;

fn options() -> DataOptions {
    DataOptions {
        downsample: 1,
        ..DataOptions::default()
    }
}

const SIDE: u32 = 64;

/// One camera's view of the object alone: its pixels over black and its alpha.
type ObjectAlone = (Vec<Vec3>, Vec<f32>);

/// The procedural all-around object on its turntable, photographed by a camera that stays
/// put while the object turns: in the object's frame (the poses') the camera circles, and the
/// room behind, a striped backdrop, is the same picture in every photo. Returns the capture
/// (with the object's masks in `masks/` when `masks`) and, per camera, the object alone over
/// black with its alpha.
fn turntable(dest: &Path, masks: bool) -> (PathBuf, Vec<ObjectAlone>) {
    let o = ProceduralOptions {
        width: SIDE,
        height: SIDE,
        views: 24,
        seed: 3,
    };
    let truth = ground_truth_around(o.seed);
    let cams = cameras_around(&o);
    let backdrop: Vec<Vec3> = (0..SIDE * SIDE)
        .map(|i| {
            let (x, y) = ((i % SIDE) as f32, (i / SIDE) as f32);
            Vec3::new(
                0.9,
                0.5 + 0.4 * (x / 2.5).sin(),
                0.2 + 0.7 * y / SIDE as f32,
            )
        })
        .collect();
    let mut writer = scenes::LlffWriter::create(dest, 1, scenes::BitDepth::Eight).unwrap();
    let mask_dir = writer.staging_dir().join("masks");
    if masks {
        std::fs::create_dir(&mask_dir).unwrap();
    }
    let mut objects = Vec::new();
    for c in &cams {
        let render = |background: Vec3| {
            let settings = RenderSettings {
                background,
                ..RenderSettings::default()
            };
            splat::render(&truth, &splat_camera(c), &settings)
                .unwrap()
                .color
                .iter()
                .map(|p| p.clamp(Vec3::ZERO, Vec3::ONE))
                .collect::<Vec<_>>()
        };
        let (black, white) = (render(Vec3::ZERO), render(Vec3::ONE));
        let alpha: Vec<f32> = black
            .iter()
            .zip(&white)
            .map(|(b, w)| (1.0 - (*w - *b).y).clamp(0.0, 1.0))
            .collect();
        let photo: Vec<Vec3> = black
            .iter()
            .zip(&alpha)
            .zip(&backdrop)
            .map(|((p, a), bg)| *p + *bg * (1.0 - a))
            .collect();
        writer
            .add(
                c,
                scenes::Bounds {
                    near: 1.2,
                    far: 6.5,
                },
                &pixels_to_rgb(&photo, SIDE, SIDE),
            )
            .unwrap();
        if masks {
            let grey: Vec<Vec3> = alpha.iter().map(|&a| Vec3::splat(a)).collect();
            scenes::images::write_png(
                &mask_dir.join(format!("{}.png", c.name)),
                &pixels_to_rgb(&grey, SIDE, SIDE),
                scenes::BitDepth::Eight,
            )
            .unwrap();
        }
        objects.push((black, alpha));
    }
    (writer.finish().unwrap(), objects)
}

/// A small simulated lens's imaging model at the turntable's size.
fn small_lens() -> aberration::ImagingModel {
    let (psf, _) =
        aberration::optics::simulate_grid(&aberration::optics::SimConfig::small(21), &|_, _| {})
            .unwrap();
    aberration::ImagingModel::new(
        &psf,
        SIDE as usize,
        SIDE as usize,
        aberration::BlurMode::Tiled,
        None,
        Default::default(),
    )
    .unwrap()
}

fn settings(iters: u64, mask_mode: MaskChoice) -> TrainSettings {
    TrainSettings {
        mode: Mode::Plain,
        iters: metasplat::settings::Iters::Steps(iters),
        eval_every: Some(0),
        checkpoint_every: Some(0),
        mask_mode,
        ..Default::default()
    }
}

/// The tiny turntable trains, in `object` mode, to a model whose held-out renders over black
/// match the object over black; trained on the whole photos, the backdrop that turns with the
/// camera cannot be fitted and ends in front of the object. The object model is empty
/// outside the object: drawn over white, it shows white there.
#[test]
fn a_turntable_capture_trains_to_the_object_alone() {
    let dir = tempfile::tempdir().unwrap();
    let (masked, objects) = turntable(&dir.path().join("masked"), true);
    let (whole, _) = turntable(&dir.path().join("whole"), false);
    let iters = 800;
    let score = |capture: &Path, mask_mode: MaskChoice| {
        let data = data::load(capture, Mode::Plain, &options()).unwrap();
        let config = TrainConfig::build(&settings(iters, mask_mode), 0, &data);
        let out = train::train(&config, &data, &Device::Cpu, None, false, &mut |_| {}).unwrap();
        let test = data.capture.split.test.clone();
        assert!(!test.is_empty());
        let (mut psnr, mut empty) = (0.0, 0.0);
        for &i in &test {
            let camera = splat_camera(&data.capture.cameras[i]);
            let draw = |background| {
                let s = RenderSettings {
                    background,
                    ..out.settings.clone()
                };
                splat::render(&out.model, &camera, &s).unwrap().color
            };
            let (object, alpha) = &objects[i];
            let (on_black, on_white) = (draw(Vec3::ZERO), draw(Vec3::ONE));
            psnr += base::psnr_rgb(
                &on_black
                    .iter()
                    .map(|p| p.clamp(Vec3::ZERO, Vec3::ONE))
                    .collect::<Vec<_>>(),
                object,
            )
            .unwrap();
            // Transmittance where the object is absent.
            let outside: Vec<f32> = on_black
                .iter()
                .zip(&on_white)
                .zip(alpha)
                .filter(|(_, a)| **a < 0.01)
                .map(|((b, w), _)| (*w - *b).element_sum() / 3.0)
                .collect();
            empty += outside.iter().sum::<f32>() as f64 / outside.len().max(1) as f64;
        }
        let n = test.len() as f64;
        (config.masks, psnr / n, empty / n)
    };
    let (masks, object_psnr, object_empty) = score(&masked, MaskChoice::Auto);
    assert_eq!(
        masks,
        Some(MaskUse::Object),
        "object is the default with masks"
    );
    let (none, whole_psnr, _) = score(&whole, MaskChoice::Auto);
    assert_eq!(none, None);
    eprintln!(
        "object mode {object_psnr:.2} dB (transmittance outside {object_empty:.3}), whole photos {whole_psnr:.2} dB"
    );
    assert!(
        object_psnr > whole_psnr + 5.0,
        "object mode {object_psnr:.2} dB, whole photos {whole_psnr:.2} dB against the object"
    );
    assert!(object_psnr > 21.0, "object mode {object_psnr:.2} dB");
    assert!(
        object_empty > 0.9,
        "the object model is not empty outside the object: transmittance {object_empty:.3}"
    );
}

/// `--mask-mode object` on a capture without object masks is refused, naming the flag.
#[test]
fn object_mode_without_masks_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let (whole, _) = turntable(&dir.path().join("whole"), false);
    let mut request = metasplat::settings::RunRequest::new(&whole, dir.path().join("run"));
    request.data.downsample = 1;
    request.training.mode = Mode::Plain;
    request.training.mask_mode = MaskChoice::Object;
    let err = metasplat::run::check(&request).unwrap_err().to_string();
    assert!(
        err.contains("--mask-mode object") && err.contains("no object masks"),
        "{err}"
    );
    assert!(!dir.path().join("run").exists());
}

/// Through the lens, the object's target over any background is the blur of the object
/// composited over that background, to f32 rounding, at the image's borders too: checked
/// against the imaging model applied to the composite itself, for a copy composited over
/// black and for photos with the room behind (inside the object and far from it).
#[test]
fn through_the_lens_the_target_is_the_blur_of_the_composite() {
    let dir = tempfile::tempdir().unwrap();
    let (masked, objects) = turntable(&dir.path().join("masked"), true);
    let imaging = small_lens();
    let data = data::load(&masked, Mode::Plain, &options()).unwrap();
    let view0 = &data.train[0];
    let i = data.capture.split.train[0];
    let (object, _) = &objects[i];
    let m = view0.mask.clone().unwrap();
    // A sharp object over a room: the object over black is `object`.
    let room: Vec<Vec3> = (0..m.len())
        .map(|k| Vec3::new(0.3, 0.7, (k % 7) as f32 / 7.0))
        .collect();
    let n = m.len();
    let outside: Vec<Vec3> = m.iter().map(|&k| Vec3::splat(1.0 - k)).collect();
    let blur_of_one = imaging.blur_pixels(&vec![Vec3::ONE; n]).unwrap();
    let targets = |composited_over| ObjectTargets {
        through_lens: true,
        composited_over,
        spread: vec![Some(imaging.blur_pixels(&outside).unwrap())],
        blur_of_one: blur_of_one.clone(),
    };
    let with_observed = |observed: Vec<Vec3>| View {
        observed,
        ..view0.clone()
    };
    // The sharp scene: the object before the room.
    let scene: Vec<Vec3> = object
        .iter()
        .zip(&room)
        .zip(&m)
        .map(|((o, r), &k)| *o + *r * (1.0 - k))
        .collect();
    for bg in [Vec3::ZERO, Vec3::new(0.2, 0.5, 0.9), Vec3::ONE] {
        let reference = imaging.blur_pixels(&over(&scene, &m, bg)).unwrap();
        // A copy composited over black before the blur (`scene aberrate`).
        let copy = with_observed(imaging.blur_pixels(&over(&scene, &m, Vec3::ZERO)).unwrap());
        let t = targets(Some(Vec3::ZERO));
        let got = t.view(0, &copy, bg);
        let worst = got
            .observed
            .iter()
            .zip(&reference)
            .map(|(a, b)| (*a - *b).abs().max_element())
            .fold(0.0f32, f32::max);
        assert!(
            worst < 1e-5,
            "composited copy, background {bg}: off by {worst}"
        );
        assert!(
            got.mask.is_none(),
            "every pixel of a composited copy counts"
        );
        // Photos with the room behind: exact where the blur mixes nothing, and the pixels it
        // mixes weigh less.
        let photo = with_observed(imaging.blur_pixels(&scene).unwrap());
        let t = targets(None);
        let got = t.view(0, &photo, bg);
        let w = got.mask.as_deref().expect("weights for photos with a room");
        let mut checked = 0;
        for k in 0..n {
            if w[k] > 0.999 && (m[k] > 0.999 || m[k] < 0.001) {
                let d = (got.observed[k] - reference[k]).abs().max_element();
                assert!(
                    d < 2e-3,
                    "pixel {k}: target off by {d} where the blur mixes nothing"
                );
                checked += 1;
            }
        }
        assert!(checked > n / 4, "only {checked} pixels unmixed");
        assert!(
            w.iter().any(|&x| x < 0.5),
            "no pixel was left out where the blur mixes"
        );
    }
}

/// In `object` mode a pixel outside the mask pulls the render towards the background: the
/// gradient there points from the background to the render, and matches finite differences
/// of the loss (plain, and aware through the blur's adjoint).
#[test]
fn outside_the_mask_the_render_is_pulled_to_the_background() {
    let dir = tempfile::tempdir().unwrap();
    let (masked, _) = turntable(&dir.path().join("masked"), true);
    let imaging = small_lens();
    let data = data::load(&masked, Mode::Plain, &options()).unwrap();
    let view = &data.train[0];
    let m = view.mask.clone().unwrap();
    let bg = Vec3::new(0.1, 0.2, 0.3);
    for (mode, through_lens) in [(Mode::Plain, false), (Mode::Aware, true)] {
        let mut v = view.clone();
        v.restored = Some(view.observed.clone());
        let targets = ObjectTargets {
            through_lens,
            composited_over: Some(Vec3::ZERO),
            spread: vec![Some(
                imaging
                    .blur_pixels(&m.iter().map(|&k| Vec3::splat(1.0 - k)).collect::<Vec<_>>())
                    .unwrap(),
            )],
            blur_of_one: Vec::new(),
        };
        let target = targets.view(0, &v, bg);
        let objective = Objective {
            mode,
            lambda: 0.5,
            dssim_weight: 1.0,
            imaging: Some(&imaging),
            width: SIDE,
            height: SIDE,
            outside: None,
        };
        // A render that shows a grey haze over the empty surround.
        let rendered: Vec<Vec3> = m
            .iter()
            .zip(&target.observed)
            .enumerate()
            .map(|(k, (&a, t))| {
                if a < 0.01 {
                    Vec3::splat(0.6) + Vec3::splat(((k * 7) % 5) as f32 / 50.0)
                } else {
                    *t
                }
            })
            .collect();
        let (_, grad) = objective.evaluate(&rendered, &target).unwrap();
        let outside: Vec<usize> = (0..m.len()).filter(|&k| m[k] < 0.01).collect();
        assert!(outside.len() > 100);
        // Descending the gradient moves the haze towards the background.
        let pull: f64 = outside
            .iter()
            .map(|&k| grad[k].dot(rendered[k] - bg) as f64)
            .sum();
        assert!(
            pull > 0.0,
            "{mode}: the gradient does not pull towards the background"
        );
        let d: Vec<Vec3> = (0..m.len())
            .map(|k| {
                if m[k] < 0.01 {
                    Vec3::new(1.0, -0.5, 0.25) * (((k * 13) % 7) as f32 / 7.0 - 0.4)
                } else {
                    Vec3::ZERO
                }
            })
            .collect();
        let eps = 1e-2f32;
        let at = |t: f32| {
            let r: Vec<Vec3> = rendered.iter().zip(&d).map(|(p, q)| *p + *q * t).collect();
            objective.value(&r, &target).unwrap() as f64
        };
        let fd = (at(eps) - at(-eps)) / (2.0 * eps as f64);
        let g: f64 = grad.iter().zip(&d).map(|(a, b)| a.dot(*b) as f64).sum();
        assert!(fd.abs() > 1e-4, "{mode}: the probe moves nothing ({fd:e})");
        assert!(
            (g - fd).abs() <= 5e-2 * fd.abs() + 1e-5,
            "{mode}: gradient {g:e}, finite differences {fd:e}"
        );
    }
}

/// Held-out views of an object run are scored on the object: the reference composited over
/// the background outside each mask, the render as drawn (`object`) or composited the same
/// way (`loss`), and PSNR inside the mask beside it; other masks score the pixels they keep.
#[test]
fn held_out_views_are_scored_on_the_object() {
    let dir = tempfile::tempdir().unwrap();
    let (masked, _) = turntable(&dir.path().join("masked"), true);
    let data = data::load(&masked, Mode::Plain, &options()).unwrap();
    let config = TrainConfig::build(&settings(20, MaskChoice::Auto), 0, &data);
    let out = train::train(&config, &data, &Device::Cpu, None, false, &mut |_| {}).unwrap();
    let bg = out.settings.background;
    for masks in [MaskUse::Object, MaskUse::Loss] {
        let m = eval::evaluate(
            &out.model,
            &data.test,
            &out.settings,
            &Device::Cpu,
            Some(masks),
        )
        .unwrap()
        .unwrap();
        let on = m.on_object.as_ref().expect("scored on the object");
        assert_eq!(on.masks, masks);
        for (v, vm) in data.test.iter().zip(&m.views) {
            let render = splat::render(&out.model, &v.camera, &out.settings)
                .unwrap()
                .color;
            let mask = v.mask.as_deref().unwrap();
            let image = match masks {
                MaskUse::Object => render.clone(),
                MaskUse::Loss => over(&render, mask, bg),
            };
            let (p, _) = eval::compare(&image, &over(&v.observed, mask, bg), SIDE, SIDE).unwrap();
            assert!(
                (p - vm.psnr).abs() < 1e-9,
                "{masks}: {p} against {}",
                vm.psnr
            );
            assert!(vm.psnr_in_mask.is_some());
        }
    }
    // Masks that are not an object's (undistortion's border, alpha) score the pixels they
    // keep: the reference has nothing elsewhere.
    let sourced = eval::evaluate(&out.model, &data.test, &out.settings, &Device::Cpu, None)
        .unwrap()
        .unwrap();
    assert!(sourced.on_object.is_none() && sourced.sourced_pixels);
    for (v, vm) in data.test.iter().zip(&sourced.views) {
        let render = splat::render(&out.model, &v.camera, &out.settings)
            .unwrap()
            .color;
        let clamped: Vec<Vec3> = render
            .iter()
            .map(|p| p.clamp(Vec3::ZERO, Vec3::ONE))
            .collect();
        let mask = v.mask.as_deref().unwrap();
        let want = metasplat::train::object::psnr_in_mask(&clamped, &v.observed, mask).unwrap();
        assert!((want - vm.psnr).abs() < 1e-9, "{want} against {}", vm.psnr);
    }
}

/// `experiment llff` on a masked capture scores every row on the object (the aberrated input
/// included), says so under its table, and records it in each run's `metrics.json`.
#[test]
fn an_experiment_on_a_masked_capture_scores_every_row_on_the_object() {
    use common::cli::{ok, s};
    let dir = tempfile::tempdir().unwrap();
    let (masked, _) = turntable(&dir.path().join("masked"), true);
    let psf = dir.path().join("psf.npy");
    let (grid, _) =
        aberration::optics::simulate_grid(&aberration::optics::SimConfig::small(9), &|_, _| {})
            .unwrap();
    grid.save_npy(&psf).unwrap();
    let out = dir.path().join("exp");
    let text = ok(&[
        "experiment",
        "llff",
        "--scene",
        s(&masked),
        "--out",
        s(&out),
        "--psf",
        s(&psf),
        "--downsample",
        "1",
        "--iters",
        "20",
        "--device",
        "cpu",
    ]);
    assert!(
        text.contains("Scored on the object (mask mode object)"),
        "{text}"
    );
    let header = text
        .lines()
        .find(|l| l.starts_with("| method"))
        .expect("a table");
    assert!(header.contains("in the mask"), "{header}");
    let rows: Vec<&str> = text
        .lines()
        .filter(|l| l.starts_with("| aberrated input") || l.starts_with("| 3D-GS"))
        .collect();
    assert_eq!(rows.len(), 5, "{text}");
    for row in &rows {
        let last = row.trim_end_matches('|').rsplit('|').next().unwrap().trim();
        assert!(last.parse::<f64>().is_ok(), "no PSNR in the mask: {row}");
    }
    for run in ["run_clean", "run_plain", "run_restored", "run_aware"] {
        let m: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(out.join(run).join("metrics.json")).unwrap(),
        )
        .unwrap();
        assert_eq!(m["metrics"]["on_object"]["masks"], "object", "{run}");
        let config: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(out.join(run).join("config.json")).unwrap(),
        )
        .unwrap();
        assert_eq!(config["masks"], "object", "{run}");
    }
}

/// `scene aberrate`'s copy of the masked turntable (composited over a colour outside the
/// masks before the blur), in `dir`.
fn aberrated_turntable(dir: &Path) -> PathBuf {
    let (masked, _) = turntable(&dir.join("masked"), true);
    let psf = dir.join("psf.npy");
    let (grid, _) =
        aberration::optics::simulate_grid(&aberration::optics::SimConfig::small(9), &|_, _| {})
            .unwrap();
    grid.save_npy(&psf).unwrap();
    let capture = scenes::open(
        &masked,
        &scenes::OpenOptions {
            resolution: scenes::Resolution::Downsample(1),
            ..Default::default()
        },
    )
    .unwrap();
    let copy = dir.join("copy");
    scenes::make_aberrated(
        &capture,
        &psf,
        &copy,
        &scenes::AberrateOptions::default(),
        &|| {},
    )
    .unwrap();
    copy
}

/// The viewer's comparison of a capture with object masks scores every panel on the object
/// (inside the view's mask) and says so; a capture without masks is scored whole.
#[test]
fn the_viewers_comparison_scores_an_object_capture_on_the_object() {
    let dir = tempfile::tempdir().unwrap();
    let copy = aberrated_turntable(dir.path());
    let mut comparison =
        metasplat::output::view::CaptureComparison::open(&copy, &options()).unwrap();
    let data = data::load(&copy, Mode::Plain, &options()).unwrap();
    let i = data.capture.split.train[0];
    let view = &data.train[0];
    let mask = view.mask.as_deref().unwrap();
    let clean = view.clean.as_deref().unwrap();
    let render: Vec<Vec3> = view.observed.iter().map(|p| *p * 0.9).collect();
    let panels = comparison.panels_for(i, &render).unwrap();
    for p in panels.iter().filter(|p| p.psnr_vs_clean.is_some()) {
        assert!(p.on_object, "{}", p.name);
        let want = metasplat::train::object::psnr_in_mask(&p.pixels, clean, mask);
        assert_eq!(p.psnr_vs_clean, want, "{}", p.name);
    }
    assert!(panels.iter().any(|p| p.psnr_vs_clean.is_some()));
}

/// The viewer's "render through the PSF" on a copy composited over `c₀` before the blur goes
/// through the lens as the photo did, `PSF ⊛ (m·render + (1 − m)·c₀)`: a render right on the
/// object and bright elsewhere (nothing in training constrains it there) then matches the
/// photo to its noise, where blurring it as it is spreads the bright room over the object.
#[test]
fn the_viewers_reblurred_render_is_composited_as_the_photo_was() {
    let dir = tempfile::tempdir().unwrap();
    let copy = aberrated_turntable(dir.path());
    let mut comparison =
        metasplat::output::view::CaptureComparison::open(&copy, &options()).unwrap();
    let data = data::load(&copy, Mode::Aware, &options()).unwrap();
    let c0 = Vec3::from_array(data.composited_over.expect("the copy records its colour"));
    let imaging = data.imaging.as_ref().unwrap();
    let i = data.capture.split.train[0];
    let view = &data.train[0];
    let mask = view.mask.as_deref().unwrap();
    let clean = view.clean.as_deref().unwrap();
    let render: Vec<Vec3> = clean
        .iter()
        .zip(mask)
        .map(|(p, &m)| if m > 0.0 { *p } else { Vec3::ONE })
        .collect();
    let panels = comparison.panels_for(i, &render).unwrap();
    let panel = panels
        .iter()
        .find(|p| p.name == metasplat::output::view::REBLURRED)
        .unwrap();
    let want = imaging.blur_pixels(&over(&render, mask, c0)).unwrap();
    let off = panel
        .pixels
        .iter()
        .zip(&want)
        .map(|(a, b)| (*a - *b).abs().max_element())
        .fold(0.0f32, f32::max);
    assert_eq!(off, 0.0, "the panel is not the composite through the lens");
    let as_is = imaging.blur_pixels(&render).unwrap();
    let to_photo = |img: &[Vec3]| base::psnr_rgb(img, &view.observed).unwrap();
    let (composited, blurred) = (to_photo(&panel.pixels), to_photo(&as_is));
    assert!(
        composited > blurred + 10.0,
        "composited {composited:.2} dB against the photo, as it is {blurred:.2} dB"
    );
}

/// Masks that leave out every pixel of every training view are refused before any work,
/// naming where the masks come from, instead of training to a loss of 0 and a perfect score.
#[test]
fn masks_that_keep_nothing_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let (masked, _) = turntable(&dir.path().join("masked"), true);
    for e in std::fs::read_dir(masked.join("masks")).unwrap() {
        let p = e.unwrap().path();
        let black = scenes::Photo {
            width: SIDE,
            height: SIDE,
            data: vec![0.0; (SIDE * SIDE * 3) as usize],
        };
        scenes::images::write_png(&p, &black, scenes::BitDepth::Eight).unwrap();
    }
    let run = dir.path().join("run");
    let mut request = metasplat::settings::RunRequest::new(&masked, &run);
    request.data.downsample = 1;
    request.training.mode = Mode::Plain;
    let e = metasplat::run::prepare(&request).err().unwrap();
    let mut err = e.to_string();
    let mut cause = std::error::Error::source(&e);
    while let Some(c) = cause {
        err += &format!(": {c}");
        cause = c.source();
    }
    assert!(
        err.contains("leaves out every pixel") && err.contains("masks/"),
        "{err}"
    );
    assert!(!run.exists(), "a refused run made its folder");
}
